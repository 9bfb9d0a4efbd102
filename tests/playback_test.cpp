// The playback layer: what the viewer, `pstream render` and `pstream demo` draw each host frame.
// Its batches hold exactly the stream's frame (contiguous, whatever the ring did), in depth order
// when asked; several clips are sorted as one; a host frame allocates nothing.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <limits>
#include <map>
#include <numeric>
#include <random>
#include <thread>

#include "alloc_counter.hpp"
#include "particlestream/alembic_writer.hpp"
#include "particlestream/codec.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"
#include "particlestream/playback.hpp"
#include "playback/interpolate.hpp"
#include "test_util.hpp"

namespace {

using namespace pstream;
namespace fs = std::filesystem;

fs::path cook(const fs::path& dir, const std::string& fixture, format::FrameCodec codec) {
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.input = test::data_path("alembic/" + fixture + ".abc");
  o.output = dir / (fixture + (codec == format::FrameCodec::Particle ? "-particle" : "-raw") + ".pstream");
  o.chunk_size = format::kMinChunkSize;  // frames straddle chunks and the ring wraps
  o.frame_codec = codec;
  cook::cook(o);
  return o.output;
}

// Depth along -z of the view for record i (the view here is identity: depth = -z).
float depth(std::span<const std::byte> records, std::uint32_t stride, std::uint32_t i) {
  float z = 0;
  std::memcpy(&z, records.data() + std::size_t(i) * stride + 8, 4);
  return -z;
}

TEST(Playback, BatchesAreTheFramesInDepthOrder) {
  const fs::path dir = test::fresh_dir();
  for (const auto codec : {format::FrameCodec::Records, format::FrameCodec::Particle}) {
    const fs::path file = cook(dir, "points_varying", codec);
    const format::Reader reader = format::Reader::open(file);
    const format::Metadata& m = reader.metadata();
    playback::PlayerOptions options;
    options.stream.blocking = true;
    options.stream.min_slots = 2;
    options.stream.max_slots = 3;
    options.loop = false;
    const fs::path files[] = {file};
    const auto player = playback::Player::open(files, std::move(options));
    std::vector<std::byte> expected(m.max_count * m.record_size);
    player->play();
    std::uint64_t frames_seen = 0;
    for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
      const auto& stats = player->advance(f == 0 ? 0.0 : 1.0 / m.fps, render::identity(), sort::SortMode::BackToFront);
      player->check();
      reader.read_frame(f, expected);
      ASSERT_EQ(stats.particles, m.frames[f].count) << "frame " << f;
      if (m.frames[f].count == 0) {
        EXPECT_TRUE(player->batches().empty());
        continue;
      }
      ASSERT_EQ(player->batches().size(), 1u);
      const render::ParticleBatch& b = player->batches()[0];
      ASSERT_EQ(b.count, m.frames[f].count);
      ASSERT_TRUE(b.second.empty());
      ASSERT_EQ(b.first.size(), b.count * m.record_size);
      ASSERT_EQ(std::memcmp(b.first.data(), expected.data(), b.first.size()), 0) << "frame " << f;
      ASSERT_EQ(b.order.size(), b.count);
      std::vector<bool> seen(b.count);
      for (std::size_t i = 0; i < b.order.size(); ++i) {
        seen[b.order[i]] = true;
        if (i > 0) {
          ASSERT_LE(depth(b.first, m.record_size, b.order[i]), depth(b.first, m.record_size, b.order[i - 1]));
        }
      }
      EXPECT_TRUE(std::all_of(seen.begin(), seen.end(), [](bool s) { return s; }));
      ++frames_seen;
    }
    EXPECT_GT(frames_seen, 50u);
  }
}

TEST(Playback, SeveralClipsAreSortedTogether) {
  const fs::path dir = test::fresh_dir();
  const fs::path files[] = {cook(dir, "points_constant", format::FrameCodec::Records),
                            cook(dir, "points_varying", format::FrameCodec::Particle)};
  playback::PlayerOptions options;
  options.stream.blocking = true;
  const auto player = playback::Player::open(files, std::move(options));
  player->set_world_transform(1, render::translation({0, 0, -0.5f}));
  player->play();
  for (int k = 0; k < 20; ++k)
    player->advance(k == 0 ? 0.0 : 1.0 / 24, render::identity(), sort::SortMode::BackToFront);
  player->check();
  const auto batches = player->batches();
  ASSERT_EQ(batches.size(), 2u);
  const auto order = player->merged_order();
  ASSERT_EQ(order.size(), batches[0].count + batches[1].count);
  const auto depth_of = [&](std::uint32_t e) {
    const std::uint32_t k = e >> sort::DepthSorter::kMergedIndexBits;
    const std::uint32_t i = e & ((1u << sort::DepthSorter::kMergedIndexBits) - 1);
    return depth(batches[k].first, batches[k].record_size, i) + (k == 1 ? 0.5f : 0.0f);
  };
  for (std::size_t i = 1; i < order.size(); ++i) ASSERT_LE(depth_of(order[i]), depth_of(order[i - 1]) + 1e-5f) << i;
}

// The player fills in what a look's shadows need and the style leaves out: the light buffer's
// bounds (the clips' world box, moved by their transforms) and the ground (the backdrop's), for
// self-shadowing sprites and for the liquid alike; what the style sets stays.
TEST(Playback, DrawDataFillsTheShadowsBoundsAndGround) {
  const fs::path dir = test::fresh_dir();
  const fs::path files[] = {cook(dir, "points_constant", format::FrameCodec::Records)};
  playback::PlayerOptions options;
  options.stream.blocking = true;
  const auto player = playback::Player::open(files, std::move(options));
  player->set_world_transform(0, render::translation({0, 2, 0}));
  player->advance(0.0, render::identity(), sort::SortMode::None);
  player->check();
  const std::array<float, 6>& m = player->clip(0).metadata().bounds;
  const std::array<float, 6> world{m[0], m[1] + 2, m[2], m[3], m[4] + 2, m[5]};
  for (const char* look : {"smoke", "liquid"}) {
    playback::DrawStyle style = playback::look_preset(look);
    style.backdrop = playback::backdrop_for("auto", style, world);
    ASSERT_TRUE(style.backdrop && style.backdrop->ground) << look;
    const render::DrawData& d = player->draw_data(style);
    const bool liquid = d.look == render::Look::Liquid;
    const std::array<float, 6>& bounds = liquid ? d.liquid.bounds : d.sprites.bounds;
    const std::optional<float>& ground = liquid ? d.liquid.ground_height : d.sprites.ground_height;
    for (std::size_t i = 0; i < 6; ++i) EXPECT_FLOAT_EQ(bounds[i], world[i]) << look << " " << i;
    ASSERT_TRUE(ground) << look;
    EXPECT_EQ(*ground, style.backdrop->ground_height) << look;
    style.liquid.ground_height = style.sprites.ground_height = -5.0f;
    style.liquid.bounds = style.sprites.bounds = {-1, -1, -1, 1, 1, 1};
    const render::DrawData& e = player->draw_data(style);
    EXPECT_EQ(liquid ? e.liquid.ground_height : e.sprites.ground_height, -5.0f) << look;
    EXPECT_EQ((liquid ? e.liquid.bounds : e.sprites.bounds)[3], 1.0f) << look;
  }
}

TEST(Playback, AHostFrameAllocatesNothing) {
  const fs::path dir = test::fresh_dir();
  const fs::path files[] = {cook(dir, "points_varying", format::FrameCodec::Particle),
                            cook(dir, "points_constant", format::FrameCodec::Records)};
  for (bool blocking : {false, true}) {
    playback::PlayerOptions options;
    options.stream.blocking = blocking;
    options.stream.min_slots = 2;
    options.stream.max_slots = 3;
    const auto player = playback::Player::open(files, std::move(options));
    player->play();
    std::uint64_t drawn = 0;
    const std::uint64_t before = test::allocation_count();
    for (int step = 0; step < 300; ++step) {
      const auto& s = player->advance(1.0 / 96, render::identity(), sort::SortMode::BackToFront);
      drawn += s.particles;
      if (!blocking) std::this_thread::sleep_for(std::chrono::microseconds(500));
    }
    const std::uint64_t after = test::allocation_count();
    player->check();
    EXPECT_EQ(after, before) << "blocking=" << blocking << ": " << (after - before) << " allocations";
    EXPECT_GT(drawn, 0u);
  }
}

// ---- Interpolation on analytic clips -------------------------------------------------------------

// Analytic clips: particles born and dying at whole frames (particle k lives from frame k % 12 for
// 18 frames), moving at constant velocity, ballistically under gravity (p0 + v0 a + g a^2 / 2),
// or in a rigid rotation about the y axis.
enum class Motion { Constant, Ballistic, Rotation };

struct Analytic {
  static constexpr double fps = 24.0, g = -9.81, omega = 2.0;
  static constexpr int frames = 48, particles = 200;
  static int birth(int k) { return k % 12; }
  static bool alive(int k, int f) { return f >= birth(k) && f < birth(k) + 18; }
  static std::array<double, 3> p0(int k) { return {0.01 * k, 1.0, -0.02 * k}; }
  static std::array<double, 3> v0(int k) { return {std::cos(0.3 * k), 4.0 + 0.01 * k, std::sin(0.3 * k)}; }
  static std::array<double, 3> at(Motion m, int k, double t) {
    const double a = t - birth(k) / fps;
    const auto p = p0(k), v = v0(k);
    if (m == Motion::Rotation) {
      const double r = 0.5 + 0.005 * k, phase = 0.1 * k + omega * t;
      return {r * std::cos(phase), 0.01 * k, r * std::sin(phase)};
    }
    const double gravity = m == Motion::Ballistic ? g : 0.0;
    return {p[0] + v[0] * a, p[1] + v[1] * a + 0.5 * gravity * a * a, p[2] + v[2] * a};
  }
  static std::array<double, 3> velocity(Motion m, int k, double t) {
    if (m == Motion::Rotation) {
      const double r = 0.5 + 0.005 * k, phase = 0.1 * k + omega * t;
      return {-r * omega * std::sin(phase), 0.0, r * omega * std::cos(phase)};
    }
    const auto v = v0(k);
    return {v[0], v[1] + (m == Motion::Ballistic ? g : 0.0) * (t - birth(k) / fps), v[2]};
  }
};
using Ballistic = Analytic;

fs::path analytic_clip(const fs::path& dir, Motion motion) {
  const std::string name = motion == Motion::Constant    ? "constant"
                           : motion == Motion::Ballistic ? "ballistic"
                                                         : "rotation";
  const fs::path abc = dir / (name + ".abc");
  {
    alembic::PointsWriterOptions o;
    alembic::ArchiveWriter w(abc, "playback test", name, Analytic::fps, 0.0, o);
    for (int f = 0; f < Analytic::frames; ++f) {
      const double t = f / Analytic::fps;
      std::vector<float> P, V, W;
      std::vector<std::uint64_t> ids;
      for (int k = 0; k < Analytic::particles; ++k) {
        if (!Analytic::alive(k, f)) continue;
        for (double c : Analytic::at(motion, k, t)) P.push_back(float(c));
        for (double c : Analytic::velocity(motion, k, t)) V.push_back(float(c));
        W.push_back(0.02f);
        ids.push_back(std::uint64_t(k));  // ascending in every frame
      }
      w.write_sample({P, ids, V, W, {}});
    }
    w.close();
  }
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.input = abc;
  o.output = dir / (name + ".pstream");
  o.attributes = {"velocity", "id"};
  cook::cook(o);
  return o.output;
}

