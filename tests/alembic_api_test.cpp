// The reader's API on real files: caller buffers, zero-copy views, repeated samples, lookups by
// time, attributes, transforms — each checked against the official reader's values.
#include <gtest/gtest.h>

#include <cmath>
#include <numeric>

#include <nlohmann/json.hpp>

#include "particlestream/alembic.hpp"
#include "particlestream/alembic_describe.hpp"
#include "particlestream/io.hpp"
#include "test_util.hpp"

namespace {

using namespace pstream;
using namespace pstream::alembic;
using nlohmann::json;

json expected(const std::string& name) {
  return json::parse(test::read_text(test::data_path("alembic/" + name + ".expected.json")));
}

Archive open(const std::string& name) { return Archive::open(test::data_path("alembic/" + name + ".abc")); }

void expect_near_rel(double expected_value, double actual, const std::string& what) {
  EXPECT_LE(std::abs(expected_value - actual), 1e-9 * std::max(1.0, std::abs(expected_value))) << what;
}

TEST(AlembicApi, PositionsIntoCallerBufferMatchOfficialSums) {
  const Archive a = open("points_large");
  const json exp = expected("points_large");
  const Points points(*a.find("/big_cloud"));
  ASSERT_EQ(points.num_samples(), 20u);
  std::vector<float> buffer(50000 * 3);
  for (std::uint32_t f = 0; f < points.num_samples(); ++f) {
    ASSERT_EQ(points.read_positions(f, buffer), 150000u);
    const json& sums = exp["points"][0]["samples"][f]["positions"]["sum"];
    for (int c = 0; c < 3; ++c) {
      double s = 0;
      for (std::size_t i = 0; i < 50000; ++i) s += buffer[i * 3 + c];
      expect_near_rel(sums[c].get<double>(), s, "frame " + std::to_string(f));
    }
  }
}

// The reader takes a byte source: a mapped one is read in place, any other (pread, the host's
// callbacks, a URL: Http.AlembicCachesAreReadFromAUrl) read whole into memory first. Every value
// comes out the same as from the path (the whole description, every sample's sums).
TEST(AlembicApi, AnyByteSourceReadsAsThePathDoes) {
  for (const std::string name : {"alembic/points_large.abc", "alembic/points_varying.abc", "sims/blender_sparks.abc"}) {
    SCOPED_TRACE(name);
    const std::string path = test::data_path(name);
    const DescribeOptions options;
    const std::string want = describe_json(Archive::open(path), options);
    const Archive read = Archive::open(io::open_file(path));
    EXPECT_EQ(describe_json(read, options), want);
    EXPECT_EQ(read.name(), path);
    auto source = io::open_mapped_file(path);
    const std::byte* const mapping = source->mapped().data();
    const Archive mapped = Archive::open(std::move(source));
    EXPECT_EQ(describe_json(mapped, options), want);
    EXPECT_EQ(mapped.bytes().data(), mapping);  // read in place
  }
  // A source that ends short of the size it claims: its error. One that claims more than the
  // machine's memory: refused before anything is allocated or read.
  class Short : public io::ByteSource {
   public:
    Short(std::uint64_t claimed, int* reads) : claimed_(claimed), reads_(reads) {}
    void read(std::uint64_t offset, std::span<std::byte> out) override {
      ++*reads_;
      if (offset + out.size() > 1000) throw Error(fmt::format("short: nothing past byte 1000 (read at {})", offset));
      std::fill(out.begin(), out.end(), std::byte{0});
    }
    std::uint64_t size() const override { return claimed_; }
    const std::string& name() const override { return name_; }

   private:
    std::uint64_t claimed_;
    int* reads_;
    std::string name_ = "short";
  };
  std::vector<std::uint64_t> fetched;
  const auto expect_error = [&](std::uint64_t claimed, const std::string& fragment, int reads) {
    int made = 0;  // reads the source saw (it goes with the failed open)
    try {
      Archive::open(std::make_unique<Short>(claimed, &made),
                    [&](std::uint64_t done, std::uint64_t) { fetched.push_back(done); });
      ADD_FAILURE() << "no error";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
    }
    EXPECT_EQ(made, reads);
  };
  expect_error(64ull << 20, "nothing past byte 1000", 1);
  expect_error(std::uint64_t{1} << 60, "it is read whole into memory, and this machine has", 0);
  EXPECT_TRUE(fetched.empty());
  // Fetch progress: after each 8 MiB read, up to the whole.
  int zero_reads = 0;
  struct Zeros : Short {
    explicit Zeros(int* reads) : Short(20ull << 20, reads) {}
    void read(std::uint64_t, std::span<std::byte> out) override { std::fill(out.begin(), out.end(), std::byte{0}); }
  };
  EXPECT_THROW(Archive::open(std::make_unique<Zeros>(&zero_reads),
                             [&](std::uint64_t done, std::uint64_t total) {
                               EXPECT_EQ(total, 20ull << 20);
                               fetched.push_back(done);
                             }),
               Error);  // zeros are no archive
  EXPECT_EQ(fetched, (std::vector<std::uint64_t>{8ull << 20, 16ull << 20, 20ull << 20}));
}

TEST(AlembicApi, TooSmallBufferIsAnErrorNotAnOverflow) {
  const Archive a = open("points_constant");
  const Points points(*a.find("/fluid"));
  std::vector<float> small(10);
  try {
    points.read_positions(0, small);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("3000 are needed"), std::string::npos) << e.what();
  }
}

