// The demo's simulator and its Alembic file: deterministic for a seed, counts that vary with
// births and deaths, and an Alembic file that reads back with every value equal.
#include <gtest/gtest.h>

#include <filesystem>
#include <set>

#include "alembic_read_back.hpp"
#include "particlestream/alembic.hpp"
#include "particlestream/alembic_writer.hpp"
#include "particlestream/demo.hpp"
#include "test_util.hpp"

namespace {

using namespace pstream;
namespace fs = std::filesystem;

TEST(DemoSimulator, DeterministicWithBirthsAndDeaths) {
  for (const std::string& preset : demo::Simulator::presets()) {
    demo::Simulator a({preset, 4000, 3.0, 30.0, 7, 1}), b({preset, 4000, 3.0, 30.0, 7, 2});  // 1 vs 2 threads
    std::set<std::size_t> counts;
    for (std::uint64_t f = 0; f < a.frame_count(); ++f) {
      a.step();
      b.step();
      ASSERT_EQ(a.state().position, b.state().position) << preset << " frame " << f;
      ASSERT_EQ(a.state().id, b.state().id);
      counts.insert(a.state().size());
      ASSERT_TRUE(std::is_sorted(a.state().id.begin(), a.state().id.end()));
    }
    EXPECT_GT(counts.size(), 10u) << preset << ": counts should vary";
    EXPECT_GT(*counts.rbegin(), 1000u) << preset;
  }
  EXPECT_THROW(demo::Simulator({"lava", 10, 1, 30, 1, 1}), Error);
}

TEST(DemoSimulator, AlembicFileReadsBackWithEveryValueEqual) {
  const fs::path dir = test::fresh_dir();
  const fs::path file = dir / "demo.abc";
  demo::Simulator sim({"fountain", 3000, 2.0, 24.0, 3, 0});
  std::vector<demo::ParticleState> frames;
  {
    alembic::PointsWriterOptions o;
    o.name = "fountain";
    o.float_params = {{"Cd", 4}, {"age", 1}};
    alembic::ArchiveWriter w(file, "demo test", "fountain", 24.0, 1.0 / 24, o);
    for (std::uint64_t f = 0; f < sim.frame_count(); ++f) {
      sim.step();
      frames.push_back(sim.state());
      const auto& s = frames.back();
      alembic::PointsSample sample;
      sample.positions = s.position;
      sample.ids = s.id;
      sample.velocities = s.velocity;
      sample.widths = s.width;
      sample.params = {s.color, s.age};
      w.write_sample(sample);
    }
    w.close();
  }
  const alembic::Archive a = alembic::Archive::open(file);
  const alembic::Points points(*a.find("/fountain"));
  ASSERT_EQ(points.num_samples(), frames.size());
  for (std::uint32_t f = 0; f < frames.size(); ++f) {
    const auto& s = frames[f];
    const std::size_t n = s.size();
    ASSERT_EQ(points.count(f), n);
    const test::PointsSampleArrays got = test::read_sample_arrays(points, f, 4);
    ASSERT_EQ(got.P, s.position) << f;
    ASSERT_EQ(got.velocities, s.velocity) << f;
    ASSERT_EQ(got.ids, s.id) << f;
    ASSERT_EQ(got.widths, s.width) << f;
    ASSERT_EQ(got.Cd, s.color) << f;
    ASSERT_EQ(got.age, s.age) << f;
  }
  EXPECT_EQ(points.find_param("Cd")->values().header().interpretation(), "rgba");
}

}  // namespace
