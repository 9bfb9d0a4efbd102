// LSD radix sort of key-index pairs. Each pass reads and writes every item once (8 bytes each
// way), so a pass costs about what copying the array costs; fewer passes is the whole game.
#include <algorithm>
#include <cstring>

#include "particlestream/sort.hpp"

namespace pstream::sort {
namespace {

template <int kDigits, int kBits>
void radix(std::uint64_t* items, std::uint64_t* scratch, std::size_t n, std::uint32_t* indices_out) {
  constexpr std::uint32_t kBuckets = 1u << kBits;
  constexpr std::uint32_t kMask = kBuckets - 1;
  static_assert((kDigits - 1) * kBits < 32);  // the top digit may be narrower
  // All histograms in one read of the items.
  std::uint32_t hist[kDigits][kBuckets] = {};
  for (std::size_t i = 0; i < n; ++i) {
    const auto key = static_cast<std::uint32_t>(items[i] >> 32);
    for (int d = 0; d < kDigits; ++d) ++hist[d][(key >> (d * kBits)) & kMask];
  }
  // A pass whose digit is the same for every item moves nothing: skip it.
  int passes[kDigits];
  int pass_count = 0;
  if (n > 0) {
    const auto first = static_cast<std::uint32_t>(items[0] >> 32);
    for (int d = 0; d < kDigits; ++d) {
      if (hist[d][(first >> (d * kBits)) & kMask] != n) passes[pass_count++] = d;
    }
  }
  std::uint64_t* src = items;
  std::uint64_t* dst = scratch;
  for (int p = 0; p < pass_count; ++p) {
    const int d = passes[p];
    const int shift = 32 + d * kBits;
    std::uint32_t offset[kBuckets];
    std::uint32_t sum = 0;
    for (std::uint32_t b = 0; b < kBuckets; ++b) {
      offset[b] = sum;
      sum += hist[d][b];
    }
    if (p == pass_count - 1) {  // the last pass writes only what the renderer needs
      for (std::size_t i = 0; i < n; ++i) {
        const std::uint64_t v = src[i];
        indices_out[offset[(v >> shift) & kMask]++] = static_cast<std::uint32_t>(v);
      }
      return;
    }
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint64_t v = src[i];
      dst[offset[(v >> shift) & kMask]++] = v;
    }
    std::swap(src, dst);
  }
  for (std::size_t i = 0; i < n; ++i) indices_out[i] = static_cast<std::uint32_t>(src[i]);  // already in order
}

}  // namespace

void radix_sort_pairs(std::uint64_t* items, std::uint64_t* scratch, std::size_t n, std::uint32_t* indices_out) {
  // 11 + 11 + 10 bits: the top digit's buckets are half empty, which costs nothing.
  radix<3, 11>(items, scratch, n, indices_out);
}

void radix_sort_pairs16(std::uint64_t* items, std::uint64_t* scratch, std::size_t n, std::uint32_t* indices_out) {
  radix<2, 8>(items, scratch, n, indices_out);
}

}  // namespace pstream::sort
