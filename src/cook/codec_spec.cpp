// Codec specs ("particle:9", "zstd:5", "raw"): the names the cook's users write, read into
// Options in one place for the command line and the bindings.
#include <charconv>

#include <fmt/format.h>

#include "base/names.hpp"
#include "particlestream/cook.hpp"

namespace pstream::cook {

void set_codec(Options& o, std::string_view spec) {
  const std::string text(spec);
  const auto colon = text.find(':');
  const std::string name = text.substr(0, colon);
  if (name == "particle" || name == "particle-lossless") {
    o.frame_codec = format::FrameCodec::Particle;
    o.particle.lossless = name == "particle-lossless";
    if (colon != std::string::npos) {  // the entropy stage's zstd level
      const std::string level = text.substr(colon + 1);
      const auto [ptr, ec] = std::from_chars(level.data(), level.data() + level.size(), o.particle.zstd_level);
      if (ec != std::errc() || ptr != level.data() + level.size() || o.particle.zstd_level < 1 ||
          o.particle.zstd_level > 22) {
        throw Error(fmt::format("`codec` '{}': the particle codec's zstd level must be 1..22 (default {}, lossless {})",
                                text, format::kDefaultParticleZstdLevel, format::kDefaultLosslessParticleZstdLevel));
      }
    }
    return;
  }
  if (name == "raw") {
    o.codec = format::Codec::Raw;
    if (colon != std::string::npos) throw Error(fmt::format("`codec` '{}': raw has no level; write raw", text));
    return;
  }
  if (name == "lz4")
    o.codec = format::Codec::Lz4;
  else if (name == "zstd")
    o.codec = format::Codec::Zstd;
  else
    throw Error(fmt::format(
        "`codec` '{}': expected particle[:LEVEL], particle-lossless[:LEVEL], raw, lz4, lz4:LEVEL, zstd or zstd:LEVEL{}",
        text, did_you_mean(name, {"particle", "particle-lossless", "raw", "lz4", "zstd"})));
  if (colon != std::string::npos) {
    const std::string level = text.substr(colon + 1);
    const auto [ptr, ec] = std::from_chars(level.data(), level.data() + level.size(), o.codec_level);
    if (ec != std::errc() || ptr != level.data() + level.size() || o.codec_level < 0 || o.codec_level > 22) {
      throw Error(fmt::format("`codec` '{}': level must be 0..22", text));
    }
  }
}

}  // namespace pstream::cook
