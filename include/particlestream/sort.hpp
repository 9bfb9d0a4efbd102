// Back-to-front (or front-to-back) ordering of particles by view depth, with an LSD radix sort
// of key-index pairs. Nothing is allocated per frame: buffers are sized once for the largest
// frame (T).
#pragma once

#include <array>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string_view>

#include "particlestream/frame.hpp"

namespace pstream::sort {

namespace detail {
template <int kDigits, int kBits>
struct Histogram;
}

using SortMode = render::SortMode;  // frame.hpp
// "none", "back" (back to front) or "front" (front to back); throws pstream::Error otherwise.
SortMode parse_sort_mode(std::string_view name);

// A float mapped to an unsigned integer with the same order (-inf < ... < -0 < +0 < ... < +inf).
inline std::uint32_t order_preserving_key(float f) {
  const auto u = std::bit_cast<std::uint32_t>(f);
  return u ^ (static_cast<std::uint32_t>(static_cast<std::int32_t>(u) >> 31) | 0x80000000u);
}

// depth = dot(p, axis) + offset: the distance in front of the camera of an object-space point,
// taken from the (view x world) matrix, so no particle is transformed on the CPU.
struct DepthAxis {
  float x = 0, y = 0, z = -1, offset = 0;
};
// `view_world` is column-major (OpenGL) and maps object space to a right-handed view space
// looking down -z, so depth = -z_view.
DepthAxis depth_axis(const std::array<float, 16>& view_world);

// Depth of every record: positions are the first 3 floats of records `stride` bytes apart.
void compute_depths(const std::byte* records, std::size_t count, std::size_t stride, const DepthAxis& axis, float* out);

// Stable LSD radix sort of 64-bit items by their upper 32 bits (a key) — key-index pairs packed
// as key << 32 | index. 8-bit digits, four passes, all histograms in one read, passes whose
// digit is the same for every item skipped. The last pass writes only the indices (low 32 bits)
// to `indices_out`. `items` and `scratch` hold n items each; both are clobbered.
void radix_sort_pairs(std::uint64_t* items, std::uint64_t* scratch, std::size_t n, std::uint32_t* indices_out);
// The same for keys of 16 bits (in bits 32..47): two 8-bit passes.
void radix_sort_pairs16(std::uint64_t* items, std::uint64_t* scratch, std::size_t n, std::uint32_t* indices_out);

struct SorterOptions {
  // Quantise depth to 16 bits over [near, far] (see docs/sorting.md): two passes instead of
  // three, at a depth resolution of (far - near) / 65535.
  bool quantize16 = false;
  // 2: histograms and scatters split between the caller and one helper thread.
  unsigned threads = 1;
};

class DepthSorter {
 public:
  explicit DepthSorter(std::size_t max_count, SorterOptions options = {});
  ~DepthSorter();
  DepthSorter(const DepthSorter&) = delete;
  DepthSorter& operator=(const DepthSorter&) = delete;

  std::size_t capacity() const { return capacity_; }

  // The draw order of `count` records: indices sorted by depth as `mode` asks (None: 0..n-1).
  // `near_far` bounds depth for 16-bit quantisation (ignored otherwise). The span stays valid
  // until the next call. count must not exceed capacity().
  std::span<const std::uint32_t> sort(const std::byte* records, std::size_t count, std::size_t stride,
                                      const std::array<float, 16>& view_world, SortMode mode,
                                      std::array<float, 2> near_far = {0.0f, 1.0f});
  // The same from precomputed depths.
  std::span<const std::uint32_t> sort_depths(std::span<const float> depths, SortMode mode,
                                             std::array<float, 2> near_far = {0.0f, 1.0f});
  std::span<const float> depths() const { return {depths_.get(), last_count_}; }

  // Several streams sorted together (overlapping streams blend correctly only in one order):
  // each source's records go through its own (view x world) matrix. The entries of the returned
  // order are (source << kMergedIndexBits) | index within that source. The total count must not
  // exceed capacity(); at most kMaxMergedSources sources of fewer than 2^kMergedIndexBits
  // particles each. The packing is the frame model's (frame.hpp), which renderers unpack.
  static constexpr int kMergedIndexBits = static_cast<int>(render::kMergedIndexBits);
  static constexpr std::size_t kMaxMergedSources = render::kMaxMergedBatches;
  struct Source {
    const std::byte* records = nullptr;
    std::size_t count = 0, stride = 16;
    std::array<float, 16> view_world{};
  };
  // `near_far` bounds the depths of every source for 16-bit quantisation, as in sort().
  std::span<const std::uint32_t> sort_merged(std::span<const Source> sources, SortMode mode,
                                             std::array<float, 2> near_far = {0.0f, 1.0f});

 private:
  struct Helper;
  std::size_t capacity_;
  SorterOptions options_;
  std::unique_ptr<float[]> depths_;
  std::unique_ptr<std::uint64_t[]> items_, scratch_;
  std::unique_ptr<std::uint32_t[]> indices_;
  std::unique_ptr<detail::Histogram<4, 8>> hist_;
  std::unique_ptr<detail::Histogram<2, 8>> hist16_;
  std::size_t last_count_ = 0;
  std::unique_ptr<Helper> helper_;
};

}  // namespace pstream::sort
