// Reading every frame's positions of points_large.abc into a caller buffer, against a memcpy
// of exactly the same bytes from the same mapping (the baseline, in the same run).
#include <benchmark/benchmark.h>

#include <cstring>
#include <vector>

#include "particlestream/alembic.hpp"

namespace {

using namespace pstream::alembic;

struct LargeFile {
  Archive archive = Archive::open(PSTREAM_TEST_DATA "/alembic/points_large.abc");
  Points points{*archive.find("/big_cloud")};
  std::vector<float> buffer = std::vector<float>(50000 * 3);
  std::int64_t bytes_per_pass() const { return std::int64_t(points.num_samples()) * 50000 * 12; }
};

LargeFile& large() {
  static LargeFile f;
  return f;
}

void BM_ReadPositionsIntoBuffer(benchmark::State& state) {
  LargeFile& f = large();
  for (auto _ : state) {
    for (std::uint32_t s = 0; s < f.points.num_samples(); ++s) f.points.read_positions(s, f.buffer);
    benchmark::DoNotOptimize(f.buffer.data());
    benchmark::ClobberMemory();
  }
  state.SetBytesProcessed(state.iterations() * f.bytes_per_pass());
}

void BM_MemcpySameBytes(benchmark::State& state) {
  LargeFile& f = large();
  std::vector<std::span<const std::byte>> spans;
  for (std::uint32_t s = 0; s < f.points.num_samples(); ++s) spans.push_back(f.points.positions(s).bytes());
  for (auto _ : state) {
    for (const auto& s : spans) std::memcpy(f.buffer.data(), s.data(), s.size());
    benchmark::DoNotOptimize(f.buffer.data());
    benchmark::ClobberMemory();
  }
  state.SetBytesProcessed(state.iterations() * f.bytes_per_pass());
}

void BM_OpenArchive(benchmark::State& state) {
  for (auto _ : state) {
    Archive a = Archive::open(PSTREAM_TEST_DATA "/alembic/points_varying.abc");
    benchmark::DoNotOptimize(a.objects().size());
  }
}

BENCHMARK(BM_MemcpySameBytes)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ReadPositionsIntoBuffer)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_OpenArchive)->Unit(benchmark::kMicrosecond);

}  // namespace
