// Frame codecs: the records unit, the decoder that picks a unit, and the particle codec's
// planning (what each record word becomes for a clip).
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>

#include <fmt/format.h>

#include "format/frame_unit.hpp"
#include "particlestream/codec.hpp"

namespace pstream::format {
namespace {

// The records codec: the packet is the frame's records.
class RecordsUnit final : public FrameUnit {
 public:
  RecordsUnit(const Metadata& meta, std::string_view name) : meta_(meta), name_(name) {}
  void decode(std::uint64_t frame, bool /*keyframe*/, std::span<const std::byte> packet,
              std::span<std::byte> out) override {
    const std::uint64_t size = meta_.frames[frame].count * meta_.record_size;
    if (packet.size() != size || out.size() < size) {
      throw Error(fmt::format("{}: frame {}: a records packet of {} bytes, expected {}", name_, frame, packet.size(),
                              size));
    }
    if (size != 0) std::memcpy(out.data(), packet.data(), size);
  }
  void reset() override {}
  std::uint64_t state_bytes() const override { return 0; }

 private:
  const Metadata& meta_;
  std::string_view name_;
};

}  // namespace

FramePacket frame_packet(const Metadata& meta, std::uint64_t frame) {
  const FrameEntry& f = meta.frames[frame];
  return {f.packet_offset, f.packet_size, f.keyframe};
}

std::uint64_t keyframe_of(const Metadata& meta, std::uint64_t frame) {
  while (frame > 0 && !meta.frames[frame].keyframe) --frame;
  return frame;
}

FrameDecoder::FrameDecoder(const Metadata& meta, std::string name) : meta_(meta), name_(std::move(name)) {
  switch (meta.codec.codec) {
    case FrameCodec::Records: unit_ = std::make_unique<RecordsUnit>(meta_, name_); break;
    case FrameCodec::Particle: unit_ = make_particle_unit(meta_, name_); break;
  }
  if (!unit_) throw Error(fmt::format("{}: unknown frame codec {}", name_, static_cast<int>(meta.codec.codec)));
  state_bytes_ = unit_->state_bytes();
}

FrameDecoder::~FrameDecoder() = default;

bool FrameDecoder::can_decode(std::uint64_t frame) const {
  return frame < meta_.frame_count() && (meta_.frames[frame].keyframe || (last_ != UINT64_MAX && frame == last_ + 1));
}

void FrameDecoder::reset() {
  unit_->reset();
  last_ = UINT64_MAX;
}

void FrameDecoder::decode(std::uint64_t frame, std::span<const std::byte> packet, std::span<std::byte> out) {
  if (!can_decode(frame)) {
    throw Error(fmt::format("{}: frame {} is predicted from frame {}, which was not decoded just before it", name_,
                            frame, frame == 0 ? 0 : frame - 1));
  }
  if (out.size() < meta_.frames[frame].count * meta_.record_size) {
    throw Error(fmt::format("{}: frame {}: {} bytes for {} records", name_, frame, out.size(),
                            meta_.frames[frame].count));
  }
  last_ = UINT64_MAX;  // a failed decode leaves no reference
  unit_->decode(frame, meta_.frames[frame].keyframe, packet, out);
  last_ = frame;
}

// ---- Clip statistics ----------------------------------------------------------------------------

ClipStats::ClipStats(const std::vector<Attribute>& layout) : layout_(layout), record_size_(record_size_of(layout)) {
  for (const Attribute& a : layout_) {
    first_component_.push_back(min_.size());
    const std::size_t n = a.type == AttributeType::Float32 ? a.components : 0;
    min_.insert(min_.end(), n, std::numeric_limits<float>::infinity());
    max_.insert(max_.end(), n, -std::numeric_limits<float>::infinity());
  }
  constant_.assign(layout_.size(), 1);
  value_.resize(record_size_);
}

void ClipStats::add(std::span<const std::byte> records, std::uint64_t count) {
  for (std::size_t a = 0; a < layout_.size(); ++a) {
    const Attribute& at = layout_[a];
    if (count > 0 && particles_ == 0) std::memcpy(value_.data() + at.offset, records.data() + at.offset, at.size());
    for (std::uint64_t i = 0; i < count; ++i) {
      const std::byte* r = records.data() + i * record_size_ + at.offset;
      if (constant_[a] && std::memcmp(r, value_.data() + at.offset, at.size()) != 0) constant_[a] = 0;
      if (at.type != AttributeType::Float32) continue;
      for (std::size_t c = 0; c < at.components; ++c) {
        float v;
        std::memcpy(&v, r + 4 * c, 4);
        float& lo = min_[first_component_[a] + c];
        float& hi = max_[first_component_[a] + c];
        if (std::isnan(v)) {  // no grid holds it: the attribute is kept exact
          lo = -std::numeric_limits<float>::infinity();
          hi = std::numeric_limits<float>::infinity();
        }
        lo = std::min(lo, v);
        hi = std::max(hi, v);
      }
    }
  }
  particles_ += count;
}

std::span<const std::byte> ClipStats::constant_value(std::size_t a) const {
  return std::span(value_).subspan(layout_[a].offset, layout_[a].size());
}

double ClipStats::diagonal() const {
  if (particles_ == 0) return 0.0;
  double sum = 0.0;
  for (std::size_t c = 0; c < 3; ++c) {
    const double e = double(max_[c]) - double(min_[c]);
    sum += e * e;
  }
  return std::sqrt(sum);
}

// ---- Planning -----------------------------------------------------------------------------------

namespace {

// A grid for values in [lo, hi] whose decoded floats stay within `error`: the step leaves room
// for the two roundings of the decoder's float arithmetic (one ulp of the largest magnitude
// each), and every value must fit 24 bits.
bool make_grid(double lo, double hi, double error, WordCodingEntry& e) {
  if (!std::isfinite(lo) || !std::isfinite(hi) || !(error > 0.0) || !std::isfinite(error)) return false;
  const float magnitude = static_cast<float>(std::max({std::abs(lo), std::abs(hi), hi - lo}));
  const double ulp = double(std::nextafter(magnitude, std::numeric_limits<float>::infinity())) - double(magnitude);
  const double step = 2.0 * (error - 2.0 * ulp);
  if (!(step > 0.0)) return false;
  e.coding = WordCoding::Quantized;
  e.step = static_cast<float>(step);
  if (double(e.step) > step) e.step = std::nextafter(e.step, 0.0f);
  e.error = static_cast<float>(error);
  if (double(e.error) > error) e.error = std::nextafter(e.error, 0.0f);
  const auto origin = static_cast<float>(lo);
  e.base = std::bit_cast<std::uint32_t>(origin);
  return (hi - double(origin)) / double(e.step) < double((1 << 24) - 2);
}

}  // namespace

CodecInfo plan_particle_codec(const std::vector<Attribute>& layout, const ClipStats& stats, double fps, bool has_ids,
                              const ParticleCodecOptions& options) {
  CodecInfo info;
  info.codec = FrameCodec::Particle;
  info.lossless = options.lossless;
  info.keyframe_interval = options.keyframe_interval;
  info.zstd_level = options.zstd_level;
  if (info.keyframe_interval < 1 || info.keyframe_interval > kMaxKeyframeInterval) {
    throw Error(fmt::format("the keyframe interval is {}, expected 1 to {}", info.keyframe_interval,
                            kMaxKeyframeInterval));
  }
  info.order = options.lossless ? FrameOrder::Source : has_ids ? FrameOrder::Id : FrameOrder::Matched;
  const std::uint32_t record_size = record_size_of(layout);
  info.words.resize(record_size / 4);
  const double diagonal = stats.diagonal();
  double position_error = 0.0;
  if (!options.lossless) {
    if (!(options.error > 0.0) || !std::isfinite(options.error)) {
      throw Error(fmt::format("the error bound is {}, expected a positive number", options.error));
    }
    position_error = options.error_relative ? options.error * diagonal : options.error;
  }
  // The same fraction of their own range for other float attributes.
  const double fraction = options.error_relative ? options.error : diagonal > 0 ? options.error / diagonal : 1e-4;
  info.error = position_error;
  std::size_t component = 0;
  for (std::size_t a = 0; a < layout.size(); ++a) {
    const Attribute& at = layout[a];
    const std::uint32_t first = at.offset / 4, words = static_cast<std::uint32_t>(at.size() / 4);
    const bool is_float = at.type == AttributeType::Float32;
    if (stats.particles() > 0 && stats.constant(a)) {
      const std::span<const std::byte> v = stats.constant_value(a);
      for (std::uint32_t w = 0; w < words; ++w) {
        info.words[first + w].coding = WordCoding::Constant;
        std::memcpy(&info.words[first + w].base, v.data() + 4 * w, 4);
      }
    } else if (at.name == "id" && at.type == AttributeType::Uint64 && info.order == FrameOrder::Id) {
      info.words[first].coding = info.words[first + 1].coding = WordCoding::Id;
    } else if (is_float && !options.lossless) {
      double error = 0.0;
      if (at.name == "position" || at.name == "scale")
        error = position_error;
      else if (at.name == "velocity")
        error = position_error * fps;
      for (std::uint32_t c = 0; c < at.components; ++c) {
        const double lo = stats.min()[component + c], hi = stats.max()[component + c];
        const double e = error > 0 ? error : fraction * (hi - lo);
        WordCodingEntry& entry = info.words[first + c];
        if (!make_grid(lo, hi, e, entry)) {
          if (at.name == "position") {
            throw Error(fmt::format(
                "positions span {}..{} on axis {}: an error bound of {} cannot be kept on a 24-bit grid at float "
                "precision; raise the error bound or use the lossless mode",
                lo, hi, "xyz"[c], e));
          }
          entry = WordCodingEntry{};  // kept exact: not finite, no range, or too fine a bound
        }
      }
    }
    if (is_float) component += at.components;
  }
  return info;
}

}  // namespace pstream::format