fs::path ballistic_clip(const fs::path& dir) { return analytic_clip(dir, Motion::Ballistic); }

struct Particle {
  std::array<float, 3> p;
  float scale;
};

// A player of one clip whose stream decodes in the host thread (blocking), not looping.
std::unique_ptr<playback::Player> open_blocking(const fs::path& file, playback::Interpolation mode) {
  playback::PlayerOptions options;
  options.stream.blocking = true;
  options.interpolation = mode;
  options.loop = false;
  const fs::path files[] = {file};
  return playback::Player::open(files, std::move(options));
}

// Plays the clip at `hz` and returns, per host frame, every particle by id.
std::vector<std::map<std::uint64_t, Particle>> play(const fs::path& file, playback::Interpolation mode, double hz) {
  const auto player = open_blocking(file, mode);
  const format::Metadata& m = player->clip(0).metadata();
  const format::Attribute* id = m.find("id");
  player->play();
  std::vector<std::map<std::uint64_t, Particle>> out;
  const int steps = int(std::floor((Ballistic::frames - 1) / Ballistic::fps * hz));
  for (int k = 0; k <= steps; ++k) {
    player->advance(k == 0 ? 0.0 : 1.0 / hz, render::identity(), sort::SortMode::None);
    player->check();
    auto& frame = out.emplace_back();
    for (const auto& b : player->batches()) {
      for (std::uint64_t i = 0; i < b.count; ++i) {
        const std::byte* r = b.first.data() + i * b.record_size;
        std::uint64_t key = 0;
        std::memcpy(&key, r + id->offset, 8);
        Particle p;
        std::memcpy(p.p.data(), r, 12);
        std::memcpy(&p.scale, r + 12, 4);
        frame[key] = p;
      }
    }
  }
  return out;
}

// Max position error against the analytic truth, for particles alive in both cached frames
// around each host time (births and deaths: the pop test below).
double max_error(const fs::path& clip, Motion motion, playback::Interpolation mode, double hz) {
  const auto frames = play(clip, mode, hz);
  EXPECT_GT(frames.size(), 200u);
  double worst = 0;
  for (std::size_t k = 0; k < frames.size(); ++k) {
    const double t = double(k) / hz;
    const int f = int(std::floor(t * Analytic::fps + 1e-9));
    for (const auto& [id, particle] : frames[k]) {
      const int i = int(id);
      if (!Analytic::alive(i, f) || !Analytic::alive(i, f + 1)) continue;
      const auto truth = Analytic::at(motion, i, t);
      for (int c = 0; c < 3; ++c) worst = std::max(worst, double(std::abs(particle.p[c] - truth[c])));
    }
  }
  return worst;
}

TEST(Playback, InterpolatedAnalyticClipsMatchTheTruth) {
  const fs::path dir = test::fresh_dir();
  const double hz = 120.0, dt = 1.0 / Analytic::fps;
  {
    // Constant velocity: both are exact (float rounding of positions up to ~5 units).
    const fs::path clip = analytic_clip(dir, Motion::Constant);
    EXPECT_LT(max_error(clip, Motion::Constant, playback::Interpolation::Hermite, hz), 2e-5);
    EXPECT_LT(max_error(clip, Motion::Constant, playback::Interpolation::Linear, hz), 2e-5);
  }
  {
    // Ballistic: a cubic through exact tangents reproduces the parabola; a chord misses by g dt^2 / 8.
    const fs::path clip = analytic_clip(dir, Motion::Ballistic);
    const double hermite = max_error(clip, Motion::Ballistic, playback::Interpolation::Hermite, hz);
    const double linear = max_error(clip, Motion::Ballistic, playback::Interpolation::Linear, hz);
    EXPECT_LT(hermite, 2e-5);
    EXPECT_NEAR(linear, 9.81 * dt * dt / 8, 2e-4);
    EXPECT_GT(linear / hermite, 50.0);
    std::cout << "ballistic at 120 Hz from 24 fps: max error Hermite " << hermite << ", linear " << linear << " ("
              << linear / hermite << "x)\n";
  }
  {
    // Rigid rotation (radius up to 1.5, 2 rad/s): a chord cuts the arc by r (1 - cos(w dt / 2)).
    const fs::path clip = analytic_clip(dir, Motion::Rotation);
    const double hermite = max_error(clip, Motion::Rotation, playback::Interpolation::Hermite, hz);
    const double linear = max_error(clip, Motion::Rotation, playback::Interpolation::Linear, hz);
    const double sag = 1.495 * (1 - std::cos(Analytic::omega * dt / 2));
    EXPECT_LT(hermite, 2e-5);
    EXPECT_NEAR(linear, sag, 0.1 * sag);
    EXPECT_GT(linear / hermite, 10.0);
    std::cout << "rotation at 120 Hz from 24 fps: max error Hermite " << hermite << ", linear " << linear << " ("
              << linear / hermite << "x)\n";
  }
}

TEST(Playback, NoParticlePopsAtFrameBoundaries) {
  const fs::path dir = test::fresh_dir();
  const fs::path clip = ballistic_clip(dir);
  const double hz = 120.0, host_dt = 1.0 / hz, frame_dt = 1.0 / Ballistic::fps;
  const auto frames = play(clip, playback::Interpolation::Hermite, hz);
  const float full = 0.01f;  // the record's scale: half the 0.02 width
  std::uint64_t checked = 0;
  for (std::size_t k = 1; k < frames.size(); ++k) {
    for (const auto& [id, now] : frames[k]) {
      const auto was = frames[k - 1].find(id);
      if (was == frames[k - 1].end()) {  // appears: grown from nothing, not popped in at full size
        EXPECT_LE(now.scale, full * float(host_dt / frame_dt) * 1.01f) << "id " << id << " at host frame " << k;
        continue;
      }
      // Moves no more than its speed allows over one host frame, and changes size smoothly.
      const auto v = Analytic::velocity(Motion::Ballistic, int(id), double(k) / hz);
      const double speed = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) + 9.81 * host_dt;
      double moved = 0;
      for (int c = 0; c < 3; ++c) moved += double(now.p[c] - was->second.p[c]) * (now.p[c] - was->second.p[c]);
      EXPECT_LE(std::sqrt(moved), speed * host_dt * 1.05 + 1e-5) << "id " << id << " at host frame " << k;
      EXPECT_LE(std::abs(now.scale - was->second.scale), full * float(host_dt / frame_dt) * 1.01f + 1e-7f)
          << "id " << id << " at host frame " << k;
      ++checked;
    }
    for (const auto& [id, was] : frames[k - 1]) {  // disappears: shrunk to nothing first
      if (frames[k].count(id) == 0 && k + 1 < frames.size()) {
        EXPECT_LE(was.scale, full * float(host_dt / frame_dt) * 1.01f) << "id " << id << " at host frame " << k;
      }
    }
  }
  EXPECT_GT(checked, 10000u);
}

// ---- Halfway frames of the real simulations ----------------------------------------------------
//
// Cook every other frame (12 fps from the 24 fps source), play at 24 Hz, and compare each
// interpolated in-between frame with the real one: per particle by id (sparks), or each
// interpolated particle with the nearest real one (FLIP, no ids). The nearest cached frame is the
// baseline. docs/playback.md quotes the figures this prints.

struct HalfwayError {
  double mean = 0, max = 0, nearest_mean = 0, nearest_max = 0, diagonal = 0;
};

// Distance from each point of `a` to the nearest of `b` (sorted by x, searched outwards).
void nearest_distances(const std::vector<std::array<float, 3>>& a, std::vector<std::array<float, 3>> b, double& sum,
                       double& max, std::uint64_t& n) {
  std::sort(b.begin(), b.end(), [](const auto& p, const auto& q) { return p[0] < q[0]; });
  for (const auto& p : a) {
    const auto at = std::lower_bound(b.begin(), b.end(), p[0], [](const auto& q, float x) { return q[0] < x; });
    double best = 1e30;
    for (auto it = at; it != b.end() && double(it->at(0) - p[0]) < best; ++it) {
      const double dx = it->at(0) - p[0], dy = it->at(1) - p[1], dz = it->at(2) - p[2];
      best = std::min(best, std::sqrt(dx * dx + dy * dy + dz * dz));
    }
    for (auto it = at; it != b.begin() && double(p[0] - std::prev(it)->at(0)) < best;) {
      --it;
      const double dx = it->at(0) - p[0], dy = it->at(1) - p[1], dz = it->at(2) - p[2];
      best = std::min(best, std::sqrt(dx * dx + dy * dy + dz * dz));
    }
    sum += best;
    max = std::max(max, best);
    ++n;
  }
}

HalfwayError halfway(const fs::path& dir, const std::string& sim, bool ids,
                     format::FrameCodec codec = format::FrameCodec::Records) {
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.input = test::data_path("sims/" + sim + ".abc");
  o.attributes = ids ? std::vector<std::string>{"velocity", "id"} : std::vector<std::string>{"velocity"};
  o.output = dir / (sim + "_24.pstream");
  cook::cook(o);
  const std::string halved =
      sim + (ids ? "" : "_noids") + (codec == format::FrameCodec::Particle ? "_12_particle" : "_12") + ".pstream";
  o.output = dir / halved;
  o.fps = 12;
  o.frame_codec = codec;
  cook::cook(o);
  const format::Reader truth = format::Reader::open(dir / (sim + "_24.pstream"));
  const format::Metadata& tm = truth.metadata();
  HalfwayError e;
  const float* bb = tm.bounds.data();
  e.diagonal = std::sqrt(double(bb[3] - bb[0]) * (bb[3] - bb[0]) + double(bb[4] - bb[1]) * (bb[4] - bb[1]) +
                         double(bb[5] - bb[2]) * (bb[5] - bb[2]));
  const format::Attribute* id = tm.find("id");
  std::vector<std::byte> records(tm.max_count * tm.record_size);
  for (const auto mode : {playback::Interpolation::Hermite, playback::Interpolation::None}) {
    playback::PlayerOptions options;
    options.stream.blocking = true;
    options.interpolation = mode;
    options.loop = false;
    const fs::path files[] = {dir / halved};
    const auto player = playback::Player::open(files, std::move(options));
    const double t0 = player->clip(0).metadata().time_of_frame0;
    player->seek(t0);
    player->play();
    double sum = 0, max = 0;
    std::uint64_t n = 0;
    for (std::uint64_t f = 0; f + 2 < tm.frame_count(); ++f) {
      player->advance(f == 0 ? 0.0 : 1.0 / 24, render::identity(), sort::SortMode::None);
      player->check();
      if (f % 2 == 0) continue;  // a cached frame: exact
      truth.read_frame(f, records);
      std::vector<std::array<float, 3>> played, real;
      std::map<std::uint64_t, std::array<float, 3>> real_by_id;
      for (std::uint64_t i = 0; i < tm.frames[f].count; ++i) {
        std::array<float, 3> p;
        std::memcpy(p.data(), records.data() + i * tm.record_size, 12);
        real.push_back(p);
        if (id) {
          std::uint64_t key = 0;
          std::memcpy(&key, records.data() + i * tm.record_size + id->offset, 8);
          real_by_id[key] = p;
        }
      }
      for (const auto& b : player->batches()) {
        for (std::uint64_t i = 0; i < b.count; ++i) {
          std::array<float, 3> p;
          std::memcpy(p.data(), b.first.data() + i * b.record_size, 12);
          float scale = 0;
          std::memcpy(&scale, b.first.data() + i * b.record_size + 12, 4);
          if (!id) {
            played.push_back(p);
            continue;
          }
          std::uint64_t key = 0;
          std::memcpy(&key, b.first.data() + i * b.record_size + id->offset, 8);
          const auto it = real_by_id.find(key);
          if (it == real_by_id.end()) continue;  // a death shrinking out (or a birth growing in)
          double d2 = 0;
          for (int c = 0; c < 3; ++c) d2 += double(p[c] - it->second[c]) * (p[c] - it->second[c]);
          sum += std::sqrt(d2);
          max = std::max(max, std::sqrt(d2));
          ++n;
        }
      }
      if (!id) nearest_distances(played, real, sum, max, n);
    }
    EXPECT_GT(n, 100u);
    (mode == playback::Interpolation::None ? e.nearest_mean : e.mean) = sum / double(std::max<std::uint64_t>(n, 1));
    (mode == playback::Interpolation::None ? e.nearest_max : e.max) = max;
  }
  std::cout << halved << " halfway frames (12 -> 24 fps): interpolated mean " << e.mean << " max " << e.max
            << "; nearest frame mean " << e.nearest_mean << " max " << e.nearest_max << "; bounds diagonal "
            << e.diagonal << "\n";
  return e;
}

