// The playback layer: what the viewer, `pstream render` and `pstream demo` draw each host frame.
// Its batches hold exactly the stream's frame (contiguous, whatever the ring did), in depth order
// when asked; several clips are sorted as one; a host frame allocates nothing.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <thread>

#include "alloc_counter.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"
#include "particlestream/playback.hpp"
#include "test_util.hpp"

namespace {

using namespace pstream;
namespace fs = std::filesystem;

fs::path cook(const fs::path& dir, const std::string& fixture, format::FrameCodec codec) {
  cook::Options o;
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

}  // namespace