TEST(AlembicApi, ZeroCopyViewPointsIntoTheMapping) {
  const Archive a = open("points_constant");
  const Points points(*a.find("/fluid"));
  const SampleView v = points.positions(7);
  ASSERT_EQ(v.size(), 1000u);
  const auto file = a.bytes();
  EXPECT_GE(v.bytes().data(), file.data());
  EXPECT_LE(v.bytes().data() + v.bytes().size(), file.data() + file.size());
  std::vector<float> copy(3000);
  points.read_positions(7, copy);
  if (const auto span = v.as_span<float>()) {  // aligned in the file: a typed view, no copy
    ASSERT_EQ(span->size(), 3000u);
    EXPECT_TRUE(std::equal(span->begin(), span->end(), copy.begin()));
  } else {
    EXPECT_NE(reinterpret_cast<std::uintptr_t>(v.bytes().data()) % alignof(float), 0u);
  }
  EXPECT_FALSE(v.as_span<double>().has_value());  // wrong type never reinterprets
}

TEST(AlembicApi, RepeatedSamplesMapToTheStoredOne) {
  const Archive a = open("points_empty_frames");
  const json exp = expected("points_empty_frames");
  const Points points(*a.find("/sparse_emitter"));
  const auto P = a.find("/sparse_emitter")->properties().find(".geom")->find("P");
  ASSERT_TRUE(P.has_value());
  // Frames 0 and 1 are identical: Ogawa stores them once, and frame 2 is the first change.
  EXPECT_EQ(P->header().first_changed, 2u);
  EXPECT_EQ(P->header().stored_index(0), 0u);
  EXPECT_EQ(P->header().stored_index(1), 0u);
  EXPECT_EQ(P->header().stored_index(2), 1u);
  for (std::uint32_t f = 0; f < points.num_samples(); ++f) {
    EXPECT_EQ(points.count(f), exp["points"][0]["samples"][f]["count"].get<std::uint64_t>()) << "frame " << f;
  }
  for (std::uint32_t f : {0u, 1u, 7u, 12u, 13u, 23u}) EXPECT_EQ(points.count(f), 0u) << f;
}

