// Chunk codecs. Every chunk is compressed on its own so that it decodes alone.
#include <lz4.h>
#include <lz4hc.h>
#include <xxhash.h>
#include <zstd.h>

#include <cstring>

#include <fmt/format.h>

#include "particlestream/format.hpp"

namespace pstream::format {

std::uint64_t checksum(std::span<const std::byte> bytes) { return XXH3_64bits(bytes.data(), bytes.size()); }

EncodedChunk encode_chunk(std::span<const std::byte> raw, Codec codec, int level) {
  EncodedChunk out;
  out.codec = codec;
  switch (codec) {
    case Codec::Raw: out.stored.assign(raw.begin(), raw.end()); break;
    case Codec::Lz4: {
      if (raw.size() > static_cast<std::size_t>(LZ4_MAX_INPUT_SIZE)) throw Error("chunk too large for lz4");
      out.stored.resize(static_cast<std::size_t>(LZ4_compressBound(static_cast<int>(raw.size()))));
      const auto* src = reinterpret_cast<const char*>(raw.data());
      auto* dst = reinterpret_cast<char*>(out.stored.data());
      const int n = level > 0 ? LZ4_compress_HC(src, dst, int(raw.size()), int(out.stored.size()), level)
                              : LZ4_compress_default(src, dst, int(raw.size()), int(out.stored.size()));
      if (n <= 0) throw Error("lz4 compression failed");
      out.stored.resize(static_cast<std::size_t>(n));
      out.codec_param = static_cast<std::uint32_t>(std::max(level, 0));
      break;
    }
    case Codec::Zstd: {
      out.stored.resize(ZSTD_compressBound(raw.size()));
      const std::size_t n = ZSTD_compress(out.stored.data(), out.stored.size(), raw.data(), raw.size(), level);
      if (ZSTD_isError(n)) throw Error(fmt::format("zstd compression failed: {}", ZSTD_getErrorName(n)));
      out.stored.resize(n);
      out.codec_param = static_cast<std::uint32_t>(level);
      break;
    }
  }
  out.checksum = checksum(out.stored);
  return out;
}

void decode_chunk(const ChunkEntry& entry, std::span<const std::byte> stored, std::span<std::byte> out,
                  std::string_view where) {
  const std::uint64_t sum = checksum(stored);
  if (sum != entry.checksum) {
    throw Error(
        fmt::format("{}: checksum mismatch: stored bytes hash to {:016x}, the chunk table says {:016x} "
                    "(the file is corrupted)",
                    where, sum, entry.checksum));
  }
  switch (entry.codec) {
    case Codec::Raw:
      if (stored.size() != out.size()) {
        throw Error(fmt::format("{}: raw chunk holds {} bytes, expected {}", where, stored.size(), out.size()));
      }
      if (!out.empty()) std::memcpy(out.data(), stored.data(), out.size());
      return;
    case Codec::Lz4: {
      const int n =
          LZ4_decompress_safe(reinterpret_cast<const char*>(stored.data()), reinterpret_cast<char*>(out.data()),
                              static_cast<int>(stored.size()), static_cast<int>(out.size()));
      if (n < 0 || static_cast<std::size_t>(n) != out.size()) {
        throw Error(fmt::format("{}: lz4 data decodes to {} bytes, expected {}", where, n, out.size()));
      }
      return;
    }
    case Codec::Zstd: {
      const std::size_t n = ZSTD_decompress(out.data(), out.size(), stored.data(), stored.size());
      if (ZSTD_isError(n)) throw Error(fmt::format("{}: zstd data does not decode: {}", where, ZSTD_getErrorName(n)));
      if (n != out.size())
        throw Error(fmt::format("{}: zstd data decodes to {} bytes, expected {}", where, n, out.size()));
      return;
    }
  }
  throw Error(fmt::format("{}: unknown codec {}", where, static_cast<int>(entry.codec)));
}

}  // namespace pstream::format

namespace pstream::format {

ChunkDecoder::ChunkDecoder() : zstd_(ZSTD_createDCtx()) {
  if (zstd_ == nullptr) throw Error("cannot create a zstd decoder");
}

ChunkDecoder::~ChunkDecoder() { ZSTD_freeDCtx(static_cast<ZSTD_DCtx*>(zstd_)); }

void ChunkDecoder::decode(const ChunkEntry& entry, std::span<const std::byte> stored, std::span<std::byte> out,
                          std::string_view file, std::uint64_t chunk) {
  const auto where = [&] { return fmt::format("{}: chunk {} (file offset {})", file, chunk, entry.file_offset); };
  if (checksum(stored) != entry.checksum) {
    throw Error(
        fmt::format("{}: checksum mismatch: the stored bytes do not hash to the chunk table's {:016x} "
                    "(the file is corrupted or was replaced)",
                    where(), entry.checksum));
  }
  if (entry.codec == Codec::Zstd) {
    const std::size_t n =
        ZSTD_decompressDCtx(static_cast<ZSTD_DCtx*>(zstd_), out.data(), out.size(), stored.data(), stored.size());
    if (ZSTD_isError(n) || n != out.size()) {
      throw Error(fmt::format("{}: zstd data does not decode to {} bytes", where(), out.size()));
    }
    return;
  }
  if (entry.codec == Codec::Raw) {
    if (stored.size() != out.size())
      throw Error(fmt::format("{}: raw chunk holds {} bytes, expected {}", where(), stored.size(), out.size()));
    if (!out.empty()) std::memcpy(out.data(), stored.data(), out.size());
    return;
  }
  if (entry.codec == Codec::Lz4) {
    const int n = LZ4_decompress_safe(reinterpret_cast<const char*>(stored.data()), reinterpret_cast<char*>(out.data()),
                                      static_cast<int>(stored.size()), static_cast<int>(out.size()));
    if (n < 0 || static_cast<std::size_t>(n) != out.size()) {
      throw Error(fmt::format("{}: lz4 data decodes to {} bytes, expected {}", where(), n, out.size()));
    }
    return;
  }
  throw Error(fmt::format("{}: unknown codec {}", where(), static_cast<int>(entry.codec)));
}

}  // namespace pstream::format
