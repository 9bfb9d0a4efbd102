// The cooker's fast path: default [x y z scale] records packed straight from the source's
// mapped arrays, with the frame's bounds and the NaN/Inf check taken in the same pass.
#pragma once

#include <array>
#include <cstdint>

#include "cook/chunk_cutter.hpp"
#include "cook/source.hpp"

namespace pstream::cook {

struct DirectPackResult {
  std::array<float, 6> bounds;  // of the packed (finite) positions; +inf/-inf when none
  std::uint64_t packed = 0;     // records written
  std::uint64_t invalid = 0;    // NaN/Inf positions met (dropped when asked to, else packing stopped)
};

// Packs every particle of `frame` into `out`. A particle whose position is not finite is left
// out when `drop_invalid`; otherwise packing stops there with `invalid` set, and the caller fails
// the frame (the output is then discarded).
DirectPackResult pack_direct(const Source::DirectFrame& frame, bool drop_invalid, ChunkCutter& out);

}  // namespace pstream::cook
