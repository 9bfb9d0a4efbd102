// Order statistics of per-frame timings, one rule for every command that reports them.
#pragma once

#include <time.h>

#include <algorithm>
#include <cstddef>
#include <vector>

namespace pstream::app {

// The q-quantile (0..1) of `v`: the element at floor(q × n) once sorted (the last for q = 1);
// 0 for no values (a clip of no frames plays none).
inline double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<std::size_t>(q * double(v.size())))];
}

// The median of `v`: the middle value, or the mean of the two middle values of an even count;
// 0 for no values.
inline double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const std::size_t h = v.size() / 2;
  return v.size() % 2 ? v[h] : 0.5 * (v[h - 1] + v[h]);
}

// This thread's CPU time in milliseconds (CLOCK_THREAD_CPUTIME_ID): what a host cost measures,
// without the time the thread waits or is descheduled on a shared machine.
inline double thread_cpu_ms() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return double(t.tv_sec) * 1e3 + double(t.tv_nsec) * 1e-6;
}

}  // namespace pstream::app