TEST(Playback, HalfwayFramesOfTheSimulations) {
  const fs::path dir = test::fresh_dir();
  const HalfwayError sparks = halfway(dir, "blender_sparks", true);
  EXPECT_LT(sparks.mean, sparks.nearest_mean / 3);
  // Without ids and without a matching (the records codec) the in-between frame is the nearer
  // frame moved along its velocities. On this FLIP cache that lands further from the real
  // particles than not moving them (docs/playback.md: its velocities do not describe the motion
  // between frames); it stays within 1% of the diagonal.
  const HalfwayError flip = halfway(dir, "blender_flip_pour_small", false);
  EXPECT_LT(flip.mean, 0.01 * flip.diagonal);
  // The sparks with their ids left out of the records (the cook still orders the frames by the
  // source's ids, and the player blends the codec's pairs), measured by the nearest real particle
  // as the FLIP pour is: far closer than the nearest frame. (A cache with no ids at all:
  // Playback.PersistingParticlesWithoutIdsAreMatchedAlongTheirVelocities.)
  const HalfwayError anonymous = halfway(dir, "blender_sparks", false, format::FrameCodec::Particle);
  EXPECT_LT(anonymous.mean, anonymous.nearest_mean / 3);
  // On the FLIP liquid every point of the volume lies within about half a particle spacing of
  // some real particle, so this measure cannot tell the two apart (docs/playback.md); the blend
  // must not be worse than the nearest frame, and its worst particle comes closer.
  const HalfwayError matched = halfway(dir, "blender_flip_pour_small", false, format::FrameCodec::Particle);
  EXPECT_LT(matched.mean, matched.nearest_mean * 1.05);
  EXPECT_LT(matched.max, matched.nearest_max);
  // Sparks through the particle codec (id order: the codec's own matching) as well as by id.
  const HalfwayError sparks_particle = halfway(dir, "blender_sparks", true, format::FrameCodec::Particle);
  EXPECT_LT(sparks_particle.mean, sparks_particle.nearest_mean / 3);
}

// The in-between points (a quarter, a half and three quarters of the way between every two cached
// frames) of `clip` played along curves (Hermite) and along straight lines: how many of them
// differ, and how many there are.
std::pair<std::size_t, std::size_t> curved_and_all(const fs::path& clip) {
  std::vector<std::vector<float>> played[2];
  for (const auto mode : {playback::Interpolation::Hermite, playback::Interpolation::Linear}) {
    const auto player = open_blocking(clip, mode);
    const format::Metadata& m = player->clip(0).metadata();
    EXPECT_NE(m.find("velocity"), nullptr) << clip;
    for (std::uint64_t f = 0; f + 1 < m.frame_count(); ++f) {
      for (const double s : {0.25, 0.5, 0.75}) {
        player->seek(m.time_of_frame0 + (double(f) + s) / m.fps);
        player->advance(0.0, render::identity(), sort::SortMode::None);
        player->check();
        std::vector<float> xyz;
        for (const auto& b : player->batches()) {
          for (std::uint64_t i = 0; i < b.count; ++i) {
            float p[3];
            std::memcpy(p, b.first.data() + i * b.record_size, 12);
            xyz.insert(xyz.end(), p, p + 3);
          }
        }
        played[mode == playback::Interpolation::Linear ? 1 : 0].push_back(std::move(xyz));
      }
    }
  }
  EXPECT_EQ(played[0].size(), played[1].size());
  std::size_t curved = 0;
  for (std::size_t k = 0; k < std::min(played[0].size(), played[1].size()); ++k) {
    EXPECT_EQ(played[0][k].size(), played[1][k].size());
    double most = 0;
    for (std::size_t c = 0; c < std::min(played[0][k].size(), played[1][k].size()); ++c)
      most = std::max(most, double(std::abs(played[0][k][c] - played[1][k][c])));
    curved += most > 1e-4 ? 1 : 0;
  }
  return {curved, played[0].size()};
}

// Curves through the velocities only where they describe the matching: the FLIP liquid's solver
// re-samples its particles, so the codec pairs each with a neighbour about 1 cm away while its
// velocity moves it 5-10 cm a frame, and curves through those velocities swung the whole liquid
// forward along its flow and back by 5-7 mm (a tenth of a frame's motion) between every two cached
// frames. Its frames are blended along straight lines; the sparks' (the same particles in both
// frames) along their curves. Both are the default cooks: the FLIP pour's velocity stored, the
// sparks' derived.
TEST(Playback, CurvesOnlyWhereTheVelocitiesDescribeTheMatching) {
  const fs::path dir = test::fresh_dir();
  for (const auto& [sim, curves] : {std::pair<std::string, bool>{"blender_flip_pour_small", false},
                                    std::pair<std::string, bool>{"blender_sparks", true}}) {
    cook::Options o;
    o.input = test::data_path("sims/" + sim + ".abc");
    o.output = dir / (sim + ".pstream");
    o.frame_begin = 16;
    o.frame_end = 28;
    cook::cook(o);
    const auto [curved, all] = curved_and_all(o.output);
    EXPECT_GT(all, 30u);
    if (curves) {
      EXPECT_EQ(curved, all) << sim << ": every in-between point along the curves";
    } else {
      EXPECT_EQ(curved, 0u) << sim << ": straight lines between frames whose velocities do not describe the matching";
    }
  }
}

// A cache whose particles persist but has no ids (a particle system exported without them): the
// sparks, each frame shuffled, their ids left out, their velocities stored. A spark moves about
// 10 cm a frame and its neighbours are 5 cm away, so the nearest particle is another spark: matched
// by plain position the clip took 6.1 times the bytes it takes with ids, and its pairs blended along
// straight lines. The encoder tries the previous frame moved on by its velocities, finds the sparks
// again, and matches from there: about the size with ids, and curves between every two frames.
TEST(Playback, PersistingParticlesWithoutIdsAreMatchedAlongTheirVelocities) {
  const fs::path dir = test::fresh_dir();
  cook::Options raw;
  raw.input = test::data_path("sims/blender_sparks.abc");
  raw.output = dir / "sparks_raw.pstream";
  raw.frame_codec = format::FrameCodec::Records;
  raw.attributes = {"velocity", "id"};
  cook::cook(raw);
  const format::Reader reader = format::Reader::open(raw.output);
  const format::Metadata& m = reader.metadata();
  const std::uint32_t velocity = m.find("velocity")->offset, id = m.find("id")->offset;
  std::vector<std::vector<float>> position(m.frame_count()), width(m.frame_count()), speed(m.frame_count());
  std::vector<std::vector<std::uint64_t>> ids(m.frame_count());
  std::vector<std::byte> records = format::frame_buffer(m, reader.name());
  std::mt19937 rng(7);
  cook::MemoryClip with_ids, without;
  with_ids.name = without.name = "the sparks, shuffled";
  for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
    reader.read_frame(f, records);
    std::vector<std::uint32_t> order(m.frames[f].count);
    std::iota(order.begin(), order.end(), 0u);
    std::shuffle(order.begin(), order.end(), rng);
    for (const std::uint32_t i : order) {
      const std::byte* r = records.data() + std::size_t(i) * m.record_size;
      float v[7];
      std::memcpy(v, r, 16);
      std::memcpy(v + 4, r + velocity, 12);
      position[f].insert(position[f].end(), v, v + 3);
      width[f].push_back(2 * v[3]);
      speed[f].insert(speed[f].end(), v + 4, v + 7);
      std::uint64_t key = 0;
      std::memcpy(&key, r + id, 8);
      ids[f].push_back(key);
    }
    cook::MemoryFrame frame;
    frame.time = m.time_of_frame0 + double(f) / m.fps;
    frame.count = m.frames[f].count;
    frame.position = position[f];
    frame.width = width[f];
    frame.velocity = speed[f];
    without.frames.push_back(frame);
    frame.id = ids[f];
    with_ids.frames.push_back(frame);
  }
  cook::Options o;
  o.particle.derive_velocity = false;  // stored in both, so that only the matching differs
  o.output = dir / "with_ids.pstream";
  const cook::Report by_id = cook::cook(o, with_ids);
  o.output = dir / "without_ids.pstream";
  const cook::Report by_position = cook::cook(o, without);
  ASSERT_EQ(by_id.order, format::FrameOrder::Id);
  ASSERT_EQ(by_position.order, format::FrameOrder::Matched);
  std::cout << "the sparks shuffled, velocity stored: " << by_id.file_bytes << " bytes with ids, "
            << by_position.file_bytes << " without\n";
  EXPECT_LT(double(by_position.file_bytes), 2.0 * double(by_id.file_bytes));
  // Played: the pairs move as their velocities say, so every in-between point is on the curves.
  const auto [curved, all] = curved_and_all(o.output);
  EXPECT_GT(all, 100u);
  EXPECT_EQ(curved, all);
}

