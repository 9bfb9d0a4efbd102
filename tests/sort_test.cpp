// The depth sort: same order as std::stable_sort on every kind of key, a permutation always,
// depths equal to a double-precision reference, and no allocation per frame.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <random>

#include "alloc_counter.hpp"
#include "particlestream/sort.hpp"

namespace {

using namespace pstream::sort;

enum class Keys { Random, DuplicateHeavy, ZerosAndDenormals };

std::vector<float> make_keys(std::size_t n, Keys kind, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<float> k(n);
  std::uniform_real_distribution<float> uni(-1000.0f, 1000.0f);
  std::uniform_int_distribution<int> small(0, 7);
  const float denorm = std::numeric_limits<float>::denorm_min();
  const float specials[] = {0.0f,
                            -0.0f,
                            denorm,
                            -denorm,
                            3 * denorm,
                            -7 * denorm,
                            std::numeric_limits<float>::min(),
                            -std::numeric_limits<float>::max(),
                            std::numeric_limits<float>::max(),
                            1e-30f};
  for (auto& v : k) {
    switch (kind) {
      case Keys::Random: v = uni(rng); break;
      case Keys::DuplicateHeavy: v = static_cast<float>(small(rng)) * 0.5f - 1.0f; break;
      case Keys::ZerosAndDenormals: v = specials[rng() % std::size(specials)]; break;
    }
  }
  return k;
}

void expect_sorted_like_stable_sort(const std::vector<float>& depth, std::span<const std::uint32_t> order,
                                    SortMode mode) {
  const std::size_t n = depth.size();
  ASSERT_EQ(order.size(), n);
  std::vector<std::uint32_t> reference(n);
  std::iota(reference.begin(), reference.end(), 0u);
  if (mode == SortMode::BackToFront) {
    std::stable_sort(reference.begin(), reference.end(), [&](auto a, auto b) { return depth[a] > depth[b]; });
  } else {
    std::stable_sort(reference.begin(), reference.end(), [&](auto a, auto b) { return depth[a] < depth[b]; });
  }
  for (std::size_t i = 0; i < n; ++i) {
    ASSERT_EQ(depth[order[i]], depth[reference[i]]) << "position " << i << " of " << n;  // ties in any order
  }
  std::vector<bool> seen(n);
  for (std::uint32_t idx : order) {
    ASSERT_LT(idx, n);
    ASSERT_FALSE(seen[idx]) << "index " << idx << " twice";
    seen[idx] = true;
  }
}

TEST(RadixSort, MatchesStableSortForEveryKindOfKeyAndSize) {
  for (std::size_t n : {0u, 1u, 2u, 255u, 256u, 65537u, 1u << 20}) {
    for (Keys kind : {Keys::Random, Keys::DuplicateHeavy, Keys::ZerosAndDenormals}) {
      const std::vector<float> depth = make_keys(n, kind, static_cast<std::uint32_t>(n * 3 + int(kind)));
      for (unsigned threads : {1u, 2u}) {
        DepthSorter sorter(n, {.threads = threads});
        for (SortMode mode : {SortMode::BackToFront, SortMode::FrontToBack}) {
          SCOPED_TRACE(testing::Message()
                       << "n=" << n << " kind=" << int(kind) << " threads=" << threads << " mode=" << int(mode));
          expect_sorted_like_stable_sort(depth, sorter.sort_depths(depth, mode), mode);
        }
      }
    }
  }
}

TEST(RadixSort, TwoThreadsGiveExactlyTheSameOrder) {
  const std::vector<float> depth = make_keys(300000, Keys::DuplicateHeavy, 7);
  DepthSorter one(depth.size()), two(depth.size(), {.threads = 2});
  const auto a = one.sort_depths(depth, SortMode::BackToFront);
  const std::vector<std::uint32_t> first(a.begin(), a.end());
  const auto b = two.sort_depths(depth, SortMode::BackToFront);
  EXPECT_TRUE(std::equal(first.begin(), first.end(), b.begin(), b.end()));  // both stable
}

TEST(RadixSort, NoneKeepsTheStoredOrder) {
  const std::vector<float> depth = make_keys(1000, Keys::Random, 1);
  DepthSorter sorter(1000);
  const auto order = sorter.sort_depths(depth, SortMode::None);
  ASSERT_EQ(order.size(), 1000u);
  for (std::uint32_t i = 0; i < 1000; ++i) EXPECT_EQ(order[i], i);
}

TEST(RadixSort, Quantized16KeepsOrderAtItsResolution) {
  const std::size_t n = 200000;
  const std::vector<float> depth = make_keys(n, Keys::Random, 3);  // in [-1000, 1000]
  DepthSorter sorter(n, {.quantize16 = true});
  const auto order = sorter.sort_depths(depth, SortMode::BackToFront, {-1000.0f, 1000.0f});
  const float resolution = 2000.0f / 65535.0f;
  std::vector<bool> seen(n);
  for (std::size_t i = 0; i < n; ++i) {
    seen[order[i]] = true;
    if (i > 0) {
      ASSERT_LE(depth[order[i]], depth[order[i - 1]] + resolution) << i;
    }
  }
  EXPECT_TRUE(std::all_of(seen.begin(), seen.end(), [](bool b) { return b; }));
}

TEST(OrderPreservingKey, KeepsFloatOrder) {
  const float values[] = {
      -std::numeric_limits<float>::infinity(),  -1e30f, -1.0f, -std::numeric_limits<float>::denorm_min(), -0.0f, 0.0f,
      std::numeric_limits<float>::denorm_min(), 1.0f,   1e30f, std::numeric_limits<float>::infinity()};
  for (std::size_t i = 1; i < std::size(values); ++i) {
    EXPECT_LT(order_preserving_key(values[i - 1]), order_preserving_key(values[i])) << values[i];
  }
}

TEST(DepthKeys, MatchADoublePrecisionReference) {
  // A camera at (3, 2, 10) looking at the origin, times a world transform that moves by (1, 0, -2)
  // and scales by 2: column-major, as OpenGL takes it.
  const double eye[3] = {3, 2, 10};
  double f[3] = {-eye[0], -eye[1], -eye[2]};
  const double fl = std::sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
  for (double& v : f) v /= fl;
  double s[3] = {f[1] * 0 - f[2] * 1, f[2] * 0 - f[0] * 0, f[0] * 1 - f[1] * 0};  // f x up(0,1,0)
  const double sl = std::sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
  for (double& v : s) v /= sl;
  const double u[3] = {s[1] * f[2] - s[2] * f[1], s[2] * f[0] - s[0] * f[2], s[0] * f[1] - s[1] * f[0]};
  double view[16] = {s[0], u[0], -f[0], 0, s[1], u[1], -f[1], 0, s[2], u[2], -f[2], 0, 0, 0, 0, 1};
  view[12] = -(s[0] * eye[0] + s[1] * eye[1] + s[2] * eye[2]);
  view[13] = -(u[0] * eye[0] + u[1] * eye[1] + u[2] * eye[2]);
  view[14] = f[0] * eye[0] + f[1] * eye[1] + f[2] * eye[2];
  const double world[16] = {2, 0, 0, 0, 0, 2, 0, 0, 0, 0, 2, 0, 1, 0, -2, 1};
  double vw[16];
  for (int c = 0; c < 4; ++c) {
    for (int r = 0; r < 4; ++r) {
      vw[c * 4 + r] = 0;
      for (int k = 0; k < 4; ++k) vw[c * 4 + r] += view[k * 4 + r] * world[c * 4 + k];
    }
  }
  std::array<float, 16> m;
  for (int i = 0; i < 16; ++i) m[i] = static_cast<float>(vw[i]);

  std::mt19937 rng(5);
  std::uniform_real_distribution<float> uni(-5.0f, 5.0f);
  const std::size_t n = 10000;
  std::vector<float> records(n * 4);
  for (auto& v : records) v = uni(rng);
  std::vector<float> depth(n);
  compute_depths(reinterpret_cast<const std::byte*>(records.data()), n, 16, depth_axis(m), depth.data());
  for (std::size_t i = 0; i < n; ++i) {
    const double x = records[i * 4], y = records[i * 4 + 1], z = records[i * 4 + 2];
    const double z_view = vw[2] * x + vw[6] * y + vw[10] * z + vw[14];
    ASSERT_NEAR(depth[i], -z_view, 1e-5 * std::max(1.0, std::abs(z_view))) << i;
  }
  // Strided records (a 28-byte layout) give the same depths.
  std::vector<std::byte> wide(n * 28);
  for (std::size_t i = 0; i < n; ++i) std::memcpy(wide.data() + i * 28, &records[i * 4], 12);
  std::vector<float> depth2(n);
  compute_depths(wide.data(), n, 28, depth_axis(m), depth2.data());
  EXPECT_EQ(depth, depth2);
}

TEST(DepthSorter, SortsRecordsWithoutAllocatingPerFrame) {
  const std::size_t n = 100000;
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> uni(-5.0f, 5.0f);
  std::vector<float> records(n * 4);
  for (auto& v : records) v = uni(rng);
  std::array<float, 16> view{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, -10, 1};  // camera at z = +10
  for (unsigned threads : {1u, 2u}) {
    for (bool q16 : {false, true}) {
      DepthSorter sorter(n, {.quantize16 = q16, .threads = threads});
      (void)sorter.sort(reinterpret_cast<const std::byte*>(records.data()), n, 16, view, SortMode::BackToFront,
                        {0, 20});
      const std::uint64_t before = pstream::test::allocation_count();
      for (int frame = 0; frame < 10; ++frame) {
        const auto order = sorter.sort(reinterpret_cast<const std::byte*>(records.data()), n - frame * 1000, 16, view,
                                       frame % 2 ? SortMode::FrontToBack : SortMode::BackToFront, {0, 20});
        ASSERT_EQ(order.size(), n - frame * 1000);
      }
      EXPECT_EQ(pstream::test::allocation_count(), before) << "threads=" << threads << " q16=" << q16;
      // Back to front: the first particle drawn is the farthest (most negative z).
      const auto order =
          sorter.sort(reinterpret_cast<const std::byte*>(records.data()), n, 16, view, SortMode::BackToFront, {0, 20});
      float min_z = 1e9f;
      for (std::size_t i = 0; i < n; ++i) min_z = std::min(min_z, records[i * 4 + 2]);
      EXPECT_NEAR(records[order[0] * 4 + 2], min_z, q16 ? 20.0f / 65535 * 2 : 0.0f);
    }
  }
}

}  // namespace

