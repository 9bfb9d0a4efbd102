// Order statistics of per-frame timings, one rule for every command that reports them.
#pragma once

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

}  // namespace pstream::app
