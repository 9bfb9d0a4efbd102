#include "stream/playhead.hpp"

#include <algorithm>
#include <cmath>

namespace pstream::stream {

bool Playhead::advance(const format::Metadata& m, std::uint64_t begin, std::uint64_t end, bool loop, double dt) {
  const double step = dt * speed;
  if (!playing || !(dt > 0.0) || !std::isfinite(step) || step == 0.0) return true;
  time += step;
  const double start = m.frames[begin].time, last = m.frames[end].time;
  const double period = last - start + 1.0 / m.fps;  // one pass, the last frame shown a whole frame time
  const double forward_end = last + 0.5 / m.fps;
  if (step > 0.0 && time > forward_end) {
    if (!loop) {
      time = last;
      playing = false;
      return false;
    }
    // Whole passes at once (a huge step is arithmetic, not a loop). The lap counts one: the
    // cache only needs to know that the target lies in a later pass than what it holds, and the
    // passes skipped in between have nothing to decode.
    const double passes = std::floor((time - forward_end) / period) + 1.0;
    time -= passes * period;
    ++lap;
    time = std::clamp(time, start - 0.5 / m.fps, forward_end);
  } else if (step < 0.0 && time < start) {
    if (!loop) {
      time = start;
      playing = false;
      return false;
    }
    time += std::ceil((start - time) / period) * period;
    time = std::clamp(time, start, last);
  }
  return true;
}

std::uint64_t Playhead::target(const format::Metadata& m, std::uint64_t begin, std::uint64_t end, bool interpolate) {
  fraction = 0.0;
  if (!interpolate) return std::clamp(m.frame_at(time), begin, end);
  const auto [before, f] = m.frame_between(time);
  const std::uint64_t frame = std::clamp(before, begin, end);
  if (frame == before && frame < end) fraction = f;
  return frame;
}

}  // namespace pstream::stream
