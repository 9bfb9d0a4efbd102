#include "cook/direct_pack.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "cook/pack_simd.hpp"
#include "particlestream/error.hpp"

namespace pstream::cook {
namespace {

using DirectFrame = Source::DirectFrame;

constexpr std::size_t kRecordSize = 16;
// Particles per SIMD call; a block holding a NaN/Inf position is packed again one by one.
constexpr std::size_t kBlock = 16384;

// min xyz, max xyz
using Bounds = std::array<float, 6>;

template <bool kIdentity>
inline void position_of(const DirectFrame& d, std::uint64_t i, float out[3]) {
  for (int c = 0; c < 3; ++c) std::memcpy(&out[c], d.positions + i * 12 + c * 4, 4);
  if constexpr (!kIdentity) {  // the same double arithmetic as the general path
    const double x = out[0], y = out[1], z = out[2];
    const auto& m = d.matrix;
    for (int c = 0; c < 3; ++c) out[c] = static_cast<float>(x * m[0][c] + y * m[1][c] + z * m[2][c] + m[3][c]);
  }
}

template <bool kWidths>
inline float scale_of(const DirectFrame& d, std::uint64_t i) {
  if constexpr (kWidths) {
    float w;
    std::memcpy(&w, d.widths + i * 4, 4);
    return scale_from_width(w);
  } else {
    return d.constant_scale;
  }
}

// Packs particles one by one, checking each position: the finite ones are packed, the others
// counted; without `drop_invalid` it stops at the first. Returns the records written.
// Transformed positions always come this way, in the general path's double arithmetic (a SIMD
// kernel could fuse multiply-adds and give other floats).
template <bool kIdentity, bool kWidths>
std::size_t pack_checked(const DirectFrame& d, std::uint64_t first, std::size_t n, std::byte* dst, bool drop_invalid,
                         Bounds& b, std::uint64_t& invalid) {
  std::size_t written = 0;
  for (std::size_t k = 0; k < n; ++k) {
    float r[4];
    position_of<kIdentity>(d, first + k, r);
    if (!std::isfinite(r[0]) || !std::isfinite(r[1]) || !std::isfinite(r[2])) {
      ++invalid;
      if (!drop_invalid) return written;
      continue;
    }
    r[3] = scale_of<kWidths>(d, first + k);
    for (int c = 0; c < 3; ++c) {
      b[c] = std::min(b[c], r[c]);
      b[c + 3] = std::max(b[c + 3], r[c]);
    }
    // Stored as loaded, one float at a time: reading the record back as one 16-byte value after
    // smaller writes stalls store forwarding (perf showed 60% of this loop's time there).
    for (int c = 0; c < 4; ++c) std::memcpy(dst + written * kRecordSize + c * 4, &r[c], 4);
    ++written;
  }
  return written;
}

template <bool kIdentity, bool kWidths>
DirectPackResult pack_frame(const DirectFrame& d, bool drop_invalid, ChunkCutter& out) {
  constexpr float inf = std::numeric_limits<float>::infinity();
  Bounds b{inf, inf, inf, -inf, -inf, -inf};
  DirectPackResult result;
  for (std::uint64_t i = 0; i < d.count;) {
    // Chunk and buffer sizes are powers of two of at least 64 KiB, so a 16-byte record never
    // straddles a border and the room is never empty.
    const std::span<std::byte> room = out.room(kRecordSize);
    if (room.empty()) throw Error("cook: internal error: a 16-byte record across a chunk border");
    const std::size_t n =
        static_cast<std::size_t>(std::min<std::uint64_t>({room.size() / kRecordSize, kBlock, d.count - i}));
    std::byte* dst = room.data();
    std::size_t written = 0;
    if constexpr (kIdentity) {  // the SIMD kernel takes whole vectors; a block with NaN/Inf is redone
      const auto simd = pack_untransformed_records(d.positions + i * 12, kWidths ? d.widths + i * 4 : nullptr,
                                                   d.constant_scale, n, dst, b);
      written = simd.value_or(0);
    }
    written += pack_checked<kIdentity, kWidths>(d, i + written, n - written, dst + written * kRecordSize, drop_invalid,
                                                b, result.invalid);
    out.commit(written * kRecordSize);
    result.packed += written;
    if (result.invalid > 0 && !drop_invalid) break;
    i += n;
  }
  result.bounds = b;
  return result;
}

}  // namespace

DirectPackResult pack_direct(const DirectFrame& frame, bool drop_invalid, ChunkCutter& out) {
  if (frame.identity) {
    return frame.widths ? pack_frame<true, true>(frame, drop_invalid, out)
                        : pack_frame<true, false>(frame, drop_invalid, out);
  }
  return frame.widths ? pack_frame<false, true>(frame, drop_invalid, out)
                      : pack_frame<false, false>(frame, drop_invalid, out);
}

}  // namespace pstream::cook
