// Every array our Alembic writer stores for one points sample, read back through the reader
// (the writer and demo tests compare them with what they wrote).
#pragma once

#include <cstdint>
#include <vector>

#include "particlestream/alembic.hpp"

namespace pstream::test {

struct PointsSampleArrays {
  std::vector<float> P, velocities, widths, Cd, age;
  std::vector<std::uint64_t> ids;
};

// `cd_extent`: 3 for rgb, 4 for rgba.
inline PointsSampleArrays read_sample_arrays(const alembic::Points& points, std::uint32_t sample,
                                             std::size_t cd_extent) {
  const std::size_t n = points.count(sample);
  PointsSampleArrays a{std::vector<float>(n * 3),         std::vector<float>(n * 3), std::vector<float>(n),
                       std::vector<float>(n * cd_extent), std::vector<float>(n),     std::vector<std::uint64_t>(n)};
  points.read_positions(sample, a.P);
  points.read_velocities(sample, a.velocities);
  points.read_ids(sample, a.ids);
  points.read_param("widths", sample, a.widths);
  points.read_param("Cd", sample, a.Cd);
  points.read_param("age", sample, a.age);
  return a;
}

}  // namespace pstream::test
