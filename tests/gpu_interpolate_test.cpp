// GPU interpolation (render::GpuInterpolator) against the CPU path (playback::FrameBlender) on
// Mesa's llvmpipe: every value within 2 ulps (or 1e-6 of the inputs' magnitude, where the terms
// cancel), ids and colours exact, for matched, born and dying particles, Hermite and linear, with
// and without velocities, and the nearer frame when there is no matching.
#include <gtest/gtest.h>

#include <epoxy/gl.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <random>
#include <vector>

#include "alloc_counter.hpp"
#include "particlestream/format.hpp"
#include "particlestream/render.hpp"
#include "playback/interpolate.hpp"

namespace {

using namespace pstream;

struct Clip {
  format::Metadata meta;
  std::int32_t velocity = -1, color = -1;
};

Clip make_clip(bool velocities) {
  Clip c;
  c.meta.layout = format::default_layout();
  c.meta.record_size = 16;
  c.color = std::int32_t(format::record_size_of(c.meta.layout));
  c.meta.record_size = format::append_attribute(c.meta.layout, "color", format::AttributeType::Unorm8, 4);
  if (velocities) {
    c.velocity = std::int32_t(c.meta.record_size);
    c.meta.record_size = format::append_attribute(c.meta.layout, "velocity", format::AttributeType::Float32, 3);
  }
  c.meta.record_size = format::append_attribute(c.meta.layout, "id", format::AttributeType::Uint64, 1);
  c.meta.record_size = format::append_attribute(c.meta.layout, "age", format::AttributeType::Float32, 1);
  return c;
}

std::vector<std::byte> random_records(const Clip& c, std::size_t n, std::mt19937& rng) {
  std::vector<std::byte> r(n * c.meta.record_size);
  std::uniform_real_distribution<float> pos(-50.0f, 50.0f), vel(-8.0f, 8.0f), small(0.001f, 0.2f);
  for (std::size_t i = 0; i < n; ++i) {
    std::byte* rec = r.data() + i * c.meta.record_size;
    const float p[3] = {pos(rng), pos(rng), pos(rng)}, s = small(rng);
    std::memcpy(rec, p, 12);
    std::memcpy(rec + 12, &s, 4);
    const std::uint32_t color = rng();
    std::memcpy(rec + c.color, &color, 4);
    if (c.velocity >= 0) {
      const float v[3] = {vel(rng), vel(rng), vel(rng)};
      std::memcpy(rec + c.velocity, v, 12);
    }
    const std::uint64_t id = (std::uint64_t(rng()) << 32) | rng();
    const float age = small(rng) * 10.0f;
    std::memcpy(rec + c.meta.find("id")->offset, &id, 8);
    std::memcpy(rec + c.meta.find("age")->offset, &age, 4);
  }
  return r;
}

// Runs covering na and nb: keeps, drops and inserts at random.
std::vector<format::MatchRun> random_runs(std::uint32_t& na, std::uint32_t& nb, std::mt19937& rng) {
  std::vector<format::MatchRun> runs;
  na = nb = 0;
  for (int k = 0; k < 120; ++k) {
    format::MatchRun r{std::uint32_t(rng() % 30), std::uint32_t(rng() % 3), std::uint32_t(rng() % 3)};
    if (r.keep + r.drop + r.insert == 0) r.keep = 1;
    na += r.keep + r.drop, nb += r.keep + r.insert;
    runs.push_back(r);
  }
  return runs;
}

float word(const std::vector<std::byte>& r, std::size_t w) {
  float v;
  std::memcpy(&v, r.data() + 4 * w, 4);
  return v;
}

TEST(GpuInterpolation, EqualsTheCpuPathWithin2Ulps) {
  render::HeadlessContext context(16, 16);
  context.bind();
  std::mt19937 rng(5);
  std::size_t compared = 0, exact = 0;
  for (const bool velocities : {true, false}) {
    const Clip c = make_clip(velocities);
    const std::vector<render::RecordLane> lanes = playback::record_lanes(c.meta);
    render::GpuInterpolator gpu(lanes, c.velocity, c.color);
    std::uint32_t na = 0, nb = 0;
    const std::vector<format::MatchRun> runs = random_runs(na, nb, rng);
    const std::vector<std::byte> a = random_records(c, na, rng);
    std::vector<std::byte> b = random_records(c, nb, rng);
    // The kept particles moved along their velocities (and a little off them), as persisting
    // particles do: the player then blends them along the curves (velocities_describe_matching()).
    if (c.velocity >= 0) {
      std::uniform_real_distribution<float> off(-0.02f, 0.02f);
      std::size_t i = 0, j = 0;
      for (const format::MatchRun& r : runs) {
        for (std::uint32_t k = 0; k < r.keep; ++k, ++i, ++j) {
          std::byte* rb = b.data() + j * c.meta.record_size;
          const std::byte* ra = a.data() + i * c.meta.record_size;
          for (int x = 0; x < 3; ++x) {
            float p = 0, va = 0, vb = 0;
            std::memcpy(&p, ra + 4 * x, 4);
            std::memcpy(&va, ra + c.velocity + 4 * x, 4);
            std::memcpy(&vb, rb + c.velocity + 4 * x, 4);
            p += float(0.5 / 24 * (double(va) + double(vb))) + off(rng);
            std::memcpy(rb + 4 * x, &p, 4);
          }
        }
        i += r.drop, j += r.insert;
      }
    }
    const std::span<const format::MatchRun> matching(runs);
    const bool curves =
        playback::velocities_describe_matching(a, b, matching, c.meta.record_size, c.velocity, 1.0 / 24);
    EXPECT_EQ(curves, c.velocity >= 0);
    for (const playback::Interpolation mode : {playback::Interpolation::Hermite, playback::Interpolation::Linear}) {
      for (const double t : {0.0, 0.25, 0.5, 0.9}) {
        for (const bool matched : {true, false}) {  // false: no matching, the nearer frame moved
          SCOPED_TRACE(testing::Message()
                       << "velocities " << velocities << " hermite " << (mode == playback::Interpolation::Hermite)
                       << " t " << t << " matched " << matched);
          const double dt = 1.0 / 24;
          playback::FrameBlender cpu(c.meta);
          std::vector<std::byte> expected((na + nb) * c.meta.record_size);
          const bool along_curves = mode == playback::Interpolation::Hermite && curves;
          const std::uint64_t n =
              cpu.blend(a, na, b, nb, matched ? &matching : nullptr, t, dt, along_curves, expected.data());
          expected.resize(n * c.meta.record_size);
          std::vector<render::ParticlePair> pairs(na + nb);
          bool nearer = false;
          pairs.resize(playback::pair_table(na, nb, matched ? &matching : nullptr, t, pairs, nearer));
          ASSERT_EQ(pairs.size(), n);
          ASSERT_EQ(nearer, !matched);
          const std::vector<std::byte> got = gpu.run_host(a, b, pairs, t, dt, along_curves, nearer);
          ASSERT_EQ(got.size(), expected.size());
          const std::size_t words = c.meta.record_size / 4;
          for (std::size_t i = 0; i < n; ++i) {
            for (std::size_t w = 0; w < words; ++w) {
              const std::size_t x = i * words + w;
              const bool is_float = lanes[w] != render::RecordLane::Copy;
              if (!is_float) {  // ids, colours, integers: bit for bit
                ASSERT_EQ(std::memcmp(got.data() + 4 * x, expected.data() + 4 * x, 4), 0)
                    << "particle " << i << " word " << w;
                continue;
              }
              const float e = word(expected, x), g = word(got, x);
              const auto ulps =
                  std::abs(std::int64_t(std::bit_cast<std::int32_t>(e)) - std::int64_t(std::bit_cast<std::int32_t>(g)));
              // Cancelling terms: compare with the magnitude of what was blended (a's and b's
              // records lie within 100 units; velocities scaled by dt or 1/dt).
              const bool close = ulps <= 2 || std::abs(e - g) <= 1e-6 * 1000.0;
              ASSERT_TRUE(close) << "particle " << i << " word " << w << ": CPU " << e << " GPU " << g << " (" << ulps
                                 << " ulps)";
              ++compared;
              exact += e == g;
            }
          }
        }
      }
    }
  }
  EXPECT_GT(compared, 50000u);
  std::printf("%zu float values compared, %zu bit-identical\n", compared, exact);
}

TEST(GpuInterpolation, AHostFrameAllocatesNothing) {
  render::HeadlessContext context(16, 16);
  context.bind();
  std::mt19937 rng(9);
  const Clip c = make_clip(true);
  render::GpuInterpolator gpu(playback::record_lanes(c.meta), c.velocity, c.color);
  std::uint32_t na = 0, nb = 0;
  const std::vector<format::MatchRun> runs = random_runs(na, nb, rng);
  const std::vector<std::byte> a = random_records(c, na, rng), b = random_records(c, nb, rng);
  std::vector<render::ParticlePair> pairs(na + nb);
  bool nearer = false;
  const std::span<const format::MatchRun> matching(runs);
  pairs.resize(playback::pair_table(na, nb, &matching, 0.5, pairs, nearer));
  (void)gpu.run_host(a, b, pairs, 0.5, 1.0 / 24, true, nearer);  // compiles, warms up
  GLuint buffers[4] = {};
  glCreateBuffers(4, buffers);
  glNamedBufferStorage(buffers[0], GLsizeiptr(a.size()), a.data(), 0);
  glNamedBufferStorage(buffers[1], GLsizeiptr(b.size()), b.data(), 0);
  glNamedBufferStorage(buffers[2], GLsizeiptr(pairs.size() * sizeof(render::ParticlePair)), pairs.data(), 0);
  glNamedBufferStorage(buffers[3], GLsizeiptr(pairs.size() * c.meta.record_size), nullptr, 0);
  const std::uint64_t before = test::allocation_count();
  for (int frame = 0; frame < 10; ++frame) {
    gpu.run(buffers[0], buffers[1], buffers[2], std::uint32_t(pairs.size()), 0.1 * frame, 1.0 / 24, true, nearer,
            buffers[3]);
  }
  glFinish();
  EXPECT_EQ(test::allocation_count(), before);
  glDeleteBuffers(4, buffers);
}

}  // namespace