// A crowd parked at an emitter that moves (a cache without ids whose unborn particles wait at
// their emitter), beside particles on a random walk, each frame shuffled: the codec pairs the crowd
// with itself, so between two frames it is one crowd halfway along the emitter's path. Its
// particles were paired but for a few a frame, and the rest were drawn twice between frames, dying
// where the emitter was and born where it went.
TEST(Playback, ACrowdThatMovesTogetherWithoutIdsPlaysAsOneCrowd) {
  constexpr int kFrames = 24, kWalkers = 400, kCrowd = 1200;
  const auto emitter = [](int f) {
    const double a = 0.08 * f;  // 4 cm a frame on a 0.5 m circle
    return std::array<double, 3>{0.5 * std::cos(a), 0.5 * std::sin(a), 0.2};
  };
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> box(-1.0f, 1.0f);
  std::normal_distribution<float> step(0.0f, 0.004f);
  std::vector<std::array<float, 3>> walkers(kWalkers);
  for (auto& p : walkers) p = {box(rng), box(rng), box(rng)};
  std::vector<std::vector<float>> position(kFrames), width(kFrames);
  cook::MemoryClip clip;
  clip.name = "a crowd at a moving emitter";
  for (int f = 0; f < kFrames; ++f) {
    std::vector<std::array<float, 3>> points = walkers;
    const std::array<double, 3> e = emitter(f);
    points.resize(kWalkers + kCrowd, {float(e[0]), float(e[1]), float(e[2])});
    std::shuffle(points.begin(), points.end(), rng);
    for (const auto& p : points) position[std::size_t(f)].insert(position[std::size_t(f)].end(), p.begin(), p.end());
    width[std::size_t(f)].assign(points.size(), 0.01f);
    cook::MemoryFrame frame;
    frame.time = double(f) / 24;
    frame.count = points.size();
    frame.position = position[std::size_t(f)];
    frame.width = width[std::size_t(f)];
    clip.frames.push_back(frame);
    for (auto& p : walkers)
      for (float& c : p) c += step(rng);
  }
  cook::Options o;
  o.output = test::fresh_dir() / "crowd.pstream";
  const cook::Report report = cook::cook(o, clip);
  ASSERT_EQ(report.order, format::FrameOrder::Matched);
  const auto player = open_blocking(o.output, playback::Interpolation::Hermite);
  const format::Metadata& m = player->clip(0).metadata();
  for (int f = 0; f + 1 < kFrames; ++f) {
    player->seek(m.time_of_frame0 + (f + 0.5) / m.fps);
    player->advance(0.0, render::identity(), sort::SortMode::None);
    player->check();
    const std::array<double, 3> a = emitter(f), b = emitter(f + 1);
    std::uint64_t shown = 0, halfway = 0;
    for (const auto& batch : player->batches()) {
      for (std::uint64_t i = 0; i < batch.count; ++i) {
        float p[3];
        std::memcpy(p, batch.first.data() + i * batch.record_size, 12);
        double d = 0;  // squared, to the middle of the emitter's step
        for (int c = 0; c < 3; ++c) d += std::pow(double(p[c]) - (a[std::size_t(c)] + b[std::size_t(c)]) / 2, 2);
        ++shown;
        halfway += d < 0.002 * 0.002 ? 1 : 0;  // the arc is 0.4 mm off its chord's middle
      }
    }
    EXPECT_EQ(shown, std::uint64_t(kWalkers + kCrowd)) << "between frames " << f << " and " << f + 1;
    EXPECT_EQ(halfway, std::uint64_t(kCrowd)) << "between frames " << f << " and " << f + 1;
  }
}

// The rule itself, on records made for it: 28-byte records (position, scale, velocity), 1,000
// particles in a, runs keeping 500, dropping 5, inserting 7 and keeping 495.
TEST(Playback, VelocitiesDescribeTheMatchingWhereTheyMovedTheParticles) {
  constexpr std::uint32_t kStride = 28;
  constexpr double kDt = 1.0 / 24;
  const std::vector<format::MatchRun> runs = {{500, 5, 7}, {495, 0, 0}};
  std::vector<std::byte> a(1000 * kStride), b(1002 * kStride);
  const auto put = [](std::vector<std::byte>& r, std::size_t i, std::size_t word, float v) {
    std::memcpy(r.data() + i * kStride + 4 * word, &v, 4);
  };
  // velocity(i): about 2 m/s in a direction of its own; jitter(i, c): up to 1 cm.
  const auto velocity = [](std::size_t i, int c) { return float(2.0 * std::cos(double(i) * 0.7 + c * 2.1)); };
  const auto jitter = [](std::size_t i, int c) { return float(0.01 * std::sin(double(i) * 1.3 + c)); };
  const auto make = [&](bool follow, float speed) {
    for (std::size_t i = 0; i < 1000; ++i) {
      for (int c = 0; c < 3; ++c) {
        put(a, i, std::size_t(c), float(i % 10) * 0.1f + float(c));
        put(a, i, 4 + std::size_t(c), speed * velocity(i, c));
      }
    }
    // b's particles: a's kept ones moved along their velocity (or by a jitter unrelated to it), then
    // the inserted ones anywhere.
    std::size_t i = 0, j = 0;
    for (const format::MatchRun& r : runs) {
      for (std::uint32_t t = 0; t < r.keep; ++t, ++i, ++j) {
        for (int c = 0; c < 3; ++c) {
          float p = 0;
          std::memcpy(&p, a.data() + i * kStride + 4 * std::size_t(c), 4);
          const float v = speed * velocity(i, c);
          put(b, j, std::size_t(c), follow ? float(p + kDt * v) : p + speed * jitter(i, c));
          put(b, j, 4 + std::size_t(c), v);
        }
      }
      i += r.drop;
      for (std::uint32_t t = 0; t < r.insert; ++t, ++j)
        for (int c = 0; c < 6; ++c) put(b, j, c < 3 ? std::size_t(c) : std::size_t(c + 1), 5.0f);
    }
  };
  make(true, 1.0f);
  EXPECT_TRUE(playback::velocities_describe_matching(a, b, runs, kStride, 16, kDt));
  EXPECT_FALSE(playback::velocities_describe_matching(a, b, runs, kStride, -1, kDt)) << "no velocity";
  make(false, 1.0f);  // re-sampled: paired with neighbours 1 cm away, velocities of 8 cm a frame
  EXPECT_FALSE(playback::velocities_describe_matching(a, b, runs, kStride, 16, kDt));
  make(false, 0.0f);  // at rest
  EXPECT_FALSE(playback::velocities_describe_matching(a, b, runs, kStride, 16, kDt));
  // Runs beyond the frames' records, or none kept: no curves, and nothing read outside the spans.
  make(true, 1.0f);
  const std::vector<format::MatchRun> beyond = {{1500, 0, 0}}, none = {{0, 1000, 1002}};
  EXPECT_FALSE(playback::velocities_describe_matching(a, b, beyond, kStride, 16, kDt));
  EXPECT_FALSE(playback::velocities_describe_matching(a, b, none, kStride, 16, kDt));
  EXPECT_FALSE(playback::velocities_describe_matching({}, {}, runs, kStride, 16, kDt));
}

// match_by_id: the runs pair equal ids, drop the ids that end and insert the ones that begin, and
// refuse what a linear merge cannot match.
TEST(Playback, MatchingByIdPairsEqualIds) {
  format::Metadata m;
  m.layout = format::default_layout();
  m.record_size = format::append_attribute(m.layout, "id", format::AttributeType::Uint64, 1);
  const auto frame = [&](std::vector<std::uint64_t> ids) {
    std::vector<std::byte> out(ids.size() * m.record_size);
    for (std::size_t i = 0; i < ids.size(); ++i) std::memcpy(out.data() + i * m.record_size + 16, &ids[i], 8);
    return out;
  };
  const auto a = frame({1, 2, 3, 5, 8, 9}), b = frame({0, 2, 3, 4, 8, 9, 12});
  std::vector<format::MatchRun> runs(8);
  const std::size_t n = format::match_by_id(m, a, 6, b, 7, runs);
  ASSERT_NE(n, format::kNoMatching);
  // Expand to pairs: previous index -> this index, and the ends and beginnings.
  std::vector<std::pair<int, int>> pairs;
  std::vector<int> dropped, inserted;
  int i = 0, j = 0;
  for (std::size_t r = 0; r < n; ++r) {
    for (std::uint32_t k = 0; k < runs[r].keep; ++k) pairs.emplace_back(i++, j++);
    for (std::uint32_t k = 0; k < runs[r].drop; ++k) dropped.push_back(i++);
    for (std::uint32_t k = 0; k < runs[r].insert; ++k) inserted.push_back(j++);
  }
  EXPECT_EQ(i, 6);
  EXPECT_EQ(j, 7);
  EXPECT_EQ(pairs, (std::vector<std::pair<int, int>>{{1, 1}, {2, 2}, {4, 4}, {5, 5}}));
  EXPECT_EQ(dropped, (std::vector<int>{0, 3}));      // ids 1 and 5 end
  EXPECT_EQ(inserted, (std::vector<int>{0, 3, 6}));  // ids 0, 4 and 12 begin
  // Ids that do not ascend, no id attribute, or more runs than room: no matching.
  const auto unordered = frame({1, 3, 2});
  EXPECT_EQ(format::match_by_id(m, unordered, 3, b, 7, runs), format::kNoMatching);
  EXPECT_EQ(format::match_by_id(m, a, 6, unordered, 3, runs), format::kNoMatching);
  EXPECT_EQ(format::match_by_id(m, a, 6, b, 7, std::span(runs).first(1)), format::kNoMatching);
  format::Metadata no_ids;
  no_ids.layout = format::default_layout();
  no_ids.record_size = 16;
  EXPECT_EQ(format::match_by_id(no_ids, a, 6, b, 6, runs), format::kNoMatching);
  // Identical frames: one run keeping everything.
  EXPECT_EQ(format::match_by_id(m, a, 6, a, 6, runs), 1u);
  EXPECT_EQ(runs[0].keep, 6u);
}