TEST(AlembicApi, IdsVelocitiesAndAttributes) {
  const Archive a = open("points_varying");
  const json s5 = expected("points_varying")["points"][0]["samples"][5];
  const Points points(*a.find("/particles"));
  const std::uint64_t n = points.count(5);
  ASSERT_EQ(n, 250u);
  std::vector<std::uint64_t> ids(n);
  points.read_ids(5, ids);
  EXPECT_EQ(ids[0], 8589934592ull);  // above 2^32: must not be truncated
  EXPECT_EQ(std::accumulate(ids.begin(), ids.end(), std::uint64_t{0}), s5["ids"]["sum"].get<std::uint64_t>());

  std::vector<float> v(n * 3);
  points.read_velocities(5, v);
  double vy = 0;
  for (std::size_t i = 0; i < n; ++i) vy += v[i * 3 + 1];
  expect_near_rel(s5["velocities"]["sum"][1].get<double>(), vy, "velocity y sum");

  std::vector<float> cd(n * 3);
  ASSERT_EQ(points.read_param("Cd", 5, cd), n * 3);
  double blue = 0;
  for (std::size_t i = 0; i < n; ++i) blue += cd[i * 3 + 2];
  expect_near_rel(s5["arb_geom_params"][0]["vals"]["sum"][2].get<double>(), blue, "Cd blue sum");

  std::vector<float> widths(n);
  ASSERT_EQ(points.read_param("widths", 5, widths), n);
  expect_near_rel(s5["widths"]["vals"]["sum"].get<double>(), std::accumulate(widths.begin(), widths.end(), 0.0),
                  "widths sum");
  std::vector<float> mass(1);
  ASSERT_EQ(points.read_param("mass", 5, mass), 1u);  // constant scope: one value per sample
  EXPECT_FLOAT_EQ(mass[0], 1.05f);
  EXPECT_EQ(points.find_param("age")->scope(), GeomScope::Vertex);
  EXPECT_EQ(points.find_param("mass")->scope(), GeomScope::Constant);
  EXPECT_THROW(points.read_param("nope", 5, mass), Error);
}

TEST(AlembicApi, WorldMatrixAtAnyTimeTakesTheNearestSample) {
  const Archive a = open("points_xform");
  const json samples = expected("points_xform")["points"][0]["samples"];
  const Object particles = *a.find("/rig/scaler/particles");
  const double dt = 1.0 / 24.0;
  for (int k = 0; k < 23; ++k) {
    const double t = (k + 1) * dt;
    for (const auto& [time, index] : {std::pair{t + 0.4 * dt, k}, std::pair{t + 0.6 * dt, k + 1}}) {
      const Matrix44 m = parent_world_matrix(particles, time);
      const json& e = samples[index]["world_matrix"];
      for (int r = 0; r < 4; ++r) {
        for (int c = 0; c < 4; ++c) EXPECT_NEAR(e[r][c].get<double>(), m[r][c], 1e-12) << "t=" << time;
      }
    }
  }
  // Before the first and after the last sample the ends are held.
  EXPECT_EQ(parent_world_matrix(particles, -10.0), parent_world_matrix(particles, dt));
  EXPECT_EQ(parent_world_matrix(particles, 99.0), parent_world_matrix(particles, 24 * dt));
}

TEST(AlembicApi, XformOpsAndMatrices) {
  const Archive a = open("points_xform");
  const Xform rig(*a.find("/rig"));
  EXPECT_EQ(rig.num_samples(), 24u);
  EXPECT_FALSE(rig.is_constant());
  const XformSample s = rig.sample(0);
  ASSERT_EQ(s.ops.size(), 2u);
  EXPECT_EQ(s.ops[0].type, XformOpType::Translate);
  EXPECT_EQ(s.ops[1].type, XformOpType::Rotate);
  EXPECT_DOUBLE_EQ(s.ops[1].channels[3], 7.5);
  const Xform scaler(*a.find("/rig/scaler"));
  EXPECT_TRUE(scaler.is_constant());
  EXPECT_EQ(scaler.sample(0).matrix()[1][1], 0.5);
}

