// The cooker's packing kernel on the frames of points_large.abc (positions -> [x y z scale]
// records, with bounds and the NaN/Inf check), on the best SIMD target and on Highway's scalar
// one, against a memcpy of the same positions (the baseline, in the same run).
#include <benchmark/benchmark.h>
#include <hwy/targets.h>

#include <array>
#include <cstring>
#include <limits>
#include <optional>
#include <vector>

#include "cook/pack_simd.hpp"
#include "particlestream/alembic.hpp"

namespace {

using namespace pstream;

struct Frames {
  alembic::Archive archive = alembic::Archive::open(PSTREAM_TEST_DATA "/alembic/points_large.abc");
  std::vector<std::span<const std::byte>> positions;
  std::vector<std::byte> records = std::vector<std::byte>(50000 * 16);
  std::int64_t particles = 0;
  Frames() {
    const alembic::Points points(*archive.find("/big_cloud"));
    for (std::uint32_t s = 0; s < points.num_samples(); ++s) {
      positions.push_back(points.positions(s).bytes());
      particles += static_cast<std::int64_t>(points.count(s));
    }
  }
};

Frames& frames() {
  static Frames f;
  return f;
}

void BM_MemcpyPositions(benchmark::State& state) {
  Frames& f = frames();
  for (auto _ : state) {
    for (const auto& p : f.positions) std::memcpy(f.records.data(), p.data(), p.size());
    benchmark::DoNotOptimize(f.records.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * f.particles);
}

// Arg 0: the best target this CPU has; 1: Highway's scalar target.
void BM_PackRecords(benchmark::State& state) {
  Frames& f = frames();
  hwy::SetSupportedTargetsForTest(state.range(0) == 1 ? HWY_SCALAR : 0);
  constexpr float inf = std::numeric_limits<float>::infinity();
  for (auto _ : state) {
    for (const auto& p : f.positions) {
      std::array<float, 6> bounds{inf, inf, inf, -inf, -inf, -inf};
      const std::optional<std::size_t> packed =
          cook::pack_untransformed_records(p.data(), nullptr, 0.01f, p.size() / 12, f.records.data(), bounds);
      benchmark::DoNotOptimize(packed);
    }
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * f.particles);
  state.SetLabel(state.range(0) == 1 ? "scalar" : "best target");
  hwy::SetSupportedTargetsForTest(0);
}

BENCHMARK(BM_MemcpyPositions)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_PackRecords)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

}  // namespace
