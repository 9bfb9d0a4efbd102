// Codec specs ("particle:9", "zstd:5", "raw"): the names the cook's users write, read into
// Options in one place for the command line and the bindings.
#include <algorithm>
#include <charconv>
#include <cmath>
#include <optional>

#include <fmt/format.h>

#include "base/names.hpp"
#include "particlestream/cook.hpp"

namespace pstream::cook {
namespace {

// All of `text` as a number, or nothing when it holds no number or more than one.
template <class T>
std::optional<T> whole_number(std::string_view text) {
  T value{};
  const auto [ptr, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || ptr != text.data() + text.size()) return std::nullopt;
  return value;
}

}  // namespace

void set_codec(Options& o, std::string_view spec) {
  const std::string text(spec);
  const auto colon = text.find(':');
  const std::string name = text.substr(0, colon);
  if (name == "particle" || name == "particle-lossless") {
    o.frame_codec = format::FrameCodec::Particle;
    o.particle.lossless = name == "particle-lossless";
    if (colon != std::string::npos) {  // the entropy stage's zstd level
      const std::optional<int> level = whole_number<int>(std::string_view(text).substr(colon + 1));
      if (!level || *level < 1 || *level > 22) {
        throw Error(
            fmt::format("`codec` '{}': the particle codec's zstd level must be 1..22 (default {} with ids, {} without, "
                        "lossless {})",
                        text, format::kDefaultParticleZstdLevel, format::kDefaultMatchedParticleZstdLevel,
                        format::kDefaultLosslessParticleZstdLevel));
      }
      o.particle.zstd_level = *level;
    }
    return;
  }
  // The records codec: each frame's records as they are, chunks compressed by this.
  if (name == "raw" || name == "lz4" || name == "zstd") o.frame_codec = format::FrameCodec::Records;
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
    const std::optional<int> level = whole_number<int>(std::string_view(text).substr(colon + 1));
    if (!level || *level < 0 || *level > 22) throw Error(fmt::format("`codec` '{}': level must be 0..22", text));
    o.codec_level = *level;
  }
}

}  // namespace pstream::cook

namespace pstream::cook {

void set_error_bound(Options& o, std::string_view spec, std::string_view what) {
  std::string number(spec);
  bool relative = true;
  if (number.rfind("abs:", 0) == 0 || number.rfind("rel:", 0) == 0) {
    relative = number[0] == 'r';
    number = number.substr(4);
  }
  const double value = whole_number<double>(number).value_or(0.0);
  if (!(value > 0) || !std::isfinite(value) || (relative && value >= 1)) {
    throw Error(
        fmt::format("{} '{}': expected a fraction of the bounds diagonal such as 1e-4 (or rel:1e-4), or abs:VALUE in "
                    "scene units",
                    what, spec));
  }
  o.particle.error = value;
  o.particle.error_relative = relative;
}

void set_scale_error(Options& o, std::string_view spec, std::string_view what) {
  std::string number(spec);
  const bool percent = !number.empty() && number.back() == '%';
  if (percent) number.pop_back();
  const double value = whole_number<double>(number).value_or(0.0) / (percent ? 100.0 : 1.0);
  if (!(value > 0) || !(value < 0.5)) {
    throw Error(fmt::format(
        "{} '{}': expected the bound on each particle's scale relative to itself, such as 1% or 0.01 (above 0, "
        "below 50%)",
        what, spec));
  }
  o.particle.scale_error = value;
}

void set_attribute_error(Options& o, std::string_view spec, std::string_view what) {
  const double value = whole_number<double>(spec).value_or(0.0);
  if (!(value > 0) || !(value < 1)) {
    throw Error(fmt::format(
        "{} '{}': expected the bound on velocity and other float attributes as a fraction of their own range, such "
        "as 1e-3 (above 0, below 1)",
        what, spec));
  }
  o.particle.attribute_error = value;
}

void set_scale_from(Options& o, std::string_view spec, std::string_view what) {
  const std::string text(spec);
  if (text == "widths") {
    o.scale_from = ScaleFrom::Widths;
  } else if (text.rfind("constant:", 0) == 0) {
    const float value = whole_number<float>(std::string_view(text).substr(9)).value_or(0.0f);
    if (!(value > 0) || !std::isfinite(value))
      throw Error(fmt::format("{} '{}': expected constant:X with X a positive number (the radius)", what, text));
    o.scale_from = ScaleFrom::Constant;
    o.scale_constant = value;
  } else if (text.rfind("attr:", 0) == 0 && text.size() > 5) {
    o.scale_from = ScaleFrom::Attribute;
    o.scale_attribute = text.substr(5);
  } else {
    throw Error(fmt::format("{} '{}': expected widths, constant:X or attr:NAME{}", what, text,
                            did_you_mean(text, {"widths", "constant:", "attr:"})));
  }
}

void add_attributes(Options& o, std::string_view list) {
  for (std::size_t at = 0; at <= list.size();) {
    const std::size_t comma = std::min(list.find(',', at), list.size());
    if (comma > at) o.attributes.emplace_back(list.substr(at, comma - at));
    at = comma + 1;
  }
}

void set_frames(Options& o, std::string_view spec, std::string_view what) {
  const auto [begin, end] = parse_frame_range(spec, what);
  o.frame_begin = begin;
  o.frame_end = end;
}

}  // namespace pstream::cook
