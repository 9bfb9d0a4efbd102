// Chunk codecs, the decoding side: each codec a unit with its name, the most bytes a stored byte
// can decode to, and its decoder (chunk_encode.cpp holds the encoders). Every chunk is compressed
// on its own so that it decodes alone; ChunkDecoder is the only way chunks are decoded.
#include <algorithm>
#include <array>
#include <cstring>
#include <memory>

#include <fmt/format.h>

#include "format/entropy.hpp"
#include "particlestream/format.hpp"

namespace pstream::format {
namespace {

// What a chunk decoder hands a codec: reusable state and how to name the chunk in errors.
struct DecodeContext {
  EntropyDecoder& entropy;
  std::string_view file;
  std::uint64_t chunk;
  const ChunkEntry& entry;
  std::string where() const { return fmt::format("{}: chunk {} (file offset {})", file, chunk, entry.file_offset); }
};

struct ChunkCodecUnit {
  Codec id;
  std::string_view name;
  // Most raw bytes one stored byte can decode to, and a constant for the smallest inputs.
  std::uint64_t max_ratio, max_extra;
  void (*decode)(const DecodeContext& ctx, std::span<const std::byte> stored, std::span<std::byte> out);
};

void raw_decode(const DecodeContext& ctx, std::span<const std::byte> stored, std::span<std::byte> out) {
  if (stored.size() != out.size())
    throw Error(fmt::format("{}: raw chunk holds {} bytes, expected {}", ctx.where(), stored.size(), out.size()));
  if (!out.empty() && stored.data() != out.data()) std::memcpy(out.data(), stored.data(), out.size());
}

void lz4_decode(const DecodeContext& ctx, std::span<const std::byte> stored, std::span<std::byte> out) {
  std::string why;
  const std::size_t n = ctx.entropy.lz4(out, stored, why);
  if (n == EntropyDecoder::kFailed)
    throw Error(fmt::format("{}: lz4 data is corrupt: {} (expected {} bytes)", ctx.where(), why, out.size()));
  if (n != out.size())
    throw Error(fmt::format("{}: lz4 data decodes to {} bytes, expected {}", ctx.where(), n, out.size()));
}

void zstd_decode(const DecodeContext& ctx, std::span<const std::byte> stored, std::span<std::byte> out) {
  std::string why;
  const std::size_t n = ctx.entropy.zstd(out, stored, why);
  if (n == EntropyDecoder::kFailed) throw Error(fmt::format("{}: zstd data does not decode: {}", ctx.where(), why));
  if (n != out.size())
    throw Error(fmt::format("{}: zstd data decodes to {} bytes, expected {}", ctx.where(), n, out.size()));
}

constexpr std::array<ChunkCodecUnit, 3> kUnits{{
    {Codec::Raw, "raw", 1, 0, raw_decode},
    {Codec::Lz4, "lz4", 255, 255, lz4_decode},
    {Codec::Zstd, "zstd", 32768, 0, zstd_decode},
}};

const ChunkCodecUnit* unit_of(Codec codec) {
  for (const ChunkCodecUnit& u : kUnits) {
    if (u.id == codec) return &u;
  }
  return nullptr;
}

}  // namespace

std::string_view codec_name(Codec codec) {
  const ChunkCodecUnit* u = unit_of(codec);
  return u ? u->name : "?";
}

std::uint64_t max_decoded_size(Codec codec, std::uint64_t stored) {
  const ChunkCodecUnit* u = unit_of(codec);
  if (u == nullptr) return 0;
  return stored > (UINT64_MAX - u->max_extra) / u->max_ratio ? UINT64_MAX : stored * u->max_ratio + u->max_extra;
}

ChunkDecoder::ChunkDecoder() : entropy_(std::make_unique<EntropyDecoder>()) {}

ChunkDecoder::~ChunkDecoder() = default;

void ChunkDecoder::decode(const ChunkEntry& entry, std::span<const std::byte> stored, std::span<std::byte> out,
                          std::string_view file, std::uint64_t chunk) {
  const DecodeContext ctx{*entropy_, file, chunk, entry};
  if (!checksum_matches(stored, entry.checksum)) {
    throw Error(
        fmt::format("{}: checksum mismatch: the stored bytes do not hash to the chunk table's {:016x} "
                    "(the file is corrupted or was replaced)",
                    ctx.where(), entry.checksum));
  }
  const ChunkCodecUnit* u = unit_of(entry.codec);
  if (u == nullptr) throw Error(fmt::format("{}: unknown codec {}", ctx.where(), static_cast<int>(entry.codec)));
  u->decode(ctx, stored, out);
}

}  // namespace pstream::format
