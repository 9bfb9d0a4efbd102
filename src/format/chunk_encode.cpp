// Chunk codecs, the encoding side (chunk_decode.cpp holds the names and decoders): a chunk's
// records compressed on their own, and checksummed.
#include <lz4.h>
#include <lz4hc.h>
#include <zstd.h>

#include <algorithm>
#include <array>
#include <memory>

#include <fmt/format.h>

#include "format/zstd_memory.hpp"
#include "particlestream/format.hpp"

namespace pstream::format {
namespace {

void raw_encode(std::span<const std::byte> raw, int /*level*/, EncodedChunk& out) {
  out.stored.assign(raw.begin(), raw.end());
}

void lz4_encode(std::span<const std::byte> raw, int level, EncodedChunk& out) {
  if (raw.size() > static_cast<std::size_t>(LZ4_MAX_INPUT_SIZE)) throw Error("chunk too large for lz4");
  out.stored.resize(static_cast<std::size_t>(LZ4_compressBound(static_cast<int>(raw.size()))));
  const auto* src = reinterpret_cast<const char*>(raw.data());
  auto* dst = reinterpret_cast<char*>(out.stored.data());
  const int n = level > 0 ? LZ4_compress_HC(src, dst, int(raw.size()), int(out.stored.size()), level)
                          : LZ4_compress_default(src, dst, int(raw.size()), int(out.stored.size()));
  if (n <= 0) throw Error("lz4 compression failed");
  out.stored.resize(static_cast<std::size_t>(n));
  out.codec_param = static_cast<std::uint32_t>(std::max(level, 0));
}

void zstd_encode(std::span<const std::byte> raw, int level, EncodedChunk& out) {
  out.stored.resize(ZSTD_compressBound(raw.size()));
  const std::unique_ptr<ZSTD_CCtx, decltype(&ZSTD_freeCCtx)> cctx(make_zstd_cctx(), &ZSTD_freeCCtx);
  if (!cctx) throw Error("cannot create a zstd encoder");
  const std::size_t n =
      ZSTD_compressCCtx(cctx.get(), out.stored.data(), out.stored.size(), raw.data(), raw.size(), level);
  if (ZSTD_isError(n)) throw Error(fmt::format("zstd compression failed: {}", ZSTD_getErrorName(n)));
  out.stored.resize(n);
  out.codec_param = static_cast<std::uint32_t>(level);
}

struct ChunkEncoder {
  Codec id;
  void (*encode)(std::span<const std::byte> raw, int level, EncodedChunk& out);
};
constexpr std::array<ChunkEncoder, 3> kEncoders{{
    {Codec::Raw, raw_encode},
    {Codec::Lz4, lz4_encode},
    {Codec::Zstd, zstd_encode},
}};

}  // namespace

EncodedChunk encode_chunk(std::span<const std::byte> raw, Codec codec, int level) {
  const auto* u =
      std::find_if(kEncoders.begin(), kEncoders.end(), [&](const ChunkEncoder& e) { return e.id == codec; });
  if (u == kEncoders.end()) throw Error(fmt::format("unknown chunk codec {}", static_cast<int>(codec)));
  EncodedChunk out;
  out.codec = codec;
  u->encode(raw, level, out);
  out.checksum = checksum(out.stored);
  return out;
}

}  // namespace pstream::format
