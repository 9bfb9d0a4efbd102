// The stream's clock: clip time driven by the host's, with a speed, a range and looping. Pure
// arithmetic on the clip's frame times, no IO and no locking: the chunk cache
// (particle_stream.cpp) asks it which frame to hold and loads and decodes towards that.
#pragma once

#include <cstdint>
#include <utility>

#include "particlestream/format.hpp"

namespace pstream::stream {

struct Playhead {
  double time = 0.0;      // clip seconds
  double speed = 1.0;     // clip seconds per host second; 0 holds, negative plays backwards
  double fraction = 0.0;  // with interpolation: how far from `frame` towards the next, [0, 1)
  std::uint64_t lap = 0;  // forward passes through the range (the cache numbers its sequence by them)
  bool playing = false;

  // Advances `dt` host seconds (ignored unless playing, positive and the step finite) within the
  // frames [begin, end] of `m`. Going forwards, a loop wraps when the time passes the last frame
  // by half a frame (every frame shows for a whole frame time); backwards, when it passes the
  // first. Without a loop it stops at the range's end and returns false.
  bool advance(const format::Metadata& m, std::uint64_t begin, std::uint64_t end, bool loop, double dt);

  // The frame to hold for the time: the nearest, or (interpolating) the one at or before it, with
  // `fraction` set towards the next (0 at the range's last frame).
  std::uint64_t target(const format::Metadata& m, std::uint64_t begin, std::uint64_t end, bool interpolate);
};

}  // namespace pstream::stream
