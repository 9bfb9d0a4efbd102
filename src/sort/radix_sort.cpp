// LSD radix sort of key-index pairs. Each pass reads and writes every item once (8 bytes each
// way), so a pass costs about what copying the array costs; fewer, cache-friendly passes win.
#include "particlestream/sort.hpp"
#include "radix.hpp"

namespace pstream::sort {

template <int kDigits, int kBits>
static void sort_items(std::uint64_t* items, std::uint64_t* scratch, std::size_t n, std::uint32_t* indices_out) {
  static thread_local detail::Histogram<kDigits, kBits> h;  // 4 KiB: off the stack, allocated once per thread
  h.clear();
  for (std::size_t i = 0; i < n; ++i) h.add(static_cast<std::uint32_t>(items[i] >> 32));
  detail::radix_scatter(items, scratch, n, h, indices_out);
}

void radix_sort_pairs(std::uint64_t* items, std::uint64_t* scratch, std::size_t n, std::uint32_t* indices_out) {
  // Four 8-bit digits. Measured on this project's 2-core machines (docs/sorting.md): 256 buckets
  // keep the scatter's write targets in L1 and beat three 11-bit passes by 2.5x at 1M pairs.
  sort_items<4, 8>(items, scratch, n, indices_out);
}

void radix_sort_pairs16(std::uint64_t* items, std::uint64_t* scratch, std::size_t n, std::uint32_t* indices_out) {
  sort_items<2, 8>(items, scratch, n, indices_out);
}

}  // namespace pstream::sort
