// The GPU radix sort (render::GpuSorter) on Mesa's llvmpipe: a stable sort whose order equals
// std::stable_sort's, and the CPU depth sorter's, exactly.
#include <gtest/gtest.h>

#include <epoxy/gl.h>

#include <algorithm>
#include <numeric>
#include <random>
#include <vector>

#include <nlohmann/json.hpp>

#include "alloc_counter.hpp"
#include "particlestream/render.hpp"
#include "particlestream/sort.hpp"
#include "test_util.hpp"

namespace {

using namespace pstream;

std::vector<std::uint32_t> stable_order(const std::vector<std::uint32_t>& keys) {
  std::vector<std::uint32_t> order(keys.size());
  std::iota(order.begin(), order.end(), 0u);
  std::stable_sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) { return keys[a] < keys[b]; });
  return order;
}

TEST(GpuSort, StableAndEqualToTheCpuOrderAtEverySize) {
  render::HeadlessContext context(16, 16);
  context.bind();
  render::GpuSorter sorter(1u << 20);
  std::mt19937 rng(7);
  // Sizes around the block (4096 pairs) and thread-run (16) borders, and a million.
  for (const std::uint32_t n : {0u, 1u, 2u, 15u, 17u, 4095u, 4096u, 4097u, 70001u, 1u << 20}) {
    for (const std::uint32_t range : {7u, 1000u, 0xffffffffu}) {  // many ties, some, few
      std::vector<std::uint32_t> keys(n);
      for (auto& k : keys) k = range == 0xffffffffu ? rng() : rng() % range;
      const std::vector<std::uint32_t> gpu = sorter.sort_indices(keys);
      ASSERT_EQ(gpu, stable_order(keys)) << n << " keys below " << range;
    }
  }
  // 16-bit keys: four passes.
  std::vector<std::uint32_t> keys(100000);
  for (auto& k : keys) k = rng() & 0xffffu;
  EXPECT_EQ(sorter.sort_indices(keys, 16), stable_order(keys));
  EXPECT_THROW(sorter.sort((1u << 20) + 1), Error);
  EXPECT_THROW(sorter.sort(10, 8), Error);
}

TEST(GpuSort, KeysAndSortAllocateNothing) {
  // What a host frame of the GPU path would call: depth keys from a records buffer, then the sort
  // (buffers made once, at construction). The driver's own memory is its business; ours is none.
  render::HeadlessContext context(16, 16);
  context.bind();
  constexpr std::uint32_t n = 50000;
  std::vector<float> records(n * 4, 1.0f);
  for (std::uint32_t i = 0; i < n; ++i) records[i * 4 + 2] = float(i % 977);
  GLuint buffer = 0;
  render::GpuSorter sorter(n);
  const std::vector<std::uint32_t> warm =
      sorter.order_by_depth(std::as_bytes(std::span(records)), 16, {0, 0, -1, 0}, true);  // compiles, warms up
  ASSERT_EQ(warm.size(), n);
  glCreateBuffers(1, &buffer);
  glNamedBufferStorage(buffer, GLsizeiptr(records.size() * 4), records.data(), 0);
  const std::uint64_t before = test::allocation_count();
  for (int frame = 0; frame < 10; ++frame) {
    sorter.depth_keys(buffer, 0, n, 16, {0, 0, -1, 0}, frame % 2 == 0);
    sorter.sort(n);
  }
  glFinish();
  EXPECT_EQ(test::allocation_count(), before);
  glDeleteBuffers(1, &buffer);
}

TEST(GpuSort, DepthKeysGiveTheDepthSortersOrder) {
  render::HeadlessContext context(16, 16);
  context.bind();
  constexpr std::size_t n = 200000;
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-5.0f, 5.0f);
  std::vector<float> records(n * 4);
  for (std::size_t i = 0; i < n; ++i) {
    for (int c = 0; c < 3; ++c) records[i * 4 + c] = std::round(u(rng) * 64.0f) / 64.0f;  // many equal depths
    records[i * 4 + 3] = 0.01f;
  }
  const render::Mat4 view = render::look_at({3, 4, 9}, {0, 0, 0}, {0, 1, 0});
  sort::DepthSorter cpu(n);
  render::GpuSorter gpu(n);
  for (const sort::SortMode mode : {sort::SortMode::BackToFront, sort::SortMode::FrontToBack}) {
    const auto cpu_order = cpu.sort(reinterpret_cast<const std::byte*>(records.data()), n, 16, view, mode);
    const std::vector<std::uint32_t> expected(cpu_order.begin(), cpu_order.end());
    std::vector<std::uint32_t> keys(n);
    const auto depths = cpu.depths();
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint32_t k = sort::order_preserving_key(depths[i]);
      keys[i] = mode == sort::SortMode::BackToFront ? ~k : k;
    }
    EXPECT_EQ(gpu.sort_indices(keys), expected);
    // The keys made on the GPU from the records, with the CPU's arithmetic: the same order.
    const sort::DepthAxis a = sort::depth_axis(view);
    EXPECT_EQ(gpu.order_by_depth(std::as_bytes(std::span(records)), 16, {a.x, a.y, a.z, a.offset},
                                 mode == sort::SortMode::BackToFront),
              expected);
  }
}

// `pstream bench sort` reports the GPU sort's own time by a timer query, with 32-bit and 16-bit
// keys, beside the wall time and the host thread's; it fails if the GPU's order is not sorted.
TEST(GpuSort, BenchSortReportsTheGpusOwnTime) {
  const auto r = test::run_cli("bench sort --n 20000 --repetitions 2 --json");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto j = nlohmann::json::parse(r.output.substr(r.output.find('{')));
  EXPECT_NE(j["gpu_renderer"].get<std::string>(), "none");
  for (const char* key : {"gpu_radix_ms", "gpu_radix_gpu_ms", "gpu_radix16_gpu_ms", "gpu_radix_host_thread_ms"}) {
    ASSERT_TRUE(j.contains(key)) << key;
    EXPECT_GT(j[key].get<double>(), 0.0) << key;
  }
  // Half the passes: less GPU time (llvmpipe's is its threads' wall time, so only a loose bound).
  EXPECT_LT(j["gpu_radix16_gpu_ms"].get<double>(), 1.5 * j["gpu_radix_gpu_ms"].get<double>());
}

}  // namespace
