// The particle spacing of a frame: the median distance from a particle to its nearest neighbour,
// for the default radius of a cache without widths (half the spacing: neighbours just touch).
#pragma once

#include <cstddef>
#include <span>

namespace pstream::cook {

// `xyz`: 3 floats per particle. Up to `samples` particles (spread evenly) are measured against
// all of them, through a uniform grid of about one particle per cell. 0 when fewer than two
// particles or no finite spacing.
float median_spacing(std::span<const float> xyz, std::size_t samples = 4096);

}  // namespace pstream::cook