// Retiming: slow motion within a range, looping, at a host rate the cache does not divide. Every
// host frame inside the range shows the analytic truth at the retimed source time, positions and
// velocities (the Hermite curve's derivative); speed 0 holds an in-between moment still.
TEST(Playback, RetimedPlaybackFollowsTheRetimedClock) {
  const fs::path dir = test::fresh_dir();
  const fs::path clip = analytic_clip(dir, Motion::Ballistic);
  playback::PlayerOptions options;
  options.stream.blocking = true;
  options.loop = true;
  const fs::path files[] = {clip};
  const auto player = playback::Player::open(files, std::move(options));
  const format::Metadata& m = player->clip(0).metadata();
  const format::Attribute* id = m.find("id");
  const format::Attribute* velocity = m.find("velocity");
  ASSERT_TRUE(id && velocity);
  const double fps = Analytic::fps, start = 5 / fps, end = 20 / fps, speed = 0.3, hz = 144.0;
  player->set_range(start, end);
  player->seek(start);
  player->set_speed(speed);
  player->play();
  const auto snapshot = [&] {
    std::map<std::uint64_t, std::array<float, 6>> out;  // position, velocity
    for (const auto& b : player->batches()) {
      for (std::uint64_t i = 0; i < b.count; ++i) {
        const std::byte* r = b.first.data() + i * b.record_size;
        std::uint64_t key = 0;
        std::memcpy(&key, r + id->offset, 8);
        std::array<float, 6> pv;
        std::memcpy(pv.data(), r, 12);
        EXPECT_EQ(b.velocity_offset, std::int32_t(velocity->offset));  // handed to the renderer
        std::memcpy(pv.data() + 3, r + b.velocity_offset, 12);
        out[key] = pv;
      }
    }
    return out;
  };
  // Two laps of the range: (end - start + 1/fps) / speed seconds each.
  const double period = end - start + 1 / fps;
  const int steps = int(2 * period / speed * hz);
  double source = start, worst_p = 0, worst_v = 0;
  int compared = 0, laps = 0;
  for (int k = 0; k <= steps; ++k) {
    const double dt = k == 0 ? 0.0 : 1.0 / hz;
    player->advance(dt, render::identity(), sort::SortMode::None);
    player->check();
    source += dt * speed;
    if (source > end + 0.5 / fps) source -= period, ++laps;
    EXPECT_NEAR(player->clip(0).time(), source, 1e-9);
    if (source < start || source > end) continue;  // the loop's seam: the end frame holds
    const int f = int(std::floor(source * fps + 1e-9));
    for (const auto& [key, pv] : snapshot()) {
      const int i = int(key);
      if (!Analytic::alive(i, f) || !Analytic::alive(i, f + 1)) continue;
      const auto p = Analytic::at(Motion::Ballistic, i, source), v = Analytic::velocity(Motion::Ballistic, i, source);
      for (int c = 0; c < 3; ++c) {
        worst_p = std::max(worst_p, double(std::abs(pv[c] - p[c])));
        worst_v = std::max(worst_v, double(std::abs(pv[3 + c] - v[c])));
      }
      ++compared;
    }
  }
  EXPECT_EQ(laps, 2);
  EXPECT_GT(compared, 1000);
  EXPECT_LT(worst_p, 2e-5);
  EXPECT_LT(worst_v, 2e-4);  // velocities of ~4 units/s
  std::cout << "retimed (x" << speed << ", " << hz << " Hz, range 5..20, looping): max error position " << worst_p
            << ", velocity " << worst_v << " over " << compared << " particles\n";
  // Speed 0 between two cached frames: the frame stays exactly where it is.
  player->seek(10.4 / fps);
  player->set_speed(1.0);
  player->advance(0.0, render::identity(), sort::SortMode::None);
  player->set_speed(0.0);
  player->advance(1.0 / hz, render::identity(), sort::SortMode::None);
  const auto held = snapshot();
  ASSERT_FALSE(held.empty());
  for (int k = 0; k < 10; ++k) {
    player->advance(1.0 / hz, render::identity(), sort::SortMode::None);
    EXPECT_EQ(snapshot(), held);
  }
  EXPECT_NEAR(player->clip(0).time(), 10.4 / fps, 1e-12);
  EXPECT_GT(player->clip(0).fraction(), 0.3);  // held between frames 10 and 11, interpolated
}

// The largest distance of the player's records from the ballistic truth at clip time `source`,
// over the particles alive in both cached frames around it (births and deaths grow and shrink
// instead); `compared` counts them.
double ballistic_error(const playback::Player& player, const format::Attribute& id, double source, int& compared) {
  const int f = int(std::floor(source * Analytic::fps + 1e-9));
  double worst = 0;
  for (const auto& b : player.batches()) {
    for (std::uint64_t i = 0; i < b.count; ++i) {
      const std::byte* r = b.first.data() + i * b.record_size;
      std::uint64_t key = 0;
      std::memcpy(&key, r + id.offset, 8);
      if (!Analytic::alive(int(key), f) || !Analytic::alive(int(key), f + 1)) continue;
      float p[3];
      std::memcpy(p, r, 12);
      const auto truth = Analytic::at(Motion::Ballistic, int(key), source);
      for (int c = 0; c < 3; ++c) worst = std::max(worst, double(std::abs(p[c] - truth[c])));
      ++compared;
    }
  }
  return worst;
}

// Reverse: speed -1 from the end to the start, at 120 Hz, through a records clip and a particle
// clip (keyframes every 8 frames: each backward step decodes from one). Every host frame shows
// the truth at the clock running backwards, interpolated, births and deaths included (a
// particle's size only shrinks or grows through the pop test's rule).
TEST(Playback, ReversePlaybackIsInterpolatedToo) {
  const fs::path dir = test::fresh_dir();
  const fs::path records = analytic_clip(dir, Motion::Ballistic);
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.input = dir / "ballistic.abc";
  o.output = dir / "ballistic-particle.pstream";
  o.attributes = {"velocity", "id"};
  o.frame_codec = format::FrameCodec::Particle;
  o.particle.keyframe_interval = 8;
  o.particle.error = 5e-6;
  o.particle.error_relative = false;
  o.particle.derive_velocity = false;  // Hermite with the stored velocities (derived: DerivedVelocity.*)
  cook::cook(o);
  for (const fs::path& clip : {records, o.output}) {
    SCOPED_TRACE(clip.filename().string());
    playback::PlayerOptions options;
    options.stream.blocking = true;
    options.loop = false;
    const fs::path files[] = {clip};
    const auto player = playback::Player::open(files, std::move(options));
    const format::Metadata& m = player->clip(0).metadata();
    const format::Attribute* id = m.find("id");
    const double hz = 120.0, end = m.frames.back().time;
    player->seek(end);
    player->set_speed(-1.0);
    player->play();
    double worst = 0, source = end;
    int compared = 0;
    const int steps = int(end * hz);
    for (int k = 0; k <= steps; ++k) {
      const double dt = k == 0 ? 0.0 : 1.0 / hz;
      const playback::FrameStats& stats = player->advance(dt, render::identity(), sort::SortMode::None);
      player->check();
      source = std::max(0.0, source - dt);
      ASSERT_NEAR(player->clip(0).time(), source, 1e-9);
      EXPECT_EQ(stats.unmatched_clips, 0u) << "host frame " << k << " clip frame " << player->clip(0).frame().frame;
      worst = std::max(worst, ballistic_error(*player, *id, source, compared));
    }
    EXPECT_GT(compared, 10000);
    EXPECT_LT(worst, 2e-5);
    std::cout << clip.filename().string() << " backwards at 120 Hz: max error " << worst << " over " << compared
              << " particles, " << player->clip(0).debug().frames_decoded << " frame decodes\n";
    player->advance(1.0 / hz, render::identity(), sort::SortMode::None);
    EXPECT_EQ(player->clip(0).state(), stream::PlayState::Paused);  // held at the start
    EXPECT_EQ(player->clip(0).time(), 0.0);
  }
}

// A seek to where the stream has decoded already keeps the frames it needs (the target and the one
// after it), and the frames decoded after them are matched to them as in forward play. The records
// clip with ids is matched by id on the IO worker, against the frame before's records: after a kept
// frame, those are the kept slot's (a copy decoded again as a reference would take the slot the next
// frame needs, and leave it unmatched).
TEST(Playback, ASeekKeepsTheDecodedFramesItNeedsAndWhatFollowsStaysMatched) {
  const fs::path dir = test::fresh_dir();
  const auto player = open_blocking(analytic_clip(dir, Motion::Ballistic), playback::Interpolation::Hermite);
  const format::Attribute* id = player->clip(0).metadata().find("id");
  ASSERT_TRUE(id);
  const double hz = 120.0, start = 5.5 / Analytic::fps;
  player->seek(start);
  player->play();
  player->advance(0.0, render::identity(), sort::SortMode::None);  // frames 5 and 6, and ahead
  // Until the IO worker has filled every decoded slot (5, 6, 7) and stopped.
  for (int wait = 0; wait < 500; ++wait) {
    const stream::DebugInfo d = player->clip(0).debug();
    if (d.decoded_ready == d.decoded_slots) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  const std::uint64_t decoded = player->clip(0).debug().frames_decoded;
  ASSERT_GE(decoded, 2u);
  player->seek(start);  // the same place: 6 is kept
  double source = start, worst = 0;
  int compared = 0;
  for (int k = 0; k < 60; ++k) {
    const double dt = k == 0 ? 0.0 : 1.0 / hz;
    const playback::FrameStats& stats = player->advance(dt, render::identity(), sort::SortMode::None);
    player->check();
    source += dt;
    if (k == 0) {  // 6 shown as it was (5 came first after a restart: without its matching, not kept)
      const stream::DebugInfo d = player->clip(0).debug();
      EXPECT_LE(d.frames_decoded, decoded + d.decoded_slots - 1);
    }
    EXPECT_EQ(stats.unmatched_clips, 0u) << "host frame " << k << " clip frame " << player->clip(0).frame().frame;
    worst = std::max(worst, ballistic_error(*player, *id, source, compared));
  }
  EXPECT_GT(compared, 10000);
  EXPECT_LT(worst, 2e-5);
}

// The clock is arithmetic: a huge, infinite or NaN host step neither hangs nor leaves the range.
TEST(Playback, HugeHostStepsStayInTheRange) {
  const fs::path dir = test::fresh_dir();
  const fs::path clip = analytic_clip(dir, Motion::Constant);
  playback::PlayerOptions options;
  options.stream.blocking = true;
  const fs::path files[] = {clip};
  const auto player = playback::Player::open(files, std::move(options));
  const format::Metadata& m = player->clip(0).metadata();
  const double start = m.frames.front().time, end = m.frames.back().time;
  player->play();
  for (const double speed : {1.0, -1.0, 1e12}) {
    player->set_speed(speed);
    for (const double dt : {1e300, 1e-300, std::numeric_limits<double>::infinity(), std::nan(""), 7.3}) {
      player->advance(dt, render::identity(), sort::SortMode::None);
      player->check();
      EXPECT_GE(player->clip(0).time(), start - 0.5 / m.fps) << speed << " " << dt;
      EXPECT_LE(player->clip(0).time(), end + 0.5 / m.fps) << speed << " " << dt;
      EXPECT_TRUE(std::isfinite(player->clip(0).time()));
    }
  }
}

}  // namespace

// ---- Derived velocity -------------------------------------------------------------------------

namespace {

struct Positions {
  std::map<std::uint64_t, std::array<float, 3>> by_id;
};

// Every particle of the player's frame at `time`, by id (the clip's record must hold one).
Positions play_at(playback::Player& player, double time) {
  player.seek(time);
  player.advance(0.0, render::identity(), sort::SortMode::None);
  player.check();
  const format::Metadata& m = player.clip(0).metadata();
  const format::Attribute* id = m.find("id");
  Positions out;
  for (const auto& b : player.batches()) {
    for (std::uint64_t i = 0; i < b.count; ++i) {
      const std::byte* r = b.first.data() + i * b.record_size;
      std::uint64_t key = 0;
      std::memcpy(&key, r + id->offset, id->size());
      std::array<float, 3> p;
      std::memcpy(p.data(), r, 12);
      out.by_id[key] = p;
    }
  }
  return out;
}

std::unique_ptr<playback::Player> open_player(const fs::path& clip) {
  playback::PlayerOptions options;
  options.stream.blocking = true;
  options.loop = false;
  const fs::path files[] = {clip};
  return playback::Player::open(files, std::move(options));
}

}  // namespace

