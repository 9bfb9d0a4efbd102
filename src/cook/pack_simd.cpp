// Compiled once per SIMD target by Highway's foreach_target; the best one is chosen at run time.
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "cook/pack_simd.cpp"
#include <hwy/foreach_target.h>  // IWYU pragma: keep
#include <hwy/highway.h>

#include <cstdint>

#include "cook/pack_simd.hpp"

HWY_BEFORE_NAMESPACE();
namespace pstream::cook::HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

// |x| as bits at or above this: Inf or NaN. An integer max of |bits| catches NaN as well,
// which float min/max would not.
constexpr std::int32_t kExponentAllOnes = 0x7f800000;

std::optional<std::size_t> PackUntransformed(const std::byte* positions, const std::byte* widths, float constant_scale,
                                             std::size_t n, std::byte* dst, std::array<float, 6>& bounds) {
  const hn::ScalableTag<float> d;
  const hn::RebindToSigned<decltype(d)> di;
  using V = hn::Vec<decltype(d)>;
  const std::size_t lanes = hn::Lanes(d);
  // The mapped source is only byte-aligned: Highway's loads are unaligned ones.
  const auto* p = reinterpret_cast<const float*>(positions);
  const auto* w = reinterpret_cast<const float*>(widths);
  auto* out = reinterpret_cast<float*>(dst);
  V lo_x = hn::Set(d, bounds[0]), lo_y = hn::Set(d, bounds[1]), lo_z = hn::Set(d, bounds[2]);
  V hi_x = hn::Set(d, bounds[3]), hi_y = hn::Set(d, bounds[4]), hi_z = hn::Set(d, bounds[5]);
  const auto abs_bits = hn::Set(di, 0x7fffffff);
  auto worst = hn::Zero(di);
  const V half = hn::Set(d, 0.5f), constant = hn::Set(d, constant_scale);
  std::size_t i = 0;
  for (; i + lanes <= n; i += lanes) {
    V x, y, z;
    hn::LoadInterleaved3(d, p + 3 * i, x, y, z);
    const V s = widths != nullptr ? hn::Mul(hn::LoadU(d, w + i), half) : constant;  // scale_from_width()
    worst = hn::Max(worst, hn::And(hn::BitCast(di, x), abs_bits));
    worst = hn::Max(worst, hn::And(hn::BitCast(di, y), abs_bits));
    worst = hn::Max(worst, hn::And(hn::BitCast(di, z), abs_bits));
    lo_x = hn::Min(lo_x, x), lo_y = hn::Min(lo_y, y), lo_z = hn::Min(lo_z, z);
    hi_x = hn::Max(hi_x, x), hi_y = hn::Max(hi_y, y), hi_z = hn::Max(hi_z, z);
    hn::StoreInterleaved4(x, y, z, s, d, out + 4 * i);
  }
  if (hn::GetLane(hn::MaxOfLanes(di, worst)) >= kExponentAllOnes) return std::nullopt;
  bounds = {hn::GetLane(hn::MinOfLanes(d, lo_x)), hn::GetLane(hn::MinOfLanes(d, lo_y)),
            hn::GetLane(hn::MinOfLanes(d, lo_z)), hn::GetLane(hn::MaxOfLanes(d, hi_x)),
            hn::GetLane(hn::MaxOfLanes(d, hi_y)), hn::GetLane(hn::MaxOfLanes(d, hi_z))};
  return i;
}

}  // namespace pstream::cook::HWY_NAMESPACE
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace pstream::cook {

HWY_EXPORT(PackUntransformed);

std::optional<std::size_t> pack_untransformed_records(const std::byte* positions, const std::byte* widths,
                                                      float constant_scale, std::size_t n, std::byte* dst,
                                                      std::array<float, 6>& bounds) {
  return HWY_DYNAMIC_DISPATCH(PackUntransformed)(positions, widths, constant_scale, n, dst, bounds);
}

}  // namespace pstream::cook
#endif
