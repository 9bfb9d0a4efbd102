// The decoder's entropy stage behind one door: zstd and lz4 data decompressed into the caller's
// buffer. Native builds implement it with libzstd and liblz4 (entropy.cpp). The browser build has
// neither library (Emscripten cannot fetch its ports here, and nothing is vendored), so it
// implements the door with the decompressor its worker supplies (web/src/entropy_host.cpp). Every
// other decoder source is the same in both builds.
#pragma once

#include <cstddef>
#include <span>
#include <string>

namespace pstream::format {

class EntropyDecoder {
 public:
  static constexpr std::size_t kFailed = static_cast<std::size_t>(-1);
  EntropyDecoder();  // throws pstream::Error when its state cannot be allocated
  ~EntropyDecoder();
  EntropyDecoder(const EntropyDecoder&) = delete;
  EntropyDecoder& operator=(const EntropyDecoder&) = delete;
  // Decompresses the zstd frame `in` into `out`, which bounds its size. Returns the bytes written,
  // or kFailed with `error` saying why (corrupt data, or more than out.size() bytes).
  std::size_t zstd(std::span<std::byte> out, std::span<const std::byte> in, std::string& error);
  // The same for an lz4 block.
  std::size_t lz4(std::span<std::byte> out, std::span<const std::byte> in, std::string& error);

 private:
  [[maybe_unused]] void* state_ = nullptr;  // libzstd's DCtx natively; the host's handle in the browser
};

}  // namespace pstream::format
