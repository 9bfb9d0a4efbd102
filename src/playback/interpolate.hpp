// Sub-frame interpolation of particle records between two cached frames (docs/playback.md).
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "particlestream/codec.hpp"
#include "particlestream/format.hpp"
#include "particlestream/playback.hpp"

namespace pstream::playback {

// How each 4-byte word ("lane") of a matched particle's record is made from that particle's
// records `a` and `b` in the two frames. A lane is either copied from `a` (ids, colours, other
// integers) or is the weighted sum
//   sa*a[w] + sb*b[w] + pa*a[w+shift] + pb*b[w+shift] + ma*a[w-shift] + mb*b[w-shift]
// where `shift` is the distance from position to velocity in words: a position lane reaches its
// velocity (the Hermite tangents), a velocity lane its position (the curve's derivative). The
// coefficients depend only on the fraction, so they are set once per frame pair; the tables repeat
// every `period` words (a whole number of records and of SIMD vectors), so one vector loop runs
// over a whole run of matched records as if it were one array of floats.
struct LanePlan {
  static constexpr std::size_t kMaxVectorLanes = 16;  // AVX-512 floats; the period fits any target
  std::size_t words = 0;                              // per record
  std::size_t shift = 0;                              // velocity offset - position offset, in words (0: none)
  std::size_t period = 0;                             // words * kMaxVectorLanes
  std::vector<float> sa, sb, pa, pb, ma, mb;          // `period` entries each
  std::vector<std::uint32_t> copy, plus, minus;       // all ones where a lane copies / uses [+shift] / [-shift]
};

// Blends `records` matched records (`a` and `b` hold them in the same order, `out` receives them)
// lane by lane as `plan` says (SIMD: Highway, the best target chosen at run time). Colours are not
// touched (copied from `a` as every copy lane is): the caller blends them.
void blend_matched(const LanePlan& plan, const std::byte* a, const std::byte* b, std::size_t records, std::byte* out);

// What interpolation does with each word of `meta`'s records (frame.hpp: RecordLane).
std::vector<render::RecordLane> record_lanes(const format::Metadata& meta);

// The pair table of the GPU path for the frame FrameBlender::blend() would make: `out` (room for
// na + nb) receives, in blend()'s order, each particle's indices in frames a and b. Returns the
// count; `nearer` is set when there is no (covering) matching, so the nearer frame alone is shown,
// moved along its velocities without shrinking (blend()'s fallback).
std::uint64_t pair_table(std::uint64_t na, std::uint64_t nb, const std::span<const format::MatchRun>* matching,
                         double t, std::span<render::ParticlePair> out, bool& nearer);

// Whether the velocities describe the matching from frame `a` to frame `b` (`stride`-byte records,
// velocity float32 x3 at `velocity_offset`, `dt` seconds apart): over up to kMotionSample matched
// pairs spread evenly over the runs, the steps from a to b are closer, in the sum of their squares,
// to dt times the pair's mean velocity than to no motion at all. Particles at rest weigh nothing
// either way. It holds for particles that persist (every clip with ids, and caches without ids whose
// particles are the same from frame to frame). It fails where the solver re-samples its particles
// (Mantaflow's FLIP liquid: a particle is paired with a neighbour about 1 cm away while its velocity
// moves it 5-10 cm a frame), and a Hermite curve through such a pair's velocities swings it
// forward along the flow and back by up to a tenth of a frame's motion (5-7 mm on the FLIP
// fixture): such pairs of frames are blended along straight lines (docs/playback.md).
inline constexpr std::uint64_t kMotionSample = 256;
// The record offset of a clip's velocity (three float32 named "velocity"), the one interpolation,
// speed colours and motion blur read; -1 when it has none.
std::int32_t velocity_offset(const format::Metadata& meta);
// The record offset of a clip's colour (four unorm8 named "color", RGBA), the one the renderers,
// the blends and the C API's batches read; -1 when it has none (another type of "color" is an
// attribute like any other: the clip draws in its stream's colour).
std::int32_t color_offset(const format::Metadata& meta);
bool velocities_describe_matching(std::span<const std::byte> a, std::span<const std::byte> b,
                                  std::span<const format::MatchRun> matching, std::uint32_t stride,
                                  std::int32_t velocity_offset, double dt);

// A pair of cached frames' answer to whether they blend along curves (Hermite through the
// velocities, where velocities_describe_matching() holds), asked every host frame and worked out
// once a pair: the player keeps one a clip, for its CPU and GPU paths, and the browser player one.
class PairCurves {
 public:
  // For the pair of frames numbered a and b: `decide()`'s answer, asked only for a new pair.
  template <class Decide>
  bool operator()(std::uint64_t a, std::uint64_t b, Decide&& decide) {
    if (a != a_ || b != b_) {
      curves_ = decide();
      a_ = a;
      b_ = b;
    }
    return curves_;
  }

 private:
  std::uint64_t a_ = ~0ull, b_ = ~0ull;
  bool curves_ = false;
};

// Interpolates a clip's frames: built once when the clip opens (every table allocated then), used
// every host frame between two cached frames with no allocation.
class FrameBlender {
 public:
  explicit FrameBlender(const format::Metadata& meta);

  // The particles at `t` (0..1) of the way from frame `a` (na records) to frame `b` (nb records),
  // `dt` seconds apart, written to `out` (room for na + nb records). Returns how many.
  // - With `matching` (the runs pairing b's particles with a's, codec.hpp): a particle in both
  //   moves along the cubic Hermite curve of its positions and velocities (`curves`, the caller's
  //   decision for the pair of frames, made once: Interpolation::Hermite and
  //   velocities_describe_matching(); ignored without velocities) and its velocity becomes the
  //   curve's derivative, or it moves along the straight line; other floats and colours blend
  //   linearly, ids and other integers are a's. One only in `a` dies: it goes on along its
  //   velocity and shrinks to nothing by `b`. One only in `b` is born: it comes in along its
  //   velocity from where it would have been, growing from nothing.
  // - Without (or with runs that do not cover both frames): the nearer frame, moved along its
  //   velocities to `t` when the clip has velocities, as it is otherwise.
  std::uint64_t blend(std::span<const std::byte> a, std::uint64_t na, std::span<const std::byte> b, std::uint64_t nb,
                      const std::span<const format::MatchRun>* matching, double t, double dt, bool curves,
                      std::byte* out);

 private:
  void set_fraction(double t, double dt, bool hermite);
  std::uint64_t nearer_advected(std::span<const std::byte> a, std::uint64_t na, std::span<const std::byte> b,
                                std::uint64_t nb, double t, double dt, std::byte* out) const;
  void advect(std::byte* record, double seconds, float grow) const;
  void blend_colors(const std::byte* a, const std::byte* b, std::size_t records, float t, std::byte* out) const;

  std::uint32_t stride_ = 16;
  std::int32_t velocity_ = -1;      // float32 x3
  std::int32_t color_ = -1;         // unorm8 x4
  std::vector<std::uint8_t> kind_;  // per word of a record: what its lane is (interpolate.cpp)
  LanePlan plan_;
  double plan_t_ = -1.0, plan_dt_ = 0.0;
  bool plan_hermite_ = false;
};

}  // namespace pstream::playback
