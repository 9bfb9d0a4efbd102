#include <cstring>

#include <string>

#include "particlestream/error.hpp"
#include "particlestream/sort.hpp"

namespace pstream::sort {

SortMode parse_sort_mode(std::string_view name) {
  if (name == "none") return SortMode::None;
  if (name == "back") return SortMode::BackToFront;
  if (name == "front") return SortMode::FrontToBack;
  throw Error("sort mode '" + std::string(name) + "': expected none, back or front");
}

DepthAxis depth_axis(const std::array<float, 16>& m) {
  // Row 2 of the column-major matrix gives z_view; depth is its negation.
  return {-m[2], -m[6], -m[10], -m[14]};
}

void compute_depths(const std::byte* records, std::size_t count, std::size_t stride, const DepthAxis& a, float* out) {
  if (stride == 16) {  // the default record: a tight loop the compiler vectorises
    const auto* r = reinterpret_cast<const float*>(records);
    for (std::size_t i = 0; i < count; ++i) {
      out[i] = r[i * 4] * a.x + r[i * 4 + 1] * a.y + r[i * 4 + 2] * a.z + a.offset;
    }
    return;
  }
  for (std::size_t i = 0; i < count; ++i) {
    float p[3];
    std::memcpy(p, records + i * stride, sizeof p);
    out[i] = p[0] * a.x + p[1] * a.y + p[2] * a.z + a.offset;
  }
}

}  // namespace pstream::sort