// A clip with ids stores no velocity: the decoder derives it from each particle's last two grid
// steps. On ballistic motion (a parabola) the second-order difference is exact but for the
// quantisation, and on circular motion its error is (1/3) h² |v'''|; keyframes every 8 frames
// give the same velocities as the frames between them. Playback's Hermite curves with it stay
// as close to the truth as with the stored velocity.
TEST(DerivedVelocity, AnalyticMotionGetsItsVelocityBackAndPlaysAsWithAStoredOne) {
  const fs::path dir = test::fresh_dir();
  for (const Motion motion : {Motion::Ballistic, Motion::Rotation}) {
    SCOPED_TRACE(motion == Motion::Ballistic ? "ballistic" : "rotation");
    const fs::path records = analytic_clip(dir, motion);
    const fs::path abc = fs::path(records).replace_extension(".abc");
    double position_error[2] = {0, 0};
    for (const bool derive : {true, false}) {
      cook::Options o;
      o.input = abc;
      o.output = dir / (abc.stem().string() + (derive ? "-derived.pstream" : "-stored.pstream"));
      o.attributes = {"id"};
      o.particle.keyframe_interval = 8;
      o.particle.error = 5e-6;
      o.particle.error_relative = false;
      o.particle.derive_velocity = derive;
      cook::cook(o);
      const format::Reader reader = format::Reader::open(o.output);
      const format::Metadata& m = reader.metadata();
      const format::Attribute* v = m.find("velocity");
      const format::Attribute* id = m.find("id");
      ASSERT_NE(v, nullptr);
      EXPECT_EQ(m.codec.words[v->offset / 4].coding,
                derive ? format::WordCoding::Derived : format::WordCoding::Quantized);
      if (derive) {
        // Every frame's velocities against the truth: particles with two steps behind them, and
        // new ones (their first step is the source's velocity over a frame).
        double worst_two = 0, worst_new = 0;
        std::vector<std::byte> frame = format::frame_buffer(m, "derived");
        for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
          reader.read_frame(f, frame);
          for (std::uint64_t i = 0; i < m.frames[f].count; ++i) {
            const std::byte* r = frame.data() + i * m.record_size;
            std::uint64_t key = 0;
            std::memcpy(&key, r + id->offset, 8);
            float got[3];
            std::memcpy(got, r + v->offset, 12);
            const auto truth = Analytic::velocity(motion, int(key), double(f) / Analytic::fps);
            double e = 0;
            for (int c = 0; c < 3; ++c) e = std::max(e, std::abs(double(got[c]) - truth[c]));
            const bool two = f >= 2 && Analytic::alive(int(key), int(f) - 2);
            (two ? worst_two : worst_new) = std::max(two ? worst_two : worst_new, e);
          }
        }
        std::printf("derived velocity: max error %.3g m/s with two steps, %.3g for new particles\n", worst_two,
                    worst_new);
        EXPECT_LT(worst_two, motion == Motion::Ballistic ? 2e-3 : 2e-2);
        EXPECT_LT(worst_new, motion == Motion::Ballistic ? 2e-3 : 2e-2);  // seeded by the source's velocity
      }
      // Playback at 120 Hz: Hermite curves through the decoded frames against the truth.
      const auto player = open_player(o.output);
      double worst = 0;
      for (int k = 0; k < int(Analytic::frames - 1) * 5; ++k) {
        const double t = k / 120.0;
        const int f = int(std::floor(t * Analytic::fps + 1e-9));
        for (const auto& [key, p] : play_at(*player, t).by_id) {
          if (!Analytic::alive(int(key), f) || !Analytic::alive(int(key), f + 1)) continue;
          const auto truth = Analytic::at(motion, int(key), t);
          for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(double(p[c]) - truth[c]));
        }
      }
      position_error[derive ? 0 : 1] = worst;
    }
    std::printf("playback at 120 Hz, max position error: derived %.3g, stored %.3g\n", position_error[0],
                position_error[1]);
    // Ballistic: as close as the stored velocity (both within the position bound's reach).
    // Rotation: the velocity's (1/3) h² r ω³ ≈ 0.007 m/s error moves a curve by ~3e-5.
    EXPECT_LT(position_error[0], motion == Motion::Ballistic ? 2.0 * position_error[1] + 1e-5 : 5e-5);
  }
}

// Halfway frames: the sparks fixture cooked at 12 fps, every other frame of its 24, played at the
// frames left out and compared with them by id. Hermite curves with the derived velocity (the
// second-order difference over 1/12 s) against those with Blender's stored velocity.
TEST(DerivedVelocity, HalfwayFramesOfTheSparksAreAsCloseAsWithStoredVelocity) {
  const fs::path dir = test::fresh_dir();
  const std::string sparks = test::data_path("sims/blender_sparks.abc");
  cook::Options truth_options;
  truth_options.input = sparks;
  truth_options.output = dir / "truth.pstream";
  truth_options.frame_codec = format::FrameCodec::Records;
  truth_options.attributes = {"id"};
  cook::cook(truth_options);
  const format::Reader truth = format::Reader::open(truth_options.output);
  const format::Metadata& tm = truth.metadata();
  const format::Attribute* tid = tm.find("id");
  std::vector<std::byte> frame = format::frame_buffer(tm, "truth");
  // Derived velocity, stored velocity, none (linear interpolation).
  double rms[3] = {0, 0, 0}, worst[3] = {0, 0, 0};
  for (const int variant : {0, 1, 2}) {
    const bool derive = variant == 0;
    cook::Options o;
    o.input = sparks;
    o.output = dir / ("half-" + std::to_string(variant) + ".pstream");
    o.fps = tm.fps / 2;
    o.attributes = {"id"};
    o.particle.derive_velocity = derive;
    o.keep_velocity = variant != 2;
    cook::cook(o);
    const auto player = open_player(o.output);
    double sum = 0;
    std::uint64_t n = 0;
    // The odd frames between the first and last kept ones, by time.
    for (std::uint64_t f = 1; f + 1 < tm.frame_count(); f += 2) {
      const Positions got = play_at(*player, tm.frames[f].time);
      truth.read_frame(f, frame);
      for (std::uint64_t i = 0; i < tm.frames[f].count; ++i) {
        const std::byte* r = frame.data() + i * tm.record_size;
        std::uint64_t key = 0;
        std::memcpy(&key, r + tid->offset, 8);
        const auto it = got.by_id.find(key);
        if (it == got.by_id.end()) continue;  // born or dead between the kept frames
        float p[3];
        std::memcpy(p, r, 12);
        double e2 = 0;
        for (int c = 0; c < 3; ++c) e2 += (double(it->second[c]) - p[c]) * (double(it->second[c]) - p[c]);
        sum += e2;
        worst[variant] = std::max(worst[variant], std::sqrt(e2));
        ++n;
      }
    }
    ASSERT_GT(n, 10000u);
    rms[variant] = std::sqrt(sum / double(n));
  }
  std::printf(
      "sparks at 12 fps, the 24 fps frames between: RMS error derived %.4g m, stored %.4g m, linear %.4g m; "
      "max %.3g / %.3g / %.3g\n",
      rms[0], rms[1], rms[2], worst[0], worst[1], worst[2]);
  // Measured: 1.33 cm derived, 0.80 cm stored (Blender's velocities are exact where the sparks
  // fly free; the backward difference over 1/12 s lags at collisions and drag).
  EXPECT_LT(rms[0], 2.0 * rms[1]);
  EXPECT_LT(rms[0], rms[2]);
}

// The default cook derives velocity where particles have ids (no bytes stored) and stores the
// source's where they have none: the codec's matching by position pairs nearby particles, not
// the same ones (on Blender's FLIP a derived velocity's RMS error is the speed's own RMS).
TEST(DerivedVelocity, TheDefaultCookDerivesWithIdsAndStoresWithout) {
  const fs::path dir = test::fresh_dir();
  std::uint64_t bytes[2] = {0, 0};
  for (const bool store : {false, true}) {
    cook::Options o;
    o.input = test::data_path("sims/blender_sparks.abc");
    o.output = dir / (store ? "sparks-stored.pstream" : "sparks.pstream");
    o.particle.derive_velocity = !store;
    bytes[store ? 1 : 0] = cook::cook(o).file_bytes;
    const format::Metadata m = format::Reader::open(o.output).metadata();
    const format::Attribute* v = m.find("velocity");
    ASSERT_NE(v, nullptr);
    EXPECT_EQ(m.codec.words[v->offset / 4].coding, store ? format::WordCoding::Quantized : format::WordCoding::Derived);
  }
  EXPECT_LT(double(bytes[0]), 0.95 * double(bytes[1]));  // measured: 1.90 against 2.07 bytes per particle
  cook::Options o;
  o.input = test::data_path("sims/blender_flip_pour_small.abc");
  o.output = dir / "flip.pstream";
  cook::cook(o);
  const format::Metadata m = format::Reader::open(o.output).metadata();
  ASSERT_NE(m.find("velocity"), nullptr);
  EXPECT_EQ(m.codec.order, format::FrameOrder::Matched);
  EXPECT_EQ(m.codec.words[m.find("velocity")->offset / 4].coding, format::WordCoding::Quantized);
}

