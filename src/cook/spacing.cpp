#include "cook/spacing.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

namespace pstream::cook {

float median_spacing(std::span<const float> xyz, std::size_t samples) {
  // Finite particles only (a frame may still hold NaN or infinite positions here).
  std::vector<std::uint32_t> finite;
  for (std::size_t i = 0; i < xyz.size() / 3; ++i) {
    if (std::isfinite(xyz[3 * i]) && std::isfinite(xyz[3 * i + 1]) && std::isfinite(xyz[3 * i + 2]))
      finite.push_back(std::uint32_t(i));
  }
  const std::size_t n = finite.size();
  if (n < 2) return 0.0f;
  std::array<double, 3> lo{}, hi{};
  for (std::size_t a = 0; a < 3; ++a) lo[a] = hi[a] = xyz[3 * finite[0] + a];
  for (const std::uint32_t i : finite) {
    for (std::size_t a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], double(xyz[3 * i + a]));
      hi[a] = std::max(hi[a], double(xyz[3 * i + a]));
    }
  }
  const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
  if (!(extent > 0) || !std::isfinite(extent)) return 0.0f;
  // Cells of about one particle each; flat or thin clouds get their thin axes floored.
  double volume = 1.0;
  for (std::size_t a = 0; a < 3; ++a) volume *= std::max(hi[a] - lo[a], extent * 1e-3);
  const double cell = std::max(std::cbrt(volume / double(n)), extent * 1e-6);
  const double cells_per_axis = extent / cell + 1;
  if (cells_per_axis > double(1 << 20)) return 0.0f;  // 21 bits a coordinate
  const auto coord = [&](std::size_t i, std::size_t a) {
    return std::uint64_t((double(xyz[3 * i + a]) - lo[a]) / cell);
  };
  const auto key = [](std::uint64_t x, std::uint64_t y, std::uint64_t z) { return x << 42 | y << 21 | z; };
  std::vector<std::pair<std::uint64_t, std::uint32_t>> grid(n);
  for (std::size_t k = 0; k < n; ++k) {
    const std::uint32_t i = finite[k];
    grid[k] = {key(coord(i, 0), coord(i, 1), coord(i, 2)), i};
  }
  std::sort(grid.begin(), grid.end());

  std::vector<float> nearest;
  const std::size_t step = std::max<std::size_t>(1, n / std::max<std::size_t>(samples, 1));
  for (std::size_t k = 0; k < n; k += step) {
    const std::size_t i = finite[k];
    const std::int64_t cx = std::int64_t(coord(i, 0)), cy = std::int64_t(coord(i, 1)), cz = std::int64_t(coord(i, 2));
    double best = std::numeric_limits<double>::infinity();
    for (int reach = 1; reach <= 2 && !std::isfinite(best); ++reach) {  // 27 cells, then 125
      for (std::int64_t x = cx - reach; x <= cx + reach; ++x) {
        for (std::int64_t y = cy - reach; y <= cy + reach; ++y) {
          for (std::int64_t z = cz - reach; z <= cz + reach; ++z) {
            if (x < 0 || y < 0 || z < 0) continue;
            const std::uint64_t k = key(std::uint64_t(x), std::uint64_t(y), std::uint64_t(z));
            auto it = std::lower_bound(grid.begin(), grid.end(), std::pair<std::uint64_t, std::uint32_t>{k, 0});
            for (; it != grid.end() && it->first == k; ++it) {
              const std::size_t j = it->second;
              if (j == i) continue;
              const double dx = double(xyz[3 * j]) - xyz[3 * i], dy = double(xyz[3 * j + 1]) - xyz[3 * i + 1],
                           dz = double(xyz[3 * j + 2]) - xyz[3 * i + 2];
              const double d = dx * dx + dy * dy + dz * dz;
              if (d > 0) best = std::min(best, d);  // coincident particles do not count
            }
          }
        }
      }
    }
    if (std::isfinite(best)) nearest.push_back(float(std::sqrt(best)));
  }
  if (nearest.empty()) return 0.0f;
  std::nth_element(nearest.begin(), nearest.begin() + std::ptrdiff_t(nearest.size() / 2), nearest.end());
  return nearest[nearest.size() / 2];
}

}  // namespace pstream::cook
