// The interpolation kernel (src/playback/interpolate.hpp) on two frames of 1M particles with ids
// and velocities ([x y z scale vx vy vz id64], 36 bytes), against a memcpy of a frame (the
// baseline, in the same run): all matched (the SIMD path), with 1 % births and deaths spread
// through the frame, and without a matching (the nearer frame advected). The matching is made
// once, outside the timing, as the stream's IO worker makes it when it decodes the frame; it is
// timed on its own (BM_MatchById).
#include <benchmark/benchmark.h>

#include <cmath>
#include <cstring>
#include <vector>

#include "particlestream/format.hpp"
#include "playback/interpolate.hpp"

namespace {

using namespace pstream;

constexpr std::uint64_t kCount = 1 << 20;

format::Metadata layout(bool ids) {
  format::Metadata m;
  m.fps = 24.0;
  m.layout = format::default_layout();
  format::append_attribute(m.layout, "velocity", format::AttributeType::Float32, 3);
  m.record_size = format::append_attribute(m.layout, "id", format::AttributeType::Uint64, 1);
  if (!ids) m.layout.back().name = "index";  // the same bytes, not read as ids
  m.max_count = kCount;
  return m;
}

// Frame `f` of particles on circles; every `churn`-th id is replaced in the second frame (a death
// and a birth), ids ascending in both.
std::vector<std::byte> frame(int f, std::uint64_t churn) {
  std::vector<std::byte> out(kCount * 36);
  for (std::uint64_t i = 0; i < kCount; ++i) {
    const double a = double(i) * 0.618 + f / 24.0, r = 1.0 + double(i % 97) * 0.01;
    const float rec[7] = {
        float(r * std::cos(a)), float(i % 997) * 0.002f, float(r * std::sin(a)), 0.01f, float(-r * std::sin(a)), 0.0f,
        float(r * std::cos(a))};
    std::uint64_t id = 2 * i;
    if (f == 1 && churn != 0 && i % churn == 0) id += 1;
    std::memcpy(out.data() + i * 36, rec, 28);
    std::memcpy(out.data() + i * 36 + 28, &id, 8);
  }
  return out;
}

void run(benchmark::State& state, bool ids, std::uint64_t churn, playback::Interpolation mode) {
  const format::Metadata m = layout(ids);
  const auto a = frame(0, 0), b = frame(1, churn);
  std::vector<std::byte> out(2 * kCount * 36);
  playback::FrameBlender blender(m);
  std::vector<format::MatchRun> runs(kCount);
  const std::size_t n = format::match_by_id(m, a, kCount, b, kCount, runs);
  const std::span<const format::MatchRun> matching(runs.data(), n == format::kNoMatching ? 0 : n);
  // Curves or lines: the player decides once a pair of cached frames, as here.
  const bool curves =
      mode == playback::Interpolation::Hermite && n != format::kNoMatching &&
      playback::velocities_describe_matching(a, b, matching, m.record_size, playback::velocity_offset(m), 1 / 24.0);
  double t = 0.2;
  for (auto _ : state) {
    benchmark::DoNotOptimize(blender.blend(a, kCount, b, kCount, n == format::kNoMatching ? nullptr : &matching, t,
                                           1 / 24.0, curves, out.data()));
    t = t > 0.7 ? 0.2 : t + 0.2;  // a new fraction each host frame, as in playback
  }
  state.SetBytesProcessed(std::int64_t(state.iterations()) * std::int64_t(kCount * 36));
}

void BM_MemcpyFrame(benchmark::State& state) {
  const auto a = frame(0, 0);
  std::vector<std::byte> out(kCount * 36);
  for (auto _ : state) {
    std::memcpy(out.data(), a.data(), a.size());
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  }
  state.SetBytesProcessed(std::int64_t(state.iterations()) * std::int64_t(kCount * 36));
}
BENCHMARK(BM_MemcpyFrame)->Unit(benchmark::kMillisecond);

void BM_MatchById(benchmark::State& state) {
  const format::Metadata m = layout(true);
  const auto a = frame(0, 0), b = frame(1, 100);
  std::vector<format::MatchRun> runs(kCount);
  for (auto _ : state) benchmark::DoNotOptimize(format::match_by_id(m, a, kCount, b, kCount, runs));
  state.SetBytesProcessed(std::int64_t(state.iterations()) * std::int64_t(kCount * 36));
}
BENCHMARK(BM_MatchById)->Unit(benchmark::kMillisecond);

void BM_InterpolateHermite(benchmark::State& s) { run(s, true, 0, playback::Interpolation::Hermite); }
void BM_InterpolateLinear(benchmark::State& s) { run(s, true, 0, playback::Interpolation::Linear); }
void BM_InterpolateHermiteChurn1pct(benchmark::State& s) { run(s, true, 100, playback::Interpolation::Hermite); }
void BM_InterpolateNoIds(benchmark::State& s) { run(s, false, 0, playback::Interpolation::Hermite); }
BENCHMARK(BM_InterpolateHermite)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_InterpolateLinear)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_InterpolateHermiteChurn1pct)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_InterpolateNoIds)->Unit(benchmark::kMillisecond);

}  // namespace