namespace {

// A clip's colour is four unorm8 named "color" (RGBA) wherever it is read: the batches, both
// blends and the browser player ask playback::color_offset(). A "color" of another type is an
// attribute like any other, and the clip draws in its stream's colour rather than as bytes.
TEST(Playback, OnlyAnRgba8ColorIsHandedOutAsTheColour) {
  const fs::path dir = test::fresh_dir();
  const auto clip = [&](const std::string& name, format::AttributeType type, std::uint32_t components) {
    format::Metadata meta;
    meta.fps = 24;
    meta.chunk_size = format::kMinChunkSize;
    meta.layout = format::default_layout();
    meta.record_size = format::append_attribute(meta.layout, "color", type, components);
    const fs::path path = dir / (name + ".pstream");
    format::Writer writer(path, meta);
    std::vector<std::byte> stream;
    for (int f = 0; f < 3; ++f) {
      writer.append_frame(2, f / 24.0, {0, 0, 0, 1, 1, 1});
      for (int i = 0; i < 2; ++i) {
        std::vector<std::byte> r(meta.record_size, std::byte{0x40});
        const float p[4] = {0.5f * float(i), 0.1f * float(f), 0.0f, 0.25f};
        std::memcpy(r.data(), p, 16);
        stream.insert(stream.end(), r.begin(), r.end());
      }
    }
    writer.append_chunk(stream, format::Codec::Raw, 0, format::checksum(stream));
    writer.commit();
    return path;
  };
  const fs::path rgba8 = clip("rgba8", format::AttributeType::Unorm8, 4);
  const fs::path rgb32f = clip("rgb32f", format::AttributeType::Float32, 3);
  EXPECT_EQ(playback::color_offset(format::Reader::open(rgba8).metadata()), 16);
  EXPECT_EQ(playback::color_offset(format::Reader::open(rgb32f).metadata()), -1);
  EXPECT_EQ(playback::velocity_offset(format::Reader::open(rgb32f).metadata()), -1);
  for (const auto interpolation : {playback::Interpolation::None, playback::Interpolation::Linear}) {
    for (const auto& [file, expected] : {std::pair{rgba8, 16}, std::pair{rgb32f, -1}}) {
      playback::PlayerOptions options;
      options.stream.blocking = true;
      options.interpolation = interpolation;
      options.loop = false;
      const fs::path files[] = {file};
      const auto player = playback::Player::open(files, std::move(options));
      player->play();
      for (int k = 0; k < 4; ++k) {
        player->advance(k == 0 ? 0.0 : 0.5 / 24, render::identity(), sort::SortMode::None);
        player->check();
        ASSERT_EQ(player->batches().size(), 1u) << file << " step " << k;
        const render::ParticleBatch& b = player->batches()[0];
        EXPECT_EQ(b.color_offset, expected) << file << " step " << k;
        ASSERT_EQ(b.count, 2u);
        // The colour bytes (either type) come through the blend as written.
        const std::byte* r = b.first.data() + b.record_size;
        EXPECT_EQ(r[16], std::byte{0x40}) << file << " step " << k;
      }
    }
  }
}

// Self-shadowing slices (render::slice_starts) bound each slice in depth as well as in count: a
// dense core of 9,000 particles over 1 unit of depth and a sparse tail of 1,000 over the next 4
// (a smoke plume's top seen along the half-angle). Equal counts give the tail three slices of
// about 1.3 units each, where its particles do not shadow each other; the library's slices each
// span at most a little over 2/32 of the depth and hold at most a little over 2/32 of the
// particles. A uniform cloud keeps nearly equal counts, and the GPU path's sample (a FramePair's
// earlier frame) and two merged batches give the same starts as the records themselves.
TEST(SliceStarts, BoundEachSliceInDepthAsWellAsCount) {
  constexpr std::uint64_t kCore = 9000, kTail = 1000, kTotal = kCore + kTail;
  constexpr int kSlices = 32;
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0, 1);
  std::vector<float> records(kTotal * 4), depths(kTotal);
  for (std::uint64_t i = 0; i < kTotal; ++i) {
    const float d = i < kCore ? u(rng) : 1 + 4 * u(rng);
    depths[i] = d;
    const float r[4] = {u(rng), u(rng), -d, 0.05f};  // depth is -z in the sort's view
    std::memcpy(&records[i * 4], r, sizeof r);
  }
  std::sort(depths.begin(), depths.end());  // the drawing order's depths, front to back
  render::ParticleBatch batch;
  batch.first = std::as_bytes(std::span(records));
  batch.count = kTotal;
  const render::Mat4 sort_view = render::identity();
  const render::SliceStarts cut = render::slice_starts({&batch, 1}, sort_view, kSlices, kTotal);
  ASSERT_EQ(cut.slices, kSlices);
  EXPECT_EQ(cut.starts[0], 0u);
  EXPECT_EQ(cut.starts[kSlices], kTotal);
  const double range = depths.back() - depths.front();
  const auto widest = [&](const auto& starts) {  // the largest depth span and count of a slice
    double span = 0;
    std::uint64_t most = 0;
    for (int k = 0; k < kSlices; ++k) {
      const std::uint64_t a = starts[std::size_t(k)], b = starts[std::size_t(k) + 1];
      EXPECT_LE(a, b) << "slice " << k;
      if (b <= a) continue;
      span = std::max(span, double(depths[b - 1] - depths[a]));
      most = std::max(most, b - a);
    }
    return std::pair{span, most};
  };
  const auto [span, most] = widest(cut.starts);
  std::printf("slice_starts: widest slice %.3f of %.3f depth units, largest %llu of %llu particles\n", span, range,
              static_cast<unsigned long long>(most), static_cast<unsigned long long>(kTotal));
  EXPECT_LE(span, 2.5 * range / kSlices);
  EXPECT_LE(double(most), 2.5 * double(kTotal) / kSlices);
  std::array<std::uint64_t, kSlices + 1> equal{};
  for (int k = 0; k <= kSlices; ++k) equal[std::size_t(k)] = kTotal * std::uint64_t(k) / kSlices;
  EXPECT_GT(widest(equal).first, 2.5 * range / kSlices) << "equal counts should make the tail's slices thick";

  // The same particles through a FramePair (the GPU path's records are made on the GPU), and as
  // two batches, the second moved by its world transform back onto the first's places.
  render::FramePair pair;
  pair.a = batch.first;
  pair.a_count = kTotal;
  pair.record_size = 16;
  render::ParticleBatch on_gpu;
  on_gpu.pair = &pair;
  on_gpu.count = kTotal;
  EXPECT_EQ(render::slice_starts({&on_gpu, 1}, sort_view, kSlices, kTotal).starts, cut.starts);
  std::vector<float> moved(records);
  for (std::uint64_t i = kTotal / 2; i < kTotal; ++i) moved[i * 4 + 2] += 10;  // 10 further, moved back by `world`
  render::ParticleBatch halves[2];
  halves[0].first = std::as_bytes(std::span(moved).first(kTotal / 2 * 4));
  halves[0].count = kTotal / 2;
  halves[1].first = std::as_bytes(std::span(moved).subspan(kTotal / 2 * 4));
  halves[1].count = kTotal - kTotal / 2;
  halves[1].world[14] = -10;
  const render::SliceStarts merged = render::slice_starts(halves, sort_view, kSlices, kTotal);
  const auto [merged_span, merged_most] = widest(merged.starts);
  EXPECT_LE(merged_span, 2.5 * range / kSlices);
  EXPECT_LE(double(merged_most), 2.5 * double(kTotal) / kSlices);

  // A uniform cloud: the two shares grow together, so the counts stay nearly equal.
  for (std::uint64_t i = 0; i < kTotal; ++i) records[i * 4 + 2] = -float(i) / float(kTotal);
  const render::SliceStarts uniform = render::slice_starts({&batch, 1}, sort_view, kSlices, kTotal);
  for (int k = 0; k <= kSlices; ++k)
    EXPECT_NEAR(double(uniform.starts[std::size_t(k)]), double(equal[std::size_t(k)]), 0.01 * kTotal) << k;

  // Nothing to cut: no particles, one slice, or more slices than allowed (clamped).
  EXPECT_EQ(render::slice_starts({}, sort_view, kSlices, 0).starts[kSlices], 0u);
  const render::SliceStarts one = render::slice_starts({&batch, 1}, sort_view, 1, kTotal);
  EXPECT_EQ(one.slices, 1);
  EXPECT_EQ(one.starts[1], kTotal);
  EXPECT_EQ(render::slice_starts({&batch, 1}, sort_view, 1000, kTotal).slices, render::kMaxSlices);
}

// Camera::framing in a region of the image (the viewer's, beside its panel): every corner of the
// box lands inside the region, the box fills it as closely as the plain framing fills the whole
// image, and the target is the region's centre.
TEST(Camera, FramingInARegionKeepsTheBoxInsideIt) {
  using namespace pstream::render;
  const Vec3 lo{-1.0f, 0.0f, -2.0f}, hi{1.5f, 3.0f, 2.0f};
  const float aspect = 16.0f / 9.0f;
  struct Extent {
    float min_x = 2, max_x = -2, min_y = 2, max_y = -2;
    std::array<float, 2> centre{};
  };
  const auto project = [&](const Camera& c) {
    const Mat4 vp = multiply(c.projection(aspect), c.view());
    const auto ndc = [&](const Vec3& p) {
      const float x = vp[0] * p[0] + vp[4] * p[1] + vp[8] * p[2] + vp[12];
      const float y = vp[1] * p[0] + vp[5] * p[1] + vp[9] * p[2] + vp[13];
      const float w = vp[3] * p[0] + vp[7] * p[1] + vp[11] * p[2] + vp[15];
      return std::array<float, 2>{x / w, y / w};
    };
    Extent e;
    for (int k = 0; k < 8; ++k) {
      const auto p = ndc({k & 1 ? hi[0] : lo[0], k & 2 ? hi[1] : lo[1], k & 4 ? hi[2] : lo[2]});
      e.min_x = std::min(e.min_x, p[0]), e.max_x = std::max(e.max_x, p[0]);
      e.min_y = std::min(e.min_y, p[1]), e.max_y = std::max(e.max_y, p[1]);
    }
    e.centre = ndc(c.target);
    return e;
  };
  const auto fill = [](const Extent& e, float left, float right, float bottom, float top) {
    return std::max((e.max_x - e.min_x) / (right - left), (e.max_y - e.min_y) / (top - bottom));
  };
  const std::array<float, 4> region{0.27f, 0.0f, 1.0f, 0.94f};  // x0 y0 x1 y1, from the top left
  const Extent in = project(Camera::framing(lo, hi, aspect, region));
  const float left = 2 * region[0] - 1, right = 2 * region[2] - 1;  // NDC: y up
  const float top = 1 - 2 * region[1], bottom = 1 - 2 * region[3];
  EXPECT_GE(in.min_x, left);
  EXPECT_LE(in.max_x, right);
  EXPECT_GE(in.min_y, bottom);
  EXPECT_LE(in.max_y, top);
  EXPECT_NEAR(in.centre[0], (left + right) / 2, 1e-4f);
  EXPECT_NEAR(in.centre[1], (top + bottom) / 2, 1e-4f);
  const Extent whole = project(Camera::framing(lo, hi, aspect));
  const float whole_fill = fill(whole, -1, 1, -1, 1);
  EXPECT_GT(fill(in, left, right, bottom, top), 0.95f * whole_fill)
      << "the region is filled as the plain framing fills the image (" << whole_fill << ")";
  // The whole image as the region is the plain framing, with no shift.
  const Camera all = Camera::framing(lo, hi, aspect, {0, 0, 1, 1});
  const Camera plain = Camera::framing(lo, hi, aspect);
  EXPECT_EQ(all.shift, (std::array<float, 2>{0.0f, 0.0f}));
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(all.eye[a], plain.eye[a], 1e-5f);
}

