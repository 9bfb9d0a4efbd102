// The entropy stage with libzstd and liblz4 (entropy.hpp): what every native build links.
#include "format/entropy.hpp"

#include <lz4.h>
#include <zstd.h>

#include <climits>

#include "format/zstd_memory.hpp"
#include "particlestream/error.hpp"

namespace pstream::format {

EntropyDecoder::EntropyDecoder() : state_(make_zstd_dctx()) {
  if (state_ == nullptr) throw Error("cannot create a zstd decoder");
}

EntropyDecoder::~EntropyDecoder() { ZSTD_freeDCtx(static_cast<ZSTD_DCtx*>(state_)); }

std::size_t EntropyDecoder::zstd(std::span<std::byte> out, std::span<const std::byte> in, std::string& error) {
  const std::size_t n =
      ZSTD_decompressDCtx(static_cast<ZSTD_DCtx*>(state_), out.data(), out.size(), in.data(), in.size());
  if (!ZSTD_isError(n)) return n;
  error = ZSTD_getErrorName(n);
  return kFailed;
}

std::size_t EntropyDecoder::lz4(std::span<std::byte> out, std::span<const std::byte> in, std::string& error) {
  if (in.size() > INT_MAX || out.size() > INT_MAX) {
    error = "more than 2 GiB in one lz4 block";
    return kFailed;
  }
  const int n = LZ4_decompress_safe(reinterpret_cast<const char*>(in.data()), reinterpret_cast<char*>(out.data()),
                                    static_cast<int>(in.size()), static_cast<int>(out.size()));
  if (n >= 0) return static_cast<std::size_t>(n);
  error = "it does not decode within the expected bytes";
  return kFailed;
}

}  // namespace pstream::format
