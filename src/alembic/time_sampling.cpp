// Sample times and time -> index lookups, with the official library's tolerances so that a
// lookup by time picks the same sample the official reader picks.
#include <cmath>
#include <limits>

#include "particlestream/alembic.hpp"

namespace pstream::alembic {
namespace {

constexpr double kEpsilon = std::numeric_limits<double>::epsilon() * 32.0;
constexpr double kTolerance = kEpsilon * 32.0;

// floor(q) as an index no larger than `last`: NaN and negatives give 0, and values past `last`
// (huge times, tiny cycles) never reach the integer conversion.
std::uint64_t clamped_index(double q, std::uint64_t last) {
  if (!(q > 0.0)) return 0;
  if (q >= static_cast<double>(last)) return last;
  return static_cast<std::uint64_t>(q);
}

}  // namespace

double TimeSampling::sample_time(std::uint64_t index) const {
  switch (type) {
    case TimeSamplingType::Uniform: return stored_times[0] + time_per_cycle * static_cast<double>(index);
    case TimeSamplingType::Acyclic: return index < stored_times.size() ? stored_times[index] : stored_times.back();
    case TimeSamplingType::Cyclic: {
      const std::uint64_t n = stored_times.size();
      const std::uint64_t cycles = index / n;
      return stored_times[index - cycles * n] + time_per_cycle * static_cast<double>(cycles);
    }
  }
  return 0.0;
}

std::pair<std::uint64_t, double> TimeSampling::floor_index(double time, std::uint64_t num_samples) const {
  if (num_samples == 0) return {0, 0.0};
  time += kEpsilon;
  const double min_time = sample_time(0);
  if (time <= min_time) return {0, min_time};
  const double max_time = sample_time(num_samples - 1);
  if (time >= max_time) return {num_samples - 1, max_time};

  if (type == TimeSamplingType::Acyclic) {
    std::uint64_t idx = 1;
    while (idx < num_samples && idx < stored_times.size() && stored_times[idx] <= time) ++idx;
    return {idx - 1, stored_times[idx - 1]};
  }
  if (type == TimeSamplingType::Uniform) {
    std::uint64_t idx = clamped_index(std::floor((time - min_time) / time_per_cycle), num_samples - 1);
    double t = min_time + time_per_cycle * static_cast<double>(idx);
    if (t > time && idx > 0) {  // round-off put us one sample late
      --idx;
      t -= time_per_cycle;
    }
    return {idx, t};
  }
  // Cyclic: find the cycle, then the last stored time within it that is <= time.
  const double elapsed = time - min_time;
  double whole = 0.0;
  const double frac = std::modf(elapsed / time_per_cycle, &whole);
  if (std::abs(1.0 - frac) <= kTolerance) whole += 1.0;
  const std::uint64_t cycles = clamped_index(whole, (num_samples - 1) / stored_times.size());
  const double block_time = static_cast<double>(cycles) * time_per_cycle;
  const double rem = time - block_time;
  std::uint64_t in_cycle = 0;
  for (std::uint64_t i = 0; i < stored_times.size(); ++i) {
    if (stored_times[i] > rem) break;
    in_cycle = i;
  }
  const std::uint64_t idx = std::min(cycles * stored_times.size() + in_cycle, num_samples - 1);
  return {idx, sample_time(idx)};
}

std::pair<std::uint64_t, double> TimeSampling::ceil_index(double time, std::uint64_t num_samples) const {
  if (num_samples == 0) return {0, 0.0};
  time -= kEpsilon;
  const std::uint64_t max_index = num_samples - 1;
  const double min_time = sample_time(0);
  if (time <= min_time) return {0, min_time};
  const double max_time = sample_time(max_index);
  if (time >= max_time) return {max_index, max_time};
  const auto [floor_idx, floor_time] = floor_index(time, num_samples);
  if (floor_idx == max_index || std::abs(floor_time - time) <= kTolerance) return {floor_idx, floor_time};
  return {floor_idx + 1, sample_time(floor_idx + 1)};
}

std::pair<std::uint64_t, double> TimeSampling::near_index(double time, std::uint64_t num_samples) const {
  if (num_samples == 0) return {0, 0.0};
  const std::uint64_t max_index = num_samples - 1;
  const double min_time = sample_time(0);
  if (time <= min_time) return {0, min_time};
  const double max_time = sample_time(max_index);
  if (time >= max_time) return {max_index, max_time};
  const auto lo = floor_index(time, num_samples);
  const auto hi = ceil_index(time, num_samples);
  return std::abs(time - lo.second) <= std::abs(hi.second - time) ? lo : hi;
}

}  // namespace pstream::alembic
