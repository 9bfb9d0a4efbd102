// The entropy stage in the browser (src/format/entropy.hpp): the worker supplies zstd through
// Module.zstdDecompress (zstddec, from npm: zstd's own decoder built to WebAssembly), and this
// build refuses lz4 chunks, which the default cook never writes. docs/web.md says why.
#include <emscripten.h>

#include "format/entropy.hpp"

// Decompresses `src_size` bytes at `src` into at most `capacity` bytes at `out`; returns the size,
// or -1 when the data does not decode within `capacity` bytes.
EM_JS(int, pstream_host_zstd, (std::byte * out, int capacity, const std::byte* src, int src_size),
      { return Module.zstdDecompress(out, capacity, src, src_size); });

// The same for the next packet of a zstd stream, its first when `restart` is 1 (the worker keeps
// the stream, in zstddec's heap).
EM_JS(int, pstream_host_zstd_stream, (std::byte * out, int capacity, const std::byte* src, int src_size, int restart),
      { return Module.zstdStream(out, capacity, src, src_size, restart); });

namespace pstream::format {

EntropyDecoder::EntropyDecoder(int) {}
EntropyDecoder::~EntropyDecoder() = default;

std::uint64_t EntropyDecoder::stream_bytes(int) { return 0; }  // the stream lives in the worker's heap

std::size_t EntropyDecoder::zstd_stream(std::span<std::byte> out, std::span<const std::byte> in, bool restart,
                                        std::string& error) {
  if (in.size() > 0x7fffffff || out.size() > 0x7fffffff) {
    error = "more than 2 GiB in one zstd packet";
    return kFailed;
  }
  const int n = pstream_host_zstd_stream(out.data(), static_cast<int>(out.size()), in.data(),
                                         static_cast<int>(in.size()), restart ? 1 : 0);
  if (n >= 0) return static_cast<std::size_t>(n);
  error = "corrupt zstd data, more than the expected bytes, or not the packet after the one decoded last";
  return kFailed;
}

std::size_t EntropyDecoder::zstd(std::span<std::byte> out, std::span<const std::byte> in, std::string& error) {
  if (in.size() > 0x7fffffff || out.size() > 0x7fffffff) {
    error = "more than 2 GiB in one zstd frame";
    return kFailed;
  }
  const int n = pstream_host_zstd(out.data(), static_cast<int>(out.size()), in.data(), static_cast<int>(in.size()));
  if (n >= 0) return static_cast<std::size_t>(n);
  error = "corrupt zstd data, or more than the expected bytes";
  return kFailed;
}

// The stream lives in the worker's heap, out of reach: no saved states (reverse play decodes from
// the keyframe).
bool EntropyDecoder::can_save_stream() { return false; }
std::uint64_t EntropyDecoder::saved_stream_bytes() const { return 0; }
bool EntropyDecoder::save_stream(std::span<std::byte>) const { return false; }
void EntropyDecoder::restore_stream(std::span<const std::byte>) {}

std::size_t EntropyDecoder::lz4(std::span<std::byte>, std::span<const std::byte>, std::string& error) {
  error = "the browser player has no lz4 decoder: cook the clip with the default particle codec, or --codec zstd";
  return kFailed;
}

}  // namespace pstream::format
