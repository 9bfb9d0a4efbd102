// The radix sort's building blocks, shared by radix_sort.cpp and the depth sorter (which fuses
// the histogram count into building the key-index pairs, saving one read of the array).
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>

namespace pstream::sort::detail {

template <int kDigits, int kBits>
struct Histogram {
  static constexpr std::uint32_t kBuckets = 1u << kBits;
  static constexpr std::uint32_t kMask = kBuckets - 1;
  std::uint32_t count[kDigits][kBuckets] = {};

  void clear() { std::fill(&count[0][0], &count[0][0] + kDigits * kBuckets, 0u); }
  void add(std::uint32_t key) {
    for (int d = 0; d < kDigits; ++d) ++count[d][(key >> (d * kBits)) & kMask];
  }
};

// The scatter passes of an LSD radix sort whose histograms are already counted. Passes whose digit
// is the same for every item are skipped; the last pass writes only the low 32 bits (indices).
template <int kDigits, int kBits>
void radix_scatter(std::uint64_t* items, std::uint64_t* scratch, std::size_t n, const Histogram<kDigits, kBits>& h,
                   std::uint32_t* indices_out) {
  using H = Histogram<kDigits, kBits>;
  int passes[kDigits];
  int pass_count = 0;
  if (n > 0) {
    const auto first = static_cast<std::uint32_t>(items[0] >> 32);
    for (int d = 0; d < kDigits; ++d) {
      if (h.count[d][(first >> (d * kBits)) & H::kMask] != n) passes[pass_count++] = d;
    }
  }
  std::uint64_t* src = items;
  std::uint64_t* dst = scratch;
  for (int p = 0; p < pass_count; ++p) {
    const int d = passes[p];
    const int shift = 32 + d * kBits;
    std::uint32_t offset[H::kBuckets];
    std::uint32_t sum = 0;
    for (std::uint32_t b = 0; b < H::kBuckets; ++b) {
      offset[b] = sum;
      sum += h.count[d][b];
    }
    if (p == pass_count - 1) {
      for (std::size_t i = 0; i < n; ++i) {
        const std::uint64_t v = src[i];
        indices_out[offset[(v >> shift) & H::kMask]++] = static_cast<std::uint32_t>(v);
      }
      return;
    }
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint64_t v = src[i];
      dst[offset[(v >> shift) & H::kMask]++] = v;
    }
    std::swap(src, dst);
  }
  for (std::size_t i = 0; i < n; ++i) indices_out[i] = static_cast<std::uint32_t>(src[i]);  // already in order
}

}  // namespace pstream::sort::detail
