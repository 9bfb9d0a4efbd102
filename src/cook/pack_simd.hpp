// SIMD kernel of the cooker's fast path (Highway, dispatched to the best target at run time).
#pragma once

#include <array>
#include <cstddef>
#include <optional>

namespace pstream::cook {

// Packs default records [x y z scale] for the leading particles of `n` that fill whole SIMD
// vectors, from untransformed positions (float32 x3, any byte alignment) and widths (float32,
// scale = width / 2; null: every scale is `constant_scale`), into `dst`, widening `bounds`
// (min xyz, max xyz). Returns how many particles it packed (the caller packs the few left), or
// nothing when one of them is not finite: `bounds` is then untouched and `dst` must be written
// again.
std::optional<std::size_t> pack_untransformed_records(const std::byte* positions, const std::byte* widths,
                                                      float constant_scale, std::size_t n, std::byte* dst,
                                                      std::array<float, 6>& bounds);

}  // namespace pstream::cook
