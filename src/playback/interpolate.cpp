#include "playback/interpolate.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>

namespace pstream::playback {
namespace {

// What a lane (a 4-byte word of a record) is (frame.hpp: RecordLane).
enum Lane : std::uint8_t { kCopy, kLerp, kPosition, kVelocity };
static_assert(kCopy == std::uint8_t(render::RecordLane::Copy) && kLerp == std::uint8_t(render::RecordLane::Lerp) &&
              kPosition == std::uint8_t(render::RecordLane::Position) &&
              kVelocity == std::uint8_t(render::RecordLane::Velocity));

float load(const std::byte* p) {
  float v;
  std::memcpy(&v, p, 4);
  return v;
}
void store(std::byte* p, float v) { std::memcpy(p, &v, 4); }

}  // namespace

std::vector<render::RecordLane> record_lanes(const format::Metadata& m) {
  std::vector<render::RecordLane> kind(m.record_size / 4, render::RecordLane::Copy);  // whole words (format.md)
  for (std::size_t w = 0; w < 3; ++w) kind[render::kPositionOffset / 4 + w] = render::RecordLane::Position;
  for (const format::Attribute& a : m.layout) {
    if (a.name == "position") continue;
    if (a.name == "velocity" && a.type == format::AttributeType::Float32 && a.components == 3) {
      for (std::size_t c = 0; c < 3; ++c) kind[a.offset / 4 + c] = render::RecordLane::Velocity;
    } else if (a.type == format::AttributeType::Float32) {
      for (std::size_t c = 0; c < a.components; ++c) kind[a.offset / 4 + c] = render::RecordLane::Lerp;
    }
  }
  return kind;
}

std::uint64_t pair_table(std::uint64_t na, std::uint64_t nb, const std::span<const format::MatchRun>* matching,
                         double t, std::span<render::ParticlePair> out, bool& nearer) {
  std::uint64_t covers_a = 0, covers_b = 0;
  if (matching != nullptr) {
    for (const format::MatchRun& r : *matching)
      covers_a += std::uint64_t(r.keep) + r.drop, covers_b += std::uint64_t(r.keep) + r.insert;
  }
  nearer = matching == nullptr || covers_a != na || covers_b != nb;
  std::uint64_t n = 0;
  if (nearer) {  // as FrameBlender::nearer_advected
    const bool first = t < 0.5;
    const std::uint64_t count = first ? na : nb;
    for (std::uint64_t i = 0; i < count; ++i)
      out[n++] = first ? render::ParticlePair{std::uint32_t(i), render::kNoParticle}
                       : render::ParticlePair{render::kNoParticle, std::uint32_t(i)};
    return n;
  }
  std::uint32_t i = 0, j = 0;
  for (const format::MatchRun& r : *matching) {
    for (std::uint32_t k = 0; k < r.keep; ++k) out[n++] = {i++, j++};
    for (std::uint32_t k = 0; k < r.drop; ++k) out[n++] = {i++, render::kNoParticle};
    for (std::uint32_t k = 0; k < r.insert; ++k) out[n++] = {render::kNoParticle, j++};
  }
  return n;
}

FrameBlender::FrameBlender(const format::Metadata& m) : stride_(m.record_size) {
  const std::size_t words = stride_ / 4;
  const std::vector<render::RecordLane> lanes = record_lanes(m);
  kind_.resize(words);
  for (std::size_t w = 0; w < words; ++w) kind_[w] = std::uint8_t(lanes[w]);
  velocity_ = velocity_offset(m);
  color_ = color_offset(m);
  plan_.words = words;
  plan_.shift = velocity_ >= 0 ? std::size_t(velocity_) / 4 : 0;
  plan_.period = words * LanePlan::kMaxVectorLanes;
  for (auto* v : {&plan_.sa, &plan_.sb, &plan_.pa, &plan_.pb, &plan_.ma, &plan_.mb}) v->assign(plan_.period, 0.0f);
  for (auto* v : {&plan_.copy, &plan_.plus, &plan_.minus}) v->assign(plan_.period, 0u);
}

void FrameBlender::set_fraction(double t, double dt, bool hermite) {
  if (t == plan_t_ && dt == plan_dt_ && hermite == plan_hermite_) return;
  plan_t_ = t, plan_dt_ = dt, plan_hermite_ = hermite;
  const double t2 = t * t, t3 = t2 * t;
  // The cubic Hermite basis (tangents are velocity x dt) and its derivative over time.
  const double h00 = 2 * t3 - 3 * t2 + 1, h10 = (t3 - 2 * t2 + t) * dt, h01 = -2 * t3 + 3 * t2, h11 = (t3 - t2) * dt;
  const double d00 = (6 * t2 - 6 * t) / dt, d10 = 3 * t2 - 4 * t + 1, d01 = (6 * t - 6 * t2) / dt, d11 = 3 * t2 - 2 * t;
  LanePlan& p = plan_;
  for (std::size_t k = 0; k < p.period; ++k) {
    Lane kind = Lane(kind_[k % p.words]);
    if (!hermite && (kind == kPosition || kind == kVelocity)) kind = kLerp;
    p.sa[k] = p.sb[k] = p.pa[k] = p.pb[k] = p.ma[k] = p.mb[k] = 0.0f;
    p.copy[k] = p.plus[k] = p.minus[k] = 0;
    switch (kind) {
      case kCopy: p.copy[k] = ~0u; break;
      case kLerp: p.sa[k] = float(1.0 - t), p.sb[k] = float(t); break;
      case kPosition:
        p.sa[k] = float(h00), p.sb[k] = float(h01), p.pa[k] = float(h10), p.pb[k] = float(h11), p.plus[k] = ~0u;
        break;
      case kVelocity:
        p.sa[k] = float(d10), p.sb[k] = float(d11), p.ma[k] = float(d00), p.mb[k] = float(d01), p.minus[k] = ~0u;
        break;
    }
  }
}

// Moves a record's position by its velocity times `seconds` and scales its size by `grow`.
void FrameBlender::advect(std::byte* r, double seconds, float grow) const {
  if (velocity_ >= 0) {
    for (int c = 0; c < 3; ++c) store(r + 4 * c, float(load(r + 4 * c) + seconds * load(r + velocity_ + 4 * c)));
  }
  store(r + render::kScaleOffset, load(r + render::kScaleOffset) * grow);
}

void FrameBlender::blend_colors(const std::byte* a, const std::byte* b, std::size_t records, float t,
                                std::byte* out) const {
  for (std::size_t i = 0; i < records; ++i) {
    const std::size_t o = i * stride_ + std::size_t(color_);
    for (std::size_t c = 0; c < 4; ++c) {
      const auto ca = static_cast<float>(std::to_integer<int>(a[o + c]));
      const auto cb = static_cast<float>(std::to_integer<int>(b[o + c]));
      out[o + c] = static_cast<std::byte>(int(ca + (cb - ca) * t + 0.5f));
    }
  }
}

// No matching: the nearer frame, moved along its velocities to the playhead.
std::uint64_t FrameBlender::nearer_advected(std::span<const std::byte> a, std::uint64_t na,
                                            std::span<const std::byte> b, std::uint64_t nb, double t, double dt,
                                            std::byte* out) const {
  const bool first = t < 0.5;
  const std::span<const std::byte> from = first ? a : b;
  const std::uint64_t n = first ? na : nb;
  if (n > 0) std::memcpy(out, from.data(), n * stride_);  // an empty frame may have no storage at all
  if (velocity_ >= 0) {
    for (std::uint64_t i = 0; i < n; ++i) advect(out + i * stride_, first ? t * dt : -(1.0 - t) * dt, 1.0f);
  }
  return n;
}

std::int32_t velocity_offset(const format::Metadata& meta) {
  const format::Attribute* v = meta.find("velocity");
  return v != nullptr && v->type == format::AttributeType::Float32 && v->components == 3 ? std::int32_t(v->offset) : -1;
}

std::int32_t color_offset(const format::Metadata& meta) {
  const format::Attribute* c = meta.find("color");
  return c != nullptr && c->type == format::AttributeType::Unorm8 && c->components == 4 ? std::int32_t(c->offset) : -1;
}

bool velocities_describe_matching(std::span<const std::byte> a, std::span<const std::byte> b,
                                  std::span<const format::MatchRun> matching, std::uint32_t stride,
                                  std::int32_t velocity_offset, double dt) {
  if (velocity_offset < 0) return false;
  std::uint64_t kept = 0;
  for (const format::MatchRun& r : matching) kept += r.keep;
  if (kept == 0) return false;
  // Pair k * every + every / 2 of the kept ones, k = 0, 1, ...: at most kMotionSample of them.
  const std::uint64_t every = (kept + kMotionSample - 1) / kMotionSample;
  const auto velocity = [&](const std::byte* r, int c) { return double(load(r + velocity_offset + 4 * c)); };
  double along = 0.0, still = 0.0;
  std::uint64_t i = 0, j = 0, seen = 0, next = every / 2;
  for (const format::MatchRun& r : matching) {
    for (; next < seen + r.keep; next += every) {
      const std::uint64_t t = next - seen;
      const std::size_t ia = std::size_t(i + t) * stride, ib = std::size_t(j + t) * stride;
      if (ia + stride > a.size() || ib + stride > b.size()) return false;  // runs beyond the frames
      const std::byte* ra = a.data() + ia;
      const std::byte* rb = b.data() + ib;
      for (int c = 0; c < 3; ++c) {
        const double step = double(load(rb + 4 * c)) - double(load(ra + 4 * c));
        const double moved = step - 0.5 * dt * (velocity(ra, c) + velocity(rb, c));
        along += moved * moved;
        still += step * step;
      }
    }
    seen += r.keep;
    i += std::uint64_t(r.keep) + r.drop;
    j += std::uint64_t(r.keep) + r.insert;
  }
  return along < still;
}

std::uint64_t FrameBlender::blend(std::span<const std::byte> a, std::uint64_t na, std::span<const std::byte> b,
                                  std::uint64_t nb, const std::span<const format::MatchRun>* matching, double t,
                                  double dt, bool curves, std::byte* out) {
  if (matching == nullptr) return nearer_advected(a, na, b, nb, t, dt, out);
  // The runs must cover both frames exactly (the stream's are; a caller's might not be).
  std::uint64_t covers_a = 0, covers_b = 0;
  for (const format::MatchRun& r : *matching)
    covers_a += std::uint64_t(r.keep) + r.drop, covers_b += std::uint64_t(r.keep) + r.insert;
  if (covers_a != na || covers_b != nb) return nearer_advected(a, na, b, nb, t, dt, out);
  set_fraction(t, dt, curves && velocity_ >= 0);
  const std::size_t stride = stride_;
  const std::byte* pa = a.data();
  const std::byte* pb = b.data();
  std::uint64_t i = 0, j = 0, n = 0;
  for (const format::MatchRun& r : *matching) {
    if (r.keep != 0) {  // the same particles in both frames, in the same order: one kernel
      blend_matched(plan_, pa + i * stride, pb + j * stride, r.keep, out + n * stride);
      if (color_ >= 0) blend_colors(pa + i * stride, pb + j * stride, r.keep, float(t), out + n * stride);
      i += r.keep, j += r.keep, n += r.keep;
    }
    for (std::uint32_t k = 0; k < r.drop; ++k, ++i, ++n) {  // dies before b: goes on, shrinking out
      std::memcpy(out + n * stride, pa + i * stride, stride);
      advect(out + n * stride, t * dt, float(1.0 - t));
    }
    for (std::uint32_t k = 0; k < r.insert; ++k, ++j, ++n) {  // born after a: comes in, growing
      std::memcpy(out + n * stride, pb + j * stride, stride);
      advect(out + n * stride, -(1.0 - t) * dt, float(t));
    }
  }
  return n;
}

}  // namespace pstream::playback
