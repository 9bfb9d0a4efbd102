// Sub-frame interpolation of particle records between two cached frames (docs/playback.md).
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "particlestream/format.hpp"
#include "particlestream/playback.hpp"

namespace pstream::playback {

// Where the fields interpolation needs are in a record, from the clip's layout.
struct RecordFields {
  std::uint32_t stride = 16;
  std::int32_t velocity = -1;  // float32 x3
  std::int32_t id = -1;        // uint64 or uint32
  bool id64 = true;
  std::int32_t color = -1;  // unorm8 x4
  struct Floats {
    std::uint32_t offset, count;
  };
  std::vector<Floats> floats;  // every other float32 attribute, blended linearly (scale included)
  static RecordFields of(const format::Metadata& m);
};

// The particles at `t` (0..1) of the way from frame `a` (na records) to frame `b` (nb records),
// `dt` seconds apart, written to `out` (room for na + nb records). Returns how many.
// - Ids in both frames, ascending: matched by a linear merge. A particle in both moves along the
//   cubic Hermite curve of its positions and velocities (`mode` Hermite, velocities present) or
//   the straight line; other floats and colours blend linearly. One only in `a` dies: it goes on
//   along its velocity and shrinks to nothing by `b`. One only in `b` is born: it comes in along
//   its velocity from where it would have been, growing from nothing.
// - No ids (or not ascending): the nearer frame, moved along its velocities to `t` when the clip
//   has velocities, as it is otherwise.
std::uint64_t interpolate_frames(const RecordFields& fields, std::span<const std::byte> a, std::uint64_t na,
                                 std::span<const std::byte> b, std::uint64_t nb, double t, double dt,
                                 Interpolation mode, std::byte* out);

}  // namespace pstream::playback
