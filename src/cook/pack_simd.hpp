// SIMD kernel of the cooker's fast path (Highway, dispatched to the best target at run time).
#pragma once

#include <array>
#include <cstddef>

namespace pstream::cook {

// Packs `n` default records [x y z scale] from untransformed positions (float32 x3, any byte
// alignment) and widths (float32, scale = width / 2; null: every scale is `constant_scale`)
// into `dst`, widening `bounds` (min xyz, max xyz). Returns false when some position is not
// finite: `bounds` is then untouched and `dst` must be written again.
bool pack_untransformed_records(const std::byte* positions, const std::byte* widths, float constant_scale,
                                std::size_t n, std::byte* dst, std::array<float, 6>& bounds);

}  // namespace pstream::cook
