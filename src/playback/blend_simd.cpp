// The matched-record kernel of interpolation (interpolate.hpp), compiled once per SIMD target by
// Highway's foreach_target; the best one is chosen at run time.
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "playback/blend_simd.cpp"
#include <hwy/foreach_target.h>  // IWYU pragma: keep
#include <hwy/highway.h>

#include <algorithm>
#include <cstdint>
#include <cstring>

#include "playback/interpolate.hpp"

HWY_BEFORE_NAMESPACE();
namespace pstream::playback::HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

namespace {

float load(const std::byte* p) {
  float v;
  std::memcpy(&v, p, 4);
  return v;
}

// Words [from, to) of the run, one at a time (the run's ends, where a vector would reach across
// the run's first or last record).
void BlendWords(const LanePlan& p, const std::byte* a, const std::byte* b, std::size_t from, std::size_t to,
                std::byte* out) {
  const std::size_t s = p.shift;
  for (std::size_t x = from; x < to; ++x) {
    const std::size_t k = x % p.words;
    if (p.copy[k] != 0) {
      std::memcpy(out + 4 * x, a + 4 * x, 4);
      continue;
    }
    float v = p.sa[k] * load(a + 4 * x) + p.sb[k] * load(b + 4 * x);
    if (p.plus[k] != 0) v += p.pa[k] * load(a + 4 * (x + s)) + p.pb[k] * load(b + 4 * (x + s));
    if (p.minus[k] != 0) v += p.ma[k] * load(a + 4 * (x - s)) + p.mb[k] * load(b + 4 * (x - s));
    std::memcpy(out + 4 * x, &v, 4);
  }
}

}  // namespace

void BlendMatched(const LanePlan& p, const std::byte* a_bytes, const std::byte* b_bytes, std::size_t records,
                  std::byte* out_bytes) {
  const hn::ScalableTag<float> d;
  const hn::RebindToUnsigned<decltype(d)> du;
  using V = hn::Vec<decltype(d)>;
  const std::size_t lanes = hn::Lanes(d), n = records * p.words, s = p.shift;
  // Records are only 4-byte aligned: Highway's loads and stores are unaligned ones.
  const auto* a = reinterpret_cast<const float*>(a_bytes);
  const auto* b = reinterpret_cast<const float*>(b_bytes);
  auto* out = reinterpret_cast<float*>(out_bytes);
  // Vectors start at multiples of `lanes` (so a vector never wraps the tables, whose period is a
  // multiple of it), at or after `s` (the [-shift] loads stay in the run) and end `s` before its
  // end (the [+shift] loads too).
  const std::size_t first = (s + lanes - 1) / lanes * lanes;
  std::size_t x = first;
  if (n >= first + s + lanes) {
    const std::size_t end = n - s - lanes;  // the last vector starts at or before it
    std::size_t k = x % p.period;
    // The tables in locals: the stores to `out` cannot change them.
    const float *sa = p.sa.data(), *sb = p.sb.data(), *pa = p.pa.data(), *pb = p.pb.data();
    const float *ma = p.ma.data(), *mb = p.mb.data();
    const std::uint32_t *copy = p.copy.data(), *plus_lanes = p.plus.data(), *minus_lanes = p.minus.data();
    const auto lane_mask = [&](const std::uint32_t* m) {
      return hn::RebindMask(d, hn::Ne(hn::LoadU(du, m), hn::Zero(du)));
    };
    for (; x <= end; x += lanes) {
      const V va = hn::LoadU(d, a + x), vb = hn::LoadU(d, b + x);
      V r = hn::MulAdd(hn::LoadU(d, sb + k), vb, hn::Mul(hn::LoadU(d, sa + k), va));
      if (s != 0) {
        const V plus = hn::MulAdd(hn::LoadU(d, pb + k), hn::LoadU(d, b + x + s),
                                  hn::Mul(hn::LoadU(d, pa + k), hn::LoadU(d, a + x + s)));
        const V minus = hn::MulAdd(hn::LoadU(d, mb + k), hn::LoadU(d, b + x - s),
                                   hn::Mul(hn::LoadU(d, ma + k), hn::LoadU(d, a + x - s)));
        r = hn::Add(r, hn::IfThenElseZero(lane_mask(plus_lanes + k), plus));
        r = hn::Add(r, hn::IfThenElseZero(lane_mask(minus_lanes + k), minus));
      }
      // A copied lane keeps a's bits exactly (a select, no arithmetic on them).
      r = hn::IfThenElse(lane_mask(copy + k), va, r);
      hn::StoreU(r, d, out + x);
      k += lanes;
      if (k == p.period) k = 0;
    }
  } else {
    x = 0;
  }
  BlendWords(p, a_bytes, b_bytes, 0, std::min(first, n), out_bytes);
  BlendWords(p, a_bytes, b_bytes, std::max(x, std::min(first, n)), n, out_bytes);
}

}  // namespace pstream::playback::HWY_NAMESPACE
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace pstream::playback {

HWY_EXPORT(BlendMatched);

void blend_matched(const LanePlan& plan, const std::byte* a, const std::byte* b, std::size_t records, std::byte* out) {
  HWY_DYNAMIC_DISPATCH(BlendMatched)(plan, a, b, records, out);
}

}  // namespace pstream::playback
#endif
