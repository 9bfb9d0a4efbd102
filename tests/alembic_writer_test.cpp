// The Alembic writer: what it writes reads back through our reader with every value equal,
// repeated samples are stored once, and the file is refused until it is closed (frozen).
#include <gtest/gtest.h>

#include <filesystem>
#include <random>

#include "alembic_read_back.hpp"
#include "particlestream/alembic.hpp"
#include "particlestream/alembic_describe.hpp"
#include "particlestream/alembic_writer.hpp"
#include "test_util.hpp"

namespace {

using namespace pstream;
using namespace pstream::alembic;
namespace fs = std::filesystem;

struct Frame {
  std::vector<float> P, v, w, cd, age;
  std::vector<std::uint64_t> ids;
};

std::vector<Frame> make_frames(int frames) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> uni(-2.0f, 2.0f);
  std::vector<Frame> out;
  for (int f = 0; f < frames; ++f) {
    Frame fr;
    const int n = f == 0 ? 0 : 100 + 37 * f;  // births: counts vary, frame 0 empty
    for (int i = 0; i < n; ++i) {
      for (int c = 0; c < 3; ++c)
        fr.P.push_back(uni(rng)), fr.v.push_back(uni(rng)), fr.cd.push_back((uni(rng) + 2) / 4);
      fr.w.push_back(0.01f + 0.001f * float(i % 7));
      fr.age.push_back(float(f) / 24.0f);
      fr.ids.push_back((std::uint64_t(i) * 2654435761u) + (i % 4 == 0 ? (1ull << 33) : 0));
    }
    out.push_back(std::move(fr));
  }
  out.push_back(out.back());  // the last frame repeated twice: stored once
  out.push_back(out.back());
  return out;
}

PointsSample sample_of(const Frame& f) {
  PointsSample s;
  s.positions = f.P;
  s.ids = f.ids;
  s.velocities = f.v;
  s.widths = f.w;
  s.params = {f.cd, f.age};
  return s;
}

TEST(AlembicWriter, EveryValueReadsBack) {
  const fs::path dir = test::fresh_dir();
  const fs::path file = dir / "written.abc";
  const auto frames = make_frames(10);
  PointsWriterOptions o;
  o.name = "sim";
  o.parent_xform = "emitter";
  o.translate = {1, 2, 3};
  o.float_params = {{"Cd", 3}, {"age", 1}};
  {
    ArchiveWriter w(file, "writer test", "round trip", 24.0, 1.0 / 24, o);
    for (const auto& f : frames) w.write_sample(sample_of(f));
    w.close();
  }
  const Archive a = Archive::open(file);
  EXPECT_EQ(a.info().app_name, "writer test");
  EXPECT_DOUBLE_EQ(a.info().dcc_fps, 24.0);
  const auto obj = a.find("/emitter/sim");
  ASSERT_TRUE(obj.has_value());
  const Points points(*obj);
  ASSERT_EQ(points.num_samples(), frames.size());
  EXPECT_DOUBLE_EQ(points.sample_time(3), 1.0 / 24 + 3.0 / 24);
  for (std::uint32_t s = 0; s < frames.size(); ++s) {
    const Frame& f = frames[s];
    const std::size_t n = f.ids.size();
    ASSERT_EQ(points.count(s), n) << s;
    const test::PointsSampleArrays got = test::read_sample_arrays(points, s, 3);
    EXPECT_EQ(got.P, f.P) << s;
    EXPECT_EQ(got.velocities, f.v) << s;
    EXPECT_EQ(got.ids, f.ids) << s;
    EXPECT_EQ(got.widths, f.w) << s;
    EXPECT_EQ(got.Cd, f.cd) << s;
    EXPECT_EQ(got.age, f.age) << s;
    const Box3 b = points.self_bounds(s);
    EXPECT_EQ(b.is_empty(), n == 0);
    const Matrix44 m = parent_world_matrix(*obj, points.sample_time(s));
    EXPECT_EQ(m[3][0], 1.0);
    EXPECT_EQ(m[3][2], 3.0);
  }
  // Repeats are not stored again: the last two samples map onto the one before them.
  const auto P = obj->properties().find(".geom")->find("P");
  EXPECT_EQ(P->header().num_samples, frames.size());
  EXPECT_EQ(P->header().last_changed, frames.size() - 3);
  EXPECT_EQ(P->header().stored_index(std::uint32_t(frames.size() - 1)),
            P->header().stored_index(std::uint32_t(frames.size() - 3)));
  EXPECT_EQ(points.find_param("Cd")->values().header().interpretation(), "rgb");
  EXPECT_EQ(points.widths()->scope(), GeomScope::Vertex);
  // The whole archive also describes cleanly (every property, every sample).
  EXPECT_NO_THROW(describe_json(a));
}

TEST(AlembicWriter, UnclosedArchiveLeavesNothing) {
  const fs::path dir = test::fresh_dir();
  const fs::path file = dir / "unclosed.abc";
  {
    ArchiveWriter w(file, "t", "d", 24.0, 0.0, {});
    const auto frames = make_frames(2);
    PointsSample s = sample_of(frames[1]);
    s.params.clear();
    w.write_sample(s);
  }  // destroyed without close(): the temporary is removed, the archive never appears
  EXPECT_FALSE(fs::exists(file));
  EXPECT_TRUE(fs::is_empty(dir)) << "a temporary was left in " << dir;
}

}  // namespace
