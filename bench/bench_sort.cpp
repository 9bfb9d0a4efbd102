// Depth sort at 1M random keys: ours (radix, 8-bit digits), its 16-bit and 2-thread variants,
// Highway's vqsort and std::sort on the same key-index pairs, plus memcpy of the pairs. And the
// self-shadowing slices' starts (render::slice_starts) over 1M records, which the host works out
// each frame beside the sort (on the GPU path instead of it).
#include <benchmark/benchmark.h>

#include <cstring>
#include <random>

#include "particlestream/frame.hpp"
#include "sort_contenders.hpp"

namespace {

const std::vector<float>& depths() {
  static const std::vector<float> d = [] {
    std::mt19937 rng(1);
    std::uniform_real_distribution<float> uni(-1000.0f, 1000.0f);
    std::vector<float> v(1 << 20);
    for (auto& x : v) x = uni(rng);
    return v;
  }();
  return d;
}

pstream::bench::SortBench& sorter() {
  static pstream::bench::SortBench s(1 << 20);
  return s;
}

void BM_Sort(benchmark::State& state, const char* name) {
  for (auto _ : state) {
    sorter().run(name, depths());
    benchmark::DoNotOptimize(sorter().result.data());
  }
  state.SetItemsProcessed(state.iterations() * std::int64_t(depths().size()));
}

void BM_MemcpyPairs(benchmark::State& state) {
  std::vector<std::uint64_t> a(1 << 20, 1), b(1 << 20);
  for (auto _ : state) {
    std::memcpy(b.data(), a.data(), a.size() * 8);
    benchmark::DoNotOptimize(b.data());
  }
}

// 48 slices (the smoke preset's) of 1M [x y z scale] records: kSliceSamples of them read.
void BM_SliceStarts(benchmark::State& state) {
  std::vector<float> records(std::size_t(4) << 20);
  for (std::size_t i = 0; i < records.size(); ++i) records[i] = depths()[i % depths().size()] * 0.001f;
  pstream::render::ParticleBatch batch;
  batch.first = std::as_bytes(std::span(records));
  batch.count = 1 << 20;
  for (auto _ : state) {
    const auto cut = pstream::render::slice_starts({&batch, 1}, pstream::render::identity(), 48, batch.count);
    benchmark::DoNotOptimize(cut.starts.data());
  }
}

BENCHMARK(BM_MemcpyPairs)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_SliceStarts)->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Sort, ours, "ours")->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Sort, ours_16bit, "ours_16bit")->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Sort, ours_2threads, "ours_2threads")->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK_CAPTURE(BM_Sort, vqsort, "vqsort")->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Sort, std_sort, "std_sort")->Unit(benchmark::kMillisecond);

}  // namespace