TEST(AlembicApi, TimeSamplingLookups) {
  TimeSampling ts;
  ts.time_per_cycle = 1.0 / 24.0;
  ts.stored_times = {1.0 / 24.0};
  const std::uint64_t n = 10;
  EXPECT_DOUBLE_EQ(ts.sample_time(3), 1.0 / 24.0 + 3.0 / 24.0);
  EXPECT_EQ(ts.near_index(ts.sample_time(4), n).first, 4u);
  EXPECT_EQ(ts.floor_index(ts.sample_time(4), n).first, 4u);
  EXPECT_EQ(ts.ceil_index(ts.sample_time(4), n).first, 4u);
  EXPECT_EQ(ts.floor_index(ts.sample_time(4) + 0.01, n).first, 4u);
  EXPECT_EQ(ts.ceil_index(ts.sample_time(4) + 0.01, n).first, 5u);
  EXPECT_EQ(ts.near_index(-5.0, n).first, 0u);
  EXPECT_EQ(ts.near_index(50.0, n).first, 9u);
  EXPECT_EQ(ts.near_index(ts.sample_time(2) + 0.49 / 24.0, n).first, 2u);
  EXPECT_EQ(ts.near_index(ts.sample_time(2) + 0.51 / 24.0, n).first, 3u);
  EXPECT_EQ(ts.near_index(ts.sample_time(2) - 1e-15, n).first, 2u);  // round-off never skips a sample

  TimeSampling cyclic;
  cyclic.type = TimeSamplingType::Cyclic;
  cyclic.samples_per_cycle = 2;
  cyclic.time_per_cycle = 1.0;
  cyclic.stored_times = {0.0, 0.25};
  EXPECT_DOUBLE_EQ(cyclic.sample_time(3), 1.25);
  EXPECT_EQ(cyclic.near_index(1.2, 6).first, 3u);
  EXPECT_EQ(cyclic.floor_index(2.1, 6).first, 4u);

  TimeSampling acyclic;
  acyclic.type = TimeSamplingType::Acyclic;
  acyclic.time_per_cycle = TimeSampling::kAcyclicTimePerCycle;
  acyclic.stored_times = {0.0, 0.1, 0.5, 2.0};
  EXPECT_DOUBLE_EQ(acyclic.sample_time(2), 0.5);
  EXPECT_EQ(acyclic.near_index(0.35, 4).first, 2u);
  EXPECT_EQ(acyclic.floor_index(1.9, 4).first, 2u);
  EXPECT_EQ(acyclic.ceil_index(0.11, 4).first, 2u);
}

TEST(AlembicApi, PolyMeshVerticesAsPoints) {
  const Archive a = open("mesh_vertices");
  const PolyMesh mesh(*a.find("/grid"));
  EXPECT_EQ(mesh.num_samples(), 24u);
  EXPECT_EQ(mesh.topology_variance(), 1);
  EXPECT_EQ(mesh.positions(5).size(), 400u);
  EXPECT_EQ(mesh.face_counts(5).size(), 361u);
  EXPECT_THROW(Points(*a.find("/grid")), Error);  // a mesh is not a Points object
}

TEST(AlembicApi, HierarchyAndMetadata) {
  const Archive a = open("points_multi");
  const auto objects = a.objects();
  ASSERT_EQ(objects.size(), 4u);
  EXPECT_EQ(objects[1].full_name(), "/emitterA/splash");
  EXPECT_EQ(objects[1].parent()->full_name(), "/emitterA");
  EXPECT_EQ(object_kind(objects[1]), "points");
  EXPECT_EQ(a.time_samplings().size(), 3u);
  EXPECT_EQ(a.info().app_name, "alembic-fixture-gen 1.0");
  EXPECT_EQ(a.archive_version(), 10812u);
  EXPECT_FALSE(a.find("/nope").has_value());
  const Points foam(*a.find("/emitterB/foam"));
  EXPECT_EQ(foam.time_sampling_index(), 2u);
  EXPECT_EQ(foam.count(10), 150u);  // n = 100 + 5 f
}

}  // namespace
