// The decoder's entropy stage behind one door: zstd and lz4 data decompressed into the caller's
// buffer. Native builds implement it with libzstd and liblz4 (entropy.cpp). The browser build has
// neither library (Emscripten cannot fetch its ports here, and nothing is vendored), so it
// implements the door with the decompressor its worker supplies (web/src/entropy_host.cpp). Every
// other decoder source is the same in both builds.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

namespace pstream::format {

class EntropyDecoder {
 public:
  static constexpr std::size_t kFailed = static_cast<std::size_t>(-1);
  // With `stream_window_log` > 0 it also decodes one zstd stream packet by packet (zstd_stream):
  // its one context is then a buffer fixed here for windows up to 2^stream_window_log bytes.
  // Throws pstream::Error when its state cannot be allocated.
  explicit EntropyDecoder(int stream_window_log = 0);
  ~EntropyDecoder();
  // The bytes the stream's fixed buffer takes (0 without a stream).
  static std::uint64_t stream_bytes(int stream_window_log);
  EntropyDecoder(const EntropyDecoder&) = delete;
  EntropyDecoder& operator=(const EntropyDecoder&) = delete;
  // Decompresses the zstd frame `in` into `out`, which bounds its size. Returns the bytes written,
  // or kFailed with `error` saying why (corrupt data, or more than out.size() bytes).
  std::size_t zstd(std::span<std::byte> out, std::span<const std::byte> in, std::string& error);
  // Decodes the next piece of a zstd stream, `in` (the stream's start when `restart`), into `out`:
  // everything its whole blocks hold. Returns the bytes written, or kFailed with `error` (corrupt
  // data, a window larger than the stream's, more than out.size() bytes, or `in` ending inside a
  // block). After a failure only a restart decodes.
  std::size_t zstd_stream(std::span<std::byte> out, std::span<const std::byte> in, bool restart, std::string& error);
  // The stream's state between two packets, saved and restored as bytes, so that decoding can come
  // back to a packet after decoding on past it (reverse play keeps a few such states). 0 when
  // there is no stream to save (`stream_window_log` 0), or when this build cannot save it: check
  // can_save_stream() first (the browser's stream lives in the worker).
  static bool can_save_stream();
  std::uint64_t saved_stream_bytes() const;
  // After a packet decoded whole: false (nothing written) when no stream is open.
  bool save_stream(std::span<std::byte> to) const;
  // The stream continues after the packet whose save_stream() wrote `from` (this decoder's own
  // bytes, of saved_stream_bytes()); fewer bytes leave no stream open (only a restart decodes).
  void restore_stream(std::span<const std::byte> from);
  // The same for an lz4 block.
  std::size_t lz4(std::span<std::byte> out, std::span<const std::byte> in, std::string& error);

 private:
  [[maybe_unused]] void* state_ = nullptr;        // libzstd's DCtx natively; the host's handle in the browser
  [[maybe_unused]] bool static_ = false;          // natively: state_ is a static DCtx in a block of ours
  [[maybe_unused]] std::size_t block_bytes_ = 0;  // natively: that block's size
  [[maybe_unused]] bool streaming_ = false;       // a stream is open (restarted, and no failure since)
};

}  // namespace pstream::format
