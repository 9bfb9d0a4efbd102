// The seed design's sorting comparison: classic sorts on the same key-index pairs our radix sort
// takes (key << 32 | index, ordered by the whole 64-bit value), plus std::sort,
// std::stable_sort, Highway's vqsort as the peer anchor, and ours.
#pragma once

#include <hwy/contrib/sort/vqsort.h>

#include <algorithm>
#include <cstdint>
#include <span>
#include <string_view>
#include <vector>

#include "particlestream/sort.hpp"

namespace pstream::bench {

using Item = std::uint64_t;

inline void bubble_sort(std::span<Item> a) {
  for (std::size_t n = a.size(); n > 1; --n) {
    bool swapped = false;
    for (std::size_t i = 1; i < n; ++i) {
      if (a[i] < a[i - 1]) std::swap(a[i], a[i - 1]), swapped = true;
    }
    if (!swapped) return;
  }
}

inline void insertion_sort(std::span<Item> a) {
  for (std::size_t i = 1; i < a.size(); ++i) {
    const Item v = a[i];
    std::size_t j = i;
    for (; j > 0 && v < a[j - 1]; --j) a[j] = a[j - 1];
    a[j] = v;
  }
}

inline void comb_sort(std::span<Item> a) {
  std::size_t gap = a.size();
  bool sorted = false;
  while (!sorted) {
    gap = std::max<std::size_t>(1, static_cast<std::size_t>(double(gap) / 1.3));
    sorted = gap == 1;
    for (std::size_t i = 0; i + gap < a.size(); ++i) {
      if (a[i + gap] < a[i]) std::swap(a[i], a[i + gap]), sorted = false;
    }
  }
}

inline void merge_sort(std::span<Item> a, std::vector<Item>& tmp) {
  tmp.resize(a.size());
  for (std::size_t width = 1; width < a.size(); width *= 2) {  // bottom-up
    for (std::size_t lo = 0; lo < a.size(); lo += 2 * width) {
      const std::size_t mid = std::min(lo + width, a.size()), hi = std::min(lo + 2 * width, a.size());
      std::merge(a.begin() + lo, a.begin() + mid, a.begin() + mid, a.begin() + hi, tmp.begin() + lo);
    }
    std::copy(tmp.begin(), tmp.begin() + a.size(), a.begin());
  }
}

inline void quick_sort(Item* lo, Item* hi) {  // [lo, hi), median of three, insertion for small
  while (hi - lo > 16) {
    Item* mid = lo + (hi - lo) / 2;
    if (*mid < *lo) std::swap(*mid, *lo);
    if (*(hi - 1) < *lo) std::swap(*(hi - 1), *lo);
    if (*(hi - 1) < *mid) std::swap(*(hi - 1), *mid);
    const Item pivot = *mid;
    Item* i = lo;
    Item* j = hi - 1;
    while (i <= j) {
      while (*i < pivot) ++i;
      while (pivot < *j) --j;
      if (i <= j) std::swap(*i++, *j--);
    }
    if (j - lo < hi - i) {
      quick_sort(lo, j + 1);
      lo = i;
    } else {
      quick_sort(i, hi);
      hi = j + 1;
    }
  }
  insertion_sort({lo, static_cast<std::size_t>(hi - lo)});
}

struct Contender {
  std::string_view name;
  std::size_t max_n;  // quadratic sorts only on small inputs
};

inline const std::vector<Contender>& contenders() {
  static const std::vector<Contender> list = {
      {"bubble", 4096},
      {"insertion", 16384},
      {"comb", SIZE_MAX},
      {"merge", SIZE_MAX},
      {"quick", SIZE_MAX},
      {"std_sort", SIZE_MAX},
      {"std_stable_sort", SIZE_MAX},
      {"vqsort", SIZE_MAX},
      {"ours", SIZE_MAX},
      {"ours_2threads", SIZE_MAX},
      {"ours_16bit", SIZE_MAX},
  };
  return list;
}

// Sorts `depths` with contender `name`; `items` etc. are preallocated work buffers.
struct SortBench {
  explicit SortBench(std::size_t max_n)
      : items(max_n),
        scratch(max_n),
        indices(max_n),
        ours(max_n),
        ours2(max_n, {.threads = 2}),
        ours16(max_n, {.quantize16 = true}) {}

  void run(std::string_view name, std::span<const float> depths) {
    const std::size_t n = depths.size();
    if (name.substr(0, 4) == "ours") {
      DepthSorter& s = name == "ours" ? ours : name == "ours_2threads" ? ours2 : ours16;
      result = s.sort_depths(depths, SortMode::FrontToBack, {-1000.0f, 1000.0f});
      return;
    }
    for (std::size_t i = 0; i < n; ++i) {
      items[i] = static_cast<Item>(pstream::sort::order_preserving_key(depths[i])) << 32 | i;
    }
    std::span<Item> a(items.data(), n);
    if (name == "bubble")
      bubble_sort(a);
    else if (name == "insertion")
      insertion_sort(a);
    else if (name == "comb")
      comb_sort(a);
    else if (name == "merge")
      merge_sort(a, scratch);
    else if (name == "quick")
      quick_sort(a.data(), a.data() + n);
    else if (name == "std_sort")
      std::sort(a.begin(), a.end());
    else if (name == "std_stable_sort")
      std::stable_sort(a.begin(), a.end());
    else if (name == "vqsort")
      vq(a.data(), n, hwy::SortAscending());
    for (std::size_t i = 0; i < n; ++i) indices[i] = static_cast<std::uint32_t>(items[i]);
    result = {indices.data(), n};
  }

  std::vector<Item> items, scratch;
  std::vector<std::uint32_t> indices;
  pstream::sort::DepthSorter ours, ours2, ours16;
  hwy::Sorter vq;
  std::span<const std::uint32_t> result;

 private:
  using DepthSorter = pstream::sort::DepthSorter;
  using SortMode = pstream::sort::SortMode;
};

}  // namespace pstream::bench