// The automatic camera's track on the two shared simulations, which both grow from a few
// particles: it pulls back at once as they grow and comes in no faster than 30 % a second; every
// frame's particles stay in view between its keys, and the first frames fill the image.
TEST(Camera, TheFramingTrackFollowsAnEffectThatGrows) {
  const fs::path dir = test::fresh_dir();
  for (const char* sim : {"blender_sparks", "blender_flip_pour_small"}) {
    SCOPED_TRACE(sim);
    cook::Options o;
    o.input = test::data_path(std::string("sims/") + sim + ".abc");
    o.output = dir / (std::string(sim) + ".pstream");
    cook::cook(o);
    const fs::path files[] = {o.output};
    const float aspect = 16.0f / 9.0f;
    const playback::CameraTrack track = playback::framing_track(files, aspect);
    using CameraTrackKey = playback::CameraTrack::Key;
    ASSERT_GE(track.keys.size(), 3u) << "an effect that grows from a point is followed";
    const auto distance = [](const render::Camera& c) {
      const float dx = c.eye[0] - c.target[0], dy = c.eye[1] - c.target[1], dz = c.eye[2] - c.target[2];
      return std::sqrt(dx * dx + dy * dy + dz * dz);
    };
    for (std::size_t k = 1; k < track.keys.size(); ++k) {
      const CameraTrackKey &a = track.keys[k - 1], &b = track.keys[k];
      EXPECT_GT(b.time, a.time);
      EXPECT_GE(distance(b.camera), distance(a.camera) * std::pow(0.7, b.time - a.time) * 0.999) << "key " << k;
    }
    const auto fixed = playback::framing_camera(files, aspect);
    EXPECT_GT(distance(fixed), 2 * distance(track.keys.front().camera)) << "the first key frames the first frame";
    EXPECT_EQ(track.at(-1.0).eye, track.keys.front().camera.eye);
    EXPECT_EQ(track.at(1e9).eye, track.keys.back().camera.eye);

    const format::Reader reader = format::Reader::open(o.output);
    const format::Metadata& m = reader.metadata();
    std::vector<std::byte> records = format::frame_buffer(m, reader.name());
    bool first = true;
    double worst_inside = 1.0;
    for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
      if (m.frames[f].count == 0) continue;
      reader.read_frame(f, records);
      const render::Camera c = track.at(m.frames[f].time);
      const render::Mat4 vp = render::multiply(c.projection(aspect), c.view());
      std::uint64_t inside = 0;
      float lo[2] = {2, 2}, hi[2] = {-2, -2};
      for (std::uint64_t i = 0; i < m.frames[f].count; ++i) {
        float p[3];
        std::memcpy(p, records.data() + i * m.record_size, sizeof p);
        const float w = vp[3] * p[0] + vp[7] * p[1] + vp[11] * p[2] + vp[15];
        const float x = (vp[0] * p[0] + vp[4] * p[1] + vp[8] * p[2] + vp[12]) / w;
        const float y = (vp[1] * p[0] + vp[5] * p[1] + vp[9] * p[2] + vp[13]) / w;
        if (w > 0 && std::abs(x) <= 1 && std::abs(y) <= 1) ++inside;
        lo[0] = std::min(lo[0], x), hi[0] = std::max(hi[0], x), lo[1] = std::min(lo[1], y), hi[1] = std::max(hi[1], y);
      }
      const double share = double(inside) / double(m.frames[f].count);
      worst_inside = std::min(worst_inside, share);
      // A key leaves out the strays beyond the 0.5th and 99.5th percentiles of each axis: at most
      // 3 % of a frame.
      EXPECT_GE(share, 0.97) << "frame " << f;
      if (first && m.frames[f].count >= 16) {  // the centres alone: a lone particle spans nothing
        const float span = std::max(hi[0] - lo[0], hi[1] - lo[1]) / 2;
        std::printf("%s: first frame with 16 particles or more (%llu): the centres span %.0f%% of the view\n", sim,
                    static_cast<unsigned long long>(f), 100.0 * span);
        EXPECT_GE(span, 0.4f);  // the centres only: the image adds their sprites
        first = false;
      }
    }
    std::printf("%s: %zu keys; at worst %.2f%% of a frame's particles in view\n", sim, track.keys.size(),
                100 * worst_inside);
  }
}

// What is drawn behind a look, by name (`pstream render --backdrop`, the browser's `backdrop=`):
// "auto" puts a ground under the liquid and under self-shadowing sprites, nothing behind others.
TEST(Looks, TheBackdropFollowsTheLookAndRefusesOtherNames) {
  const std::array<float, 6> bounds{-1.0f, 0.25f, -2.0f, 1.0f, 2.0f, 2.0f};
  const playback::DrawStyle sprites = playback::look_preset("sprites"), smoke = playback::look_preset("smoke"),
                            liquid = playback::look_preset("liquid");
  EXPECT_FALSE(playback::backdrop_for("auto", sprites, bounds));
  for (const playback::DrawStyle* style : {&smoke, &liquid}) {
    const std::optional<render::Backdrop> b = playback::backdrop_for("auto", *style, bounds);
    ASSERT_TRUE(b);
    EXPECT_TRUE(b->ground);
    EXPECT_EQ(b->ground_height, 0.25f);      // the clip's lowest point
    EXPECT_FLOAT_EQ(b->grid_spacing, 0.5f);  // a tenth of the 4-unit footprint, rounded to 1, 2 or 5
  }
  const std::optional<render::Backdrop> ground = playback::backdrop_for("ground", sprites, bounds);
  ASSERT_TRUE(ground);
  EXPECT_TRUE(ground->ground);
  const std::optional<render::Backdrop> sky = playback::backdrop_for("sky", liquid, bounds);
  ASSERT_TRUE(sky);
  EXPECT_FALSE(sky->ground);
  EXPECT_FALSE(playback::backdrop_for("none", liquid, bounds));
  try {
    playback::backdrop_for("grund", liquid, bounds);
    FAIL() << "a backdrop named 'grund' was taken";
  } catch (const OptionError& e) {
    EXPECT_EQ(e.option(), "backdrop");
    EXPECT_NE(std::string(e.what()).find("expected auto, ground, sky or none (did you mean 'ground'?)"),
              std::string::npos)
        << e.what();
  }
}

// The liquid's passes as numbers (frame.hpp: liquid_passes), which the native renderer and the
// browser player both take: lengths are the style's particle radii in view units, the buffers the
// style's fraction of the image, and the filter's passes three smaller ones and its iterations.
TEST(Looks, TheLiquidsPassesScaleWithTheParticleRadius) {
  render::LiquidStyle style;
  const render::Mat4 projection = render::perspective(45.0f, 16.0f / 9.0f, 0.1f, 100.0f);
  const float radius = 0.02f;
  const render::LiquidPasses p = render::liquid_passes(style, 1.0f, radius, projection, 480, 270);
  EXPECT_EQ(p.width, 480);
  EXPECT_EQ(p.height, 270);
  EXPECT_EQ(p.radius, radius);
  EXPECT_EQ(p.fixed_radius, 0.0f);
  // A particle 1 unit away: its radius through the focal length, in pixels of the buffer's height.
  EXPECT_FLOAT_EQ(p.radius_px_at_1, radius * projection[5] * 0.5f * 270.0f);
  EXPECT_FLOAT_EQ(p.filter_radius_at_1, style.smoothing * p.radius_px_at_1);
  EXPECT_FLOAT_EQ(p.range, style.depth_range * radius);
  EXPECT_FLOAT_EQ(p.color_depth, style.color_depth * radius);
  EXPECT_FLOAT_EQ(p.opacity_depth, style.opacity_depth * radius);
  EXPECT_FLOAT_EQ(p.foam_thickness, style.foam_isolation * radius);
  for (std::size_t c = 0; c < 3; ++c)  // color_depth of liquid lets `color` through
    EXPECT_NEAR(std::exp(-p.absorb[c] * p.color_depth), style.color[c], 1e-5f);
  EXPECT_EQ(p.filter_mode, 0);
  EXPECT_EQ(p.filter_passes, render::kLiquidRampPasses + style.iterations);
  EXPECT_TRUE(p.spray);  // isolated particles are spray by default
  // The shadow needs a ground to fall on: its depth in view units, the light buffer's size clamped.
  EXPECT_EQ(p.shadow_depth, 0.0f);
  style.ground_height = 0.0f;
  style.shadow_resolution = 9000;
  const render::LiquidPasses shadowed = render::liquid_passes(style, 1.0f, radius, projection, 480, 270);
  EXPECT_FLOAT_EQ(shadowed.shadow_depth, style.shadow_depth * radius);
  EXPECT_EQ(shadowed.shadow_resolution, 4096);
  style.shadow_depth = 0.0f;
  EXPECT_EQ(render::liquid_passes(style, 1.0f, radius, projection, 480, 270).shadow_depth, 0.0f);
  style.shadow_depth = render::LiquidStyle{}.shadow_depth;

  style.resolution = 0.5f;
  style.iterations = 50;
  style.filter = render::LiquidFilter::Bilateral;
  style.particle_radius = 0.03f;
  style.output = render::LiquidOutput::Depth;
  // The style's radius, scaled by the world transform, wins over the image's.
  const render::LiquidPasses q = render::liquid_passes(style, 2.0f, radius, projection, 481, 271);
  EXPECT_EQ(q.width, 241);  // rounded
  EXPECT_EQ(q.height, 136);
  EXPECT_EQ(q.radius, 0.06f);
  EXPECT_EQ(q.fixed_radius, 0.03f);
  EXPECT_FLOAT_EQ(q.range, style.depth_range * 0.06f);
  EXPECT_EQ(q.filter_mode, 1);
  EXPECT_EQ(q.filter_passes, render::kLiquidRampPasses + render::kLiquidMaxIterations);
  EXPECT_FALSE(q.spray);            // an inspection view has none
  EXPECT_EQ(q.shadow_depth, 0.0f);  // nor a shadow
  style.filter = render::LiquidFilter::None;
  EXPECT_EQ(render::liquid_passes(style, 2.0f, radius, projection, 481, 271).filter_passes, 0);

  // The filter's passes: 1/8, 1/4 and 1/2 of its radius, then the whole; each pass's taps on the
  // same spiral over the unit disc, turned 1.1 radians from the pass before, with Gaussian weights.
  EXPECT_EQ(render::liquid_filter_scale(0), 0.125f);
  EXPECT_EQ(render::liquid_filter_scale(2), 0.5f);
  EXPECT_EQ(render::liquid_filter_scale(3), 1.0f);
  const auto a = render::liquid_filter_taps(0), b = render::liquid_filter_taps(1);
  for (int i = 0; i < render::kLiquidFilterPairs; ++i) {
    const float ax = a[3 * std::size_t(i)], ay = a[3 * std::size_t(i) + 1], bx = b[3 * std::size_t(i)],
                by = b[3 * std::size_t(i) + 1];
    const float r = std::hypot(ax, ay);
    EXPECT_NEAR(r, std::sqrt((i + 0.5f) / render::kLiquidFilterPairs), 1e-5f);
    EXPECT_NEAR(std::hypot(bx, by), r, 1e-5f);
    EXPECT_NEAR(a[3 * std::size_t(i) + 2], std::exp(-2.0f * r * r), 1e-5f);
    EXPECT_NEAR(std::remainder(std::atan2(by, bx) - std::atan2(ay, ax) - 1.1f, 6.2831853f), 0.0f, 1e-4f);
  }
}

// The particles' radius where the style sets none: the median of up to 255 of them spread over the
// image, leaving out radii that are not finite or not positive.
TEST(Looks, TheLiquidsRadiusIsTheMedianOfTheImages) {
  EXPECT_EQ(render::median_radius(0, [](std::uint64_t) { return 1.0f; }), 0.01f);  // none: a default
  EXPECT_EQ(render::median_radius(3, [](std::uint64_t i) { return float(i + 1); }), 2.0f);
  // 100,000 particles, radius i / 1000 for particle i: 255 sampled evenly, their median near 50.
  EXPECT_NEAR(render::median_radius(100000, [](std::uint64_t i) { return float(i) / 1000.0f; }), 50.0f, 0.5f);
  // Bad radii do not count: half of them NaN, negative or zero.
  const float m = render::median_radius(1000, [](std::uint64_t i) {
    return i % 2 == 0 ? 0.5f : i % 3 == 0 ? std::numeric_limits<float>::quiet_NaN() : i % 5 == 0 ? -1.0f : 0.0f;
  });
  EXPECT_EQ(m, 0.5f);
}

}  // namespace
