// The particle codec's matching for a clip without ids (docs/format.md, "The particle codec";
// docs/compression.md): each particle of a frame paired with at most one particle of the frame
// before, by position, so that the encoder predicts it from that one. Only the encoder needs it:
// the packet's operations carry the pairs, and the decoder follows them.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

namespace pstream::format::particle {

// One frame's particles on the codec's position grid: a coordinate array an axis, each value read
// as a signed 32-bit number below kGridLimit in magnitude.
struct GridPoints {
  std::array<const std::uint32_t*, 3> q{};
  std::uint32_t count = 0;
};

// The frame before's stored velocity, quantised on its own grid (the clip's velocity words), and
// what turns it into position grid steps over one frame. A clip that stores none leaves q null.
struct GridVelocity {
  std::array<const std::uint32_t*, 3> q{};
  std::array<float, 3> step{}, origin{};  // the velocity words' grids
  std::array<double, 3> position_step{};  // the position words' grid steps
  double frame_seconds = 0;
  bool present() const { return q[0] != nullptr && q[1] != nullptr && q[2] != nullptr; }
};

// Pairs a frame's particles with the frame before's, closest first within about one particle
// spacing, each particle of either frame once at most (particle_matching.cpp says how, and why).
// Its working memory is kept from one frame to the next: one matcher serves a keyframe group.
class PositionMatcher {
 public:
  PositionMatcher();
  ~PositionMatcher();
  PositionMatcher(const PositionMatcher&) = delete;
  PositionMatcher& operator=(const PositionMatcher&) = delete;

  // Sets match[j] to the index in `previous` of current particle j's partner; a particle left
  // without one keeps its -1. `match` holds current.count values, each -1 on entry. The pairs
  // depend on the positions and velocities alone, so every build of the encoder makes the same.
  void match(const GridPoints& previous, const GridVelocity& velocity, const GridPoints& current,
             std::vector<std::int64_t>& match);

  struct Scratch;  // the working memory (particle_matching.cpp)

 private:
  std::unique_ptr<Scratch> scratch_;
};

}  // namespace pstream::format::particle
