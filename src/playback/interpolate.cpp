#include "playback/interpolate.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>

namespace pstream::playback {
namespace {

float load(const std::byte* p) {
  float v;
  std::memcpy(&v, p, 4);
  return v;
}
void store(std::byte* p, float v) { std::memcpy(p, &v, 4); }

std::uint64_t id_of(const RecordFields& f, const std::byte* record) {
  if (f.id64) {
    std::uint64_t v;
    std::memcpy(&v, record + f.id, 8);
    return v;
  }
  std::uint32_t v;
  std::memcpy(&v, record + f.id, 4);
  return v;
}

// Moves a record's position by its velocity times `seconds` and scales its size by `grow`.
void advect(const RecordFields& f, std::byte* r, double seconds, float grow) {
  if (f.velocity >= 0) {
    for (int c = 0; c < 3; ++c) store(r + 4 * c, float(load(r + 4 * c) + seconds * load(r + f.velocity + 4 * c)));
  }
  store(r + 12, load(r + 12) * grow);
}

// The Hermite basis at t, computed once per frame pair.
struct Basis {
  float t, h00, h10, h01, h11;
  explicit Basis(double t_, double dt) : t(float(t_)) {
    const double t2 = t_ * t_, t3 = t2 * t_;
    h00 = float(2 * t3 - 3 * t2 + 1);
    h10 = float((t3 - 2 * t2 + t_) * dt);  // the tangents are velocities x dt
    h01 = float(-2 * t3 + 3 * t2);
    h11 = float((t3 - t2) * dt);
  }
};

void blend(const RecordFields& f, const std::byte* a, const std::byte* b, const Basis& k, bool hermite,
           std::byte* out) {
  std::memcpy(out, a, f.stride);
  float pa[3], pb[3], p[3];
  std::memcpy(pa, a, 12);
  std::memcpy(pb, b, 12);
  if (hermite) {
    float va[3], vb[3];
    std::memcpy(va, a + f.velocity, 12);
    std::memcpy(vb, b + f.velocity, 12);
    for (int c = 0; c < 3; ++c) p[c] = k.h00 * pa[c] + k.h10 * va[c] + k.h01 * pb[c] + k.h11 * vb[c];
  } else {
    for (int c = 0; c < 3; ++c) p[c] = pa[c] + (pb[c] - pa[c]) * k.t;
  }
  std::memcpy(out, p, 12);
  for (const auto& fl : f.floats) {
    for (std::uint32_t c = 0; c < fl.count; ++c) {
      const std::uint32_t o = fl.offset + 4 * c;
      const float x = load(a + o);
      store(out + o, x + (load(b + o) - x) * k.t);
    }
  }
  if (f.color >= 0) {
    for (int c = 0; c < 4; ++c) {
      const auto ca = static_cast<float>(std::to_integer<int>(a[f.color + c]));
      const auto cb = static_cast<float>(std::to_integer<int>(b[f.color + c]));
      out[f.color + c] = static_cast<std::byte>(int(ca + (cb - ca) * k.t + 0.5f));
    }
  }
}

}  // namespace

RecordFields RecordFields::of(const format::Metadata& m) {
  RecordFields f;
  f.stride = m.record_size;
  for (const format::Attribute& a : m.layout) {
    if (a.name == "position") continue;
    if (a.name == "velocity" && a.type == format::AttributeType::Float32 && a.components == 3) {
      f.velocity = std::int32_t(a.offset);
      f.floats.push_back({a.offset, 3});  // blended linearly too
    } else if (a.name == "id" && (a.type == format::AttributeType::Uint64 || a.type == format::AttributeType::Uint32)) {
      f.id = std::int32_t(a.offset);
      f.id64 = a.type == format::AttributeType::Uint64;
    } else if (a.name == "color" && a.type == format::AttributeType::Unorm8 && a.components == 4) {
      f.color = std::int32_t(a.offset);
    } else if (a.type == format::AttributeType::Float32) {
      f.floats.push_back({a.offset, a.components});  // scale and any float attribute
    }
  }
  return f;
}

namespace {

// No matching: the nearer frame, moved along its velocities to the playhead.
std::uint64_t nearer_advected(const RecordFields& f, std::span<const std::byte> a, std::uint64_t na,
                              std::span<const std::byte> b, std::uint64_t nb, double t, double dt, std::byte* out) {
  const bool first = t < 0.5;
  const std::span<const std::byte> from = first ? a : b;
  const std::uint64_t n = first ? na : nb;
  std::memcpy(out, from.data(), n * f.stride);
  if (f.velocity >= 0) {
    for (std::uint64_t i = 0; i < n; ++i) advect(f, out + i * f.stride, first ? t * dt : -(1.0 - t) * dt, 1.0f);
  }
  return n;
}

}  // namespace

std::uint64_t interpolate_frames(const RecordFields& f, std::span<const std::byte> a, std::uint64_t na,
                                 std::span<const std::byte> b, std::uint64_t nb, double t, double dt,
                                 Interpolation mode, std::byte* out) {
  const std::size_t stride = f.stride;
  if (f.id < 0) return nearer_advected(f, a, na, b, nb, t, dt, out);
  const Basis basis(t, dt);
  const bool hermite = mode == Interpolation::Hermite && f.velocity >= 0;
  // One pass: the merge also checks that the ids ascend (a separate check would read both frames
  // once more); when they do not, the frames cannot be matched this way.
  std::uint64_t i = 0, j = 0, n = 0;
  std::uint64_t ia = na ? id_of(f, a.data()) : UINT64_MAX, ib = nb ? id_of(f, b.data()) : UINT64_MAX;
  const auto next_a = [&] {
    ++i;
    const std::uint64_t id = i < na ? id_of(f, a.data() + i * stride) : UINT64_MAX;
    const bool ascending = id > ia || (i >= na);
    ia = id;
    return ascending;
  };
  const auto next_b = [&] {
    ++j;
    const std::uint64_t id = j < nb ? id_of(f, b.data() + j * stride) : UINT64_MAX;
    const bool ascending = id > ib || (j >= nb);
    ib = id;
    return ascending;
  };
  while (i < na || j < nb) {
    std::byte* o = out + n * stride;
    bool ascending = true;
    if (i < na && j < nb && ia == ib) {
      blend(f, a.data() + i * stride, b.data() + j * stride, basis, hermite, o);
      ascending = next_a() && next_b();
    } else if (j >= nb || (i < na && ia < ib)) {  // dies before b: goes on, shrinking out
      std::memcpy(o, a.data() + i * stride, stride);
      advect(f, o, t * dt, float(1.0 - t));
      ascending = next_a();
    } else {  // born after a: comes in, growing
      std::memcpy(o, b.data() + j * stride, stride);
      advect(f, o, -(1.0 - t) * dt, float(t));
      ascending = next_b();
    }
    ++n;
    if (!ascending) return nearer_advected(f, a, na, b, nb, t, dt, out);
  }
  return n;
}

}  // namespace pstream::playback