namespace {

TEST(DepthSorter, MergedSourcesSortTogether) {
  // Three streams with their own world transforms: the merged order must equal sorting all
  // their depths together, and each entry must name its stream and index.
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> uni(-3.0f, 3.0f);
  std::vector<std::vector<float>> records(3);
  std::vector<DepthSorter::Source> sources;
  const std::size_t counts[3] = {5000, 1, 7000};
  for (int k = 0; k < 3; ++k) {
    records[k].resize(counts[k] * 4);
    for (auto& v : records[k]) v = uni(rng);
    DepthSorter::Source s;
    s.records = reinterpret_cast<const std::byte*>(records[k].data());
    s.count = counts[k];
    s.view_world = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, float(k), 0, -10.0f - 2.0f * float(k), 1};
    sources.push_back(s);
  }
  DepthSorter sorter(12001);
  const auto order = sorter.sort_merged(sources, SortMode::BackToFront);
  ASSERT_EQ(order.size(), 12001u);
  std::vector<float> all;  // depth = -(z + offset) for these pure translations
  for (int k = 0; k < 3; ++k) {
    for (std::size_t i = 0; i < counts[k]; ++i) all.push_back(-(records[k][i * 4 + 2] - 10.0f - 2.0f * float(k)));
  }
  std::vector<std::uint32_t> global;
  const std::size_t base[3] = {0, 5000, 5001};
  for (std::uint32_t e : order) {
    const std::uint32_t k = e >> DepthSorter::kMergedIndexBits, i = e & ((1u << DepthSorter::kMergedIndexBits) - 1);
    ASSERT_LT(k, 3u);
    ASSERT_LT(i, counts[k]);
    global.push_back(static_cast<std::uint32_t>(base[k] + i));
  }
  for (std::size_t i = 1; i < global.size(); ++i) ASSERT_GE(all[global[i - 1]] + 1e-5f, all[global[i]]) << i;
  std::vector<bool> seen(all.size());
  for (auto g : global) seen[g] = true;
  EXPECT_TRUE(std::all_of(seen.begin(), seen.end(), [](bool b) { return b; }));
}

// Regression (#12): sort_merged passed no near/far to the 16-bit path, so depths far from [0, 1]
// all quantised to the same key and the merged order was the input order.
TEST(DepthSorter, MergedQuantized16UsesNearFar) {
  std::vector<float> a(400), b(400);  // [x y z scale] records, depths 10..30 in both
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> z(-30.0f, -10.0f);
  for (std::size_t i = 0; i < 100; ++i) a[i * 4 + 2] = z(rng), b[i * 4 + 2] = z(rng);
  const std::array<float, 16> identity = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  const DepthSorter::Source sources[2] = {{reinterpret_cast<const std::byte*>(a.data()), 100, 16, identity},
                                          {reinterpret_cast<const std::byte*>(b.data()), 100, 16, identity}};
  DepthSorter sorter(200, {.quantize16 = true});
  const auto order = sorter.sort_merged(sources, SortMode::BackToFront, {10.0f, 30.0f});
  ASSERT_EQ(order.size(), 200u);
  const float resolution = 20.0f / 65535.0f;
  const auto depth = [&](std::uint32_t e) {
    const std::vector<float>& r = (e >> DepthSorter::kMergedIndexBits) ? b : a;
    return -r[(e & ((1u << DepthSorter::kMergedIndexBits) - 1)) * 4 + 2];
  };
  for (std::size_t i = 1; i < order.size(); ++i) ASSERT_LE(depth(order[i]), depth(order[i - 1]) + resolution) << i;
}

}  // namespace
