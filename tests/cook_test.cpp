// Cooking real files: every frame of every fixture must come back exactly as the source holds it
// (positions, scale = width / 2), whatever the codec and however frames straddle chunks.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <numeric>

#include <fmt/format.h>
#include <hwy/targets.h>

#include "alloc_counter.hpp"
#include "cook/source.hpp"  // to_unorm8: the colour rule every source keeps
#include "particlestream/alembic.hpp"
#include "particlestream/alembic_writer.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"
#include "test_util.hpp"

namespace {

using namespace pstream;
namespace fs = std::filesystem;

struct Expected {
  std::vector<float> records;  // x y z scale per particle
};

// What a frame must hold, computed from the Alembic reader independently of the cooker:
// positions times the parent world matrix (in double, as Imath does), scale = width / 2.
std::vector<float> expected_frame(const alembic::Archive& a, const std::vector<std::string>& objects,
                                  std::uint32_t sample, float default_scale) {
  std::vector<float> out;
  for (const std::string& name : objects) {
    const alembic::Object o = *a.find(name);
    std::vector<float> P, widths;
    std::uint64_t n = 0;
    double time = 0;
    if (alembic::Points::matches(o)) {
      const alembic::Points points(o);
      time = points.sample_time(sample);
      n = points.count(sample);
      P.resize(n * 3);
      points.read_positions(sample, P);
      if (points.widths()) {
        widths.resize(n);
        const auto w = points.widths()->values().sample_at(time).first;
        for (std::uint64_t i = 0; i < n; ++i) widths[i] = static_cast<float>(w.value_f64(w.size() == 1 ? 0 : i));
      }
    } else {
      const alembic::PolyMesh mesh(o);
      time = mesh.time_sampling().sample_time(sample);
      const auto v = mesh.positions(sample);
      n = v.size();
      P.resize(n * 3);
      v.copy_raw(std::as_writable_bytes(std::span(P)));
    }
    const alembic::Matrix44 m = alembic::parent_world_matrix(o, time);
    const double det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
                       m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
                       m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    const bool identity = m == alembic::identity_matrix();
    for (std::uint64_t i = 0; i < n; ++i) {
      const double x = P[i * 3], y = P[i * 3 + 1], z = P[i * 3 + 2];
      for (int c = 0; c < 3; ++c) {
        // Without a transform the stored floats pass through untouched (-0.0 stays -0.0).
        out.push_back(identity ? P[i * 3 + c] : static_cast<float>(x * m[0][c] + y * m[1][c] + z * m[2][c] + m[3][c]));
      }
      float s = widths.empty() ? default_scale : widths[i] * 0.5f;
      if (!identity && !widths.empty()) s = static_cast<float>(s * std::cbrt(std::abs(det)));
      out.push_back(s);
    }
  }
  return out;
}

struct Case {
  const char* file;
  std::vector<std::string> objects;
  std::uint32_t samples;
};

const Case kCases[] = {
    {"points_constant", {"/fluid"}, 48},
    {"points_varying", {"/particles"}, 60},
    {"points_xform", {"/rig/scaler/particles"}, 24},
    {"points_multi", {"/emitterA/splash"}, 24},
    {"points_empty_frames", {"/sparse_emitter"}, 24},
    {"points_large", {"/big_cloud"}, 20},
    {"points_widths_constant", {"/dust"}, 12},
    {"mesh_vertices", {"/grid"}, 24},
};

// Bounds of a frame's expected records (min xyz, max xyz).
std::array<float, 6> bounds_of(const std::vector<float>& records) {
  constexpr float inf = std::numeric_limits<float>::infinity();
  std::array<float, 6> b{inf, inf, inf, -inf, -inf, -inf};
  for (std::size_t i = 0; i < records.size(); i += 4) {
    for (int c = 0; c < 3; ++c) {
      b[c] = std::min(b[c], records[i + c]);
      b[c + 3] = std::max(b[c + 3], records[i + c]);
    }
  }
  return b;
}

// Chunk sizes: the smallest (frames straddle many borders) and one larger than the cooker's raw
// write pieces (a chunk is then written and checksummed in several pieces).
class CookFixture : public ::testing::TestWithParam<std::tuple<Case, format::Codec, std::uint64_t>> {};

TEST_P(CookFixture, EveryFrameEqualsTheSource) {
  const auto& [c, codec, chunk_size] = GetParam();
  const fs::path dir = test::fresh_dir();
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.keep_velocity = false;                      // the fixture's [x y z scale] (+ colour) records
  o.input = test::data_path(std::string("alembic/") + c.file + ".abc");
  o.output = dir / "out.pstream";
  o.object = c.objects.front();
  o.chunk_size = chunk_size;
  o.codec = codec;
  o.threads = 2;
  const cook::Report report = cook::cook(o);
  ASSERT_EQ(report.frames, c.samples);

  const alembic::Archive archive = alembic::Archive::open(o.input);
  const format::Reader reader = format::Reader::open(o.output);
  const format::Metadata& m = reader.metadata();
  ASSERT_EQ(m.frame_count(), c.samples);
  // Colour is added when the source has Cd: 20-byte records also straddle chunk borders.
  ASSERT_EQ(m.record_size, m.find("color") ? 20u : 16u);
  const std::uint32_t rs = m.record_size;
  std::vector<std::byte> buffer(std::max<std::uint64_t>(m.max_count, 1) * rs), scratch(m.chunk_size);
  std::uint64_t straddling = 0;
  for (std::uint32_t f = 0; f < c.samples; ++f) {
    const std::vector<float> expected = expected_frame(archive, c.objects, f, static_cast<float>(report.default_scale));
    ASSERT_EQ(m.frames[f].count * 4, expected.size()) << "frame " << f;
    reader.read_frame(f, buffer);
    for (std::uint64_t i = 0; i < m.frames[f].count; ++i) {
      ASSERT_EQ(std::memcmp(buffer.data() + i * rs, &expected[i * 4], 16), 0)
          << c.file << " frame " << f << " particle " << i;
    }
    const auto& e = m.frames[f];
    EXPECT_EQ(e.bounds, bounds_of(expected)) << c.file << " frame " << f;
    if (e.count && e.byte_offset / m.chunk_size != (e.byte_offset + e.count * rs - 1) / m.chunk_size) ++straddling;
  }
  if (m.stream_size() > 2 * m.chunk_size) {
    EXPECT_GT(straddling, 0u) << "no frame crosses a chunk border";
  }
}

std::string case_name(const ::testing::TestParamInfo<std::tuple<Case, format::Codec, std::uint64_t>>& info) {
  return fmt::format("{}_{}_{}k", std::get<0>(info.param).file, format::codec_name(std::get<1>(info.param)),
                     std::get<2>(info.param) / 1024);
}

INSTANTIATE_TEST_SUITE_P(Cook, CookFixture,
                         ::testing::Combine(::testing::ValuesIn(kCases),
                                            ::testing::Values(format::Codec::Raw, format::Codec::Lz4,
                                                              format::Codec::Zstd),
                                            ::testing::Values(format::kMinChunkSize, std::uint64_t{1} << 20)),
                         case_name);

TEST(Cook, MergedObjectsKeepTheirOwnTransforms) {
  const fs::path dir = test::fresh_dir();
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.input = test::data_path("alembic/points_multi.abc");
  o.output = dir / "merged.pstream";
  o.merge = true;
  o.fps = 24;
  cook::cook(o);
  const alembic::Archive archive = alembic::Archive::open(o.input);
  const format::Reader reader = format::Reader::open(o.output);
  const auto& m = reader.metadata();
  ASSERT_EQ(m.frame_count(), 24u);
  std::vector<std::byte> buffer(m.max_count * 16), scratch(m.chunk_size);
  // Output frame k is at 1/48 + k/24 s: splash sample k and foam's nearest sample 2k+1.
  const alembic::Points splash(*archive.find("/emitterA/splash")), foam(*archive.find("/emitterB/foam"));
  for (std::uint32_t k = 0; k < 24; ++k) {
    reader.read_frame(k, buffer);
    const double t = m.frames[k].time;
    const auto a = splash.time_sampling().near_index(t, 24).first, b = foam.time_sampling().near_index(t, 48).first;
    ASSERT_EQ(m.frames[k].count,
              splash.count(static_cast<std::uint32_t>(a)) + foam.count(static_cast<std::uint32_t>(b)));
    float first_foam[4];
    std::memcpy(first_foam, buffer.data() + splash.count(static_cast<std::uint32_t>(a)) * 16, 16);
    std::vector<float> P(foam.count(static_cast<std::uint32_t>(b)) * 3);
    foam.read_positions(static_cast<std::uint32_t>(b), P);
    EXPECT_EQ(first_foam[0], static_cast<float>(double(P[0]) + 2.0)) << "foam is translated by /emitterB";
  }
}

TEST(Cook, AttributesColourVelocityIdAndFloats) {
  const fs::path dir = test::fresh_dir();
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.input = test::data_path("alembic/points_varying.abc");
  o.output = dir / "attrs.pstream";
  o.attributes = {"velocity", "id", "age"};
  o.codec = format::Codec::Zstd;
  cook::cook(o);
  const format::Reader reader = format::Reader::open(o.output);
  const auto& m = reader.metadata();
  ASSERT_EQ(m.record_size, 44u);
  const auto *color = m.find("color"), *velocity = m.find("velocity"), *id = m.find("id"), *age = m.find("age");
  ASSERT_TRUE(color && velocity && id && age);
  const alembic::Archive archive = alembic::Archive::open(o.input);
  const alembic::Points points(*archive.find("/particles"));
  std::vector<std::byte> buffer(m.max_count * m.record_size), scratch(m.chunk_size);
  std::uint64_t reordered = 0;  // particles whose record is not at their source index
  for (std::uint32_t f : {5u, 20u, 59u}) {
    reader.read_frame(f, buffer);
    const std::uint64_t n = points.count(f);
    std::vector<float> v(n * 3), cd(n * 3), ages(n);
    std::vector<std::uint64_t> ids(n);
    points.read_velocities(f, v);
    points.read_ids(f, ids);
    points.read_param("Cd", f, cd);
    points.read_param("age", f, ages);
    // The frame is written in ascending id order: record k is the source particle with the k-th
    // smallest id (the source's order is not sorted here).
    std::vector<std::uint64_t> by_id(n);
    for (std::uint64_t i = 0; i < n; ++i) by_id[i] = i;
    std::stable_sort(by_id.begin(), by_id.end(), [&](auto x, auto y) { return ids[x] < ids[y]; });
    for (std::uint64_t k = 0; k < n; ++k) reordered += by_id[k] != k;
    for (std::uint64_t k = 0; k < n; ++k) {
      const std::uint64_t i = by_id[k];
      const std::byte* r = buffer.data() + k * m.record_size;
      float vel[3], a;
      std::uint64_t pid;
      std::uint8_t rgba[4];
      std::memcpy(vel, r + velocity->offset, 12);
      std::memcpy(&pid, r + id->offset, 8);
      std::memcpy(&a, r + age->offset, 4);
      std::memcpy(rgba, r + color->offset, 4);
      ASSERT_EQ(std::memcmp(vel, &v[i * 3], 12), 0) << "frame " << f << " particle " << i;
      ASSERT_EQ(pid, ids[i]);
      float pos[3];
      std::memcpy(pos, r, 12);
      const alembic::SampleView positions = points.positions(f);
      ASSERT_EQ(std::memcmp(pos, positions.bytes().data() + i * 12, 12), 0) << "frame " << f << " particle " << i;
      ASSERT_EQ(a, ages[i]);
      for (int c = 0; c < 3; ++c) ASSERT_EQ(rgba[c], std::lround(std::clamp(cd[i * 3 + c], 0.0f, 1.0f) * 255.0f));
      ASSERT_EQ(rgba[3], 255);
    }
  }
  EXPECT_GT(reordered, 0u) << "the fixture's ids are already in order: this test would not see the sort";
}

TEST(Cook, InterpolationBlendsParticlesMatchedById) {
  const fs::path dir = test::fresh_dir();
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.input = test::data_path("alembic/points_constant.abc");
  o.output = dir / "interp.pstream";
  o.fps = 48;
  o.interpolate = true;
  cook::cook(o);
  const format::Reader reader = format::Reader::open(o.output);
  const auto& m = reader.metadata();
  EXPECT_TRUE(m.flags & format::kFlagInterpolated);
  ASSERT_EQ(m.frame_count(), 95u);  // 48 samples at 24 fps span 47/24 s
  const alembic::Archive archive = alembic::Archive::open(o.input);
  const alembic::Points points(*archive.find("/fluid"));
  std::vector<float> a(3000), b(3000), rec(4000);
  std::vector<std::byte> scratch(m.chunk_size);
  points.read_positions(3, a);
  points.read_positions(4, b);
  reader.read_frame(7, std::as_writable_bytes(std::span(rec)));  // half-way between samples 3 and 4
  const double w = (m.frames[7].time - points.sample_time(3)) / (points.sample_time(4) - points.sample_time(3));
  EXPECT_NEAR(w, 0.5, 1e-9);
  for (int i = 0; i < 1000; ++i) {
    for (int c = 0; c < 3; ++c) {
      const float x = a[i * 3 + c], y = b[i * 3 + c];
      ASSERT_EQ(rec[i * 4 + c], static_cast<float>(x + (y - x) * w)) << i;
    }
  }
}

TEST(Cook, SameInputSameBytes) {
  const fs::path dir = test::fresh_dir();
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.input = test::data_path("alembic/points_varying.abc");
  o.codec = format::Codec::Zstd;
  o.chunk_size = format::kMinChunkSize;
  o.attributes = {"velocity", "id"};
  o.threads = 2;
  o.output = dir / "a.pstream";
  cook::cook(o);
  o.output = dir / "b.pstream";
  o.threads = 1;
  cook::cook(o);
  EXPECT_EQ(test::read_text(dir / "a.pstream"), test::read_text(dir / "b.pstream"));
  EXPECT_GT(fs::file_size(dir / "a.pstream"), 1000u);
}

// read_frames hands over what a records cook stores, frame by frame, and writes nothing: the
// default records (which the cook packs straight from the source's mapping), sparks reordered by
// id with colours and velocities, a subset of frames, and a visitor that stops.
TEST(Cook, ReadFramesGivesTheRecordsACookStores) {
  const fs::path dir = test::fresh_dir();
  struct Case {
    std::string input;
    std::vector<std::string> attributes;
    std::int64_t begin, end;
  };
  for (const Case& c :
       {Case{"alembic/points_varying.abc", {}, 0, -1}, Case{"sims/blender_sparks.abc", {"id", "velocity"}, 5, 30},
        Case{"sims/blender_flip_pour_small.abc", {}, 0, -1}}) {
    SCOPED_TRACE(c.input);
    cook::Options o;
    o.frame_codec = format::FrameCodec::Records;
    o.input = test::data_path(c.input);
    o.attributes = c.attributes;
    o.frame_begin = c.begin;
    o.frame_end = c.end;
    o.output = dir / "cooked.pstream";
    cook::cook(o);
    const auto reader = format::Reader::open(o.output);
    const format::Metadata& m = reader.metadata();
    std::vector<std::byte> stored(m.max_count * m.record_size);
    o.output = dir / "never-written.pstream";
    std::uint64_t seen = 0;
    const std::uint64_t visited = cook::read_frames(o, [&](const format::Metadata& meta, const cook::CookedFrame& f) {
      EXPECT_EQ(meta.record_size, m.record_size);
      EXPECT_EQ(meta.layout.size(), m.layout.size());
      EXPECT_EQ(meta.fps, m.fps);
      EXPECT_EQ(meta.time_of_frame0, m.time_of_frame0);
      EXPECT_EQ(meta.flags, m.flags);
      EXPECT_EQ(meta.source_file, m.source_file);
      EXPECT_EQ(meta.source_object, m.source_object);
      for (std::size_t a = 0; a < std::min(meta.layout.size(), m.layout.size()); ++a) {
        EXPECT_EQ(meta.layout[a].name, m.layout[a].name);
        EXPECT_EQ(meta.layout[a].offset, m.layout[a].offset);
      }
      EXPECT_TRUE(meta.cooked_with.empty());  // not the source's hash: the visitor may want 3 frames
      EXPECT_EQ(f.index, seen);
      EXPECT_EQ(f.frame_count, m.frame_count());
      EXPECT_NEAR(f.time, m.frames[f.index].time, 1e-9);
      EXPECT_EQ(f.count, m.frames[f.index].count);
      reader.read_frame(f.index, stored);
      EXPECT_EQ(f.records.size(), f.count * m.record_size);
      EXPECT_TRUE(std::equal(f.records.begin(), f.records.end(), stored.begin())) << "frame " << f.index;
      ++seen;
      return true;
    });
    EXPECT_EQ(visited, m.frame_count());
    EXPECT_EQ(seen, m.frame_count());
    EXPECT_GT(seen, 10u);
    EXPECT_FALSE(fs::exists(o.output));
    // A visitor that returns false stops the reading there.
    EXPECT_EQ(cook::read_frames(o, [](const format::Metadata&, const cook::CookedFrame& f) { return f.index < 2; }),
              3u);
  }
}

// ---- Bad input --------------------------------------------------------------------------------

std::string cook_error(cook::Options o) {
  try {
    cook::cook(o);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

void expect_cook_error(const cook::Options& o, const std::string& fragment) {
  const std::string message = cook_error(o);
  EXPECT_NE(message.find(fragment), std::string::npos) << "message: " << message;
  EXPECT_FALSE(fs::exists(o.output)) << "a failed cook left " << o.output;
  for (const auto& entry : fs::directory_iterator(o.output.parent_path())) {
    EXPECT_EQ(entry.path().string().find(".partial-"), std::string::npos) << "temporary file left: " << entry.path();
  }
}

TEST(CookBadInput, MissingObjectNoPointsZeroFramesTooMany) {
  const fs::path dir = test::fresh_dir();
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.output = dir / "out.pstream";
  o.input = test::data_path("alembic/points_constant.abc");
  o.object = "/nope";
  expect_cook_error(o, "no object '/nope'");
  o.object.clear();
  o.input = test::data_path("alembic/times_singles_only.abc");
  expect_cook_error(o, "holds no points objects");
  o.input = test::data_path("alembic/points_multi.abc");
  expect_cook_error(o, "cook them together with `merge`");
  o.input = test::data_path("alembic/points_constant.abc");
  o.frame_begin = 5;
  o.frame_end = 5;
  expect_cook_error(o, "selects no frames");
  o.frame_begin = 0;
  o.frame_end = -1;
  o.max_particles = 999;
  expect_cook_error(o, "frame 0 has 1000 particles, more than `max_particles`, 999");
  o.max_particles = 1000;
  o.chunk_size = 1000;
  expect_cook_error(o, "power of two");
  o.chunk_size = format::kMinChunkSize;
  o.attributes = {"velocity"};
  expect_cook_error(o, "`attributes` has velocity, but the source has no velocities");
}

// An archive without points objects but with one mesh cooks that mesh's vertices, as --object
// naming it does, and says so in the report; a mesh beside points objects is left alone.
TEST(Cook, TheOnlyMeshOfAnArchiveWithoutPointsCooksAsItsVertices) {
  const fs::path dir = test::fresh_dir();
  cook::Options o;
  o.input = test::data_path("alembic/mesh_vertices.abc");
  o.output = dir / "auto.pstream";
  const cook::Report automatic = cook::cook(o);
  EXPECT_EQ(automatic.object, "/grid");
  EXPECT_TRUE(automatic.mesh_vertices);
  o.object = "/grid";
  o.output = dir / "named.pstream";
  const cook::Report named = cook::cook(o);
  EXPECT_TRUE(named.mesh_vertices);
  EXPECT_EQ(automatic.particles, 24u * 400u);
  EXPECT_EQ(named.particles, automatic.particles);
  const auto a = format::Reader::open(dir / "auto.pstream");
  const auto b = format::Reader::open(dir / "named.pstream");
  ASSERT_EQ(a.metadata().frame_count(), 24u);
  const std::size_t bytes = 400 * a.metadata().record_size;
  std::vector<std::byte> from_a(bytes), from_b(bytes);
  for (std::uint64_t f = 0; f < 24; ++f) {
    a.read_frame(f, from_a);
    b.read_frame(f, from_b);
    EXPECT_EQ(from_a, from_b) << "frame " << f;
  }

  o.object.clear();
  o.input = test::data_path("alembic/strings_attributes.abc");  // points and a mesh
  o.output = dir / "points.pstream";
  const cook::Report points = cook::cook(o);
  EXPECT_EQ(points.object, "/sparks_geo/sparks");
  EXPECT_FALSE(points.mesh_vertices);
}

void write_ply(const fs::path& path, const std::vector<std::array<float, 4>>& points, bool binary) {
  std::ofstream out(path, std::ios::binary);
  out << "ply\nformat " << (binary ? "binary_little_endian" : "ascii") << " 1.0\nelement vertex " << points.size()
      << "\nproperty float x\nproperty float y\nproperty float z\nproperty float pscale\nend_header\n";
  for (const auto& p : points) {
    if (binary) {
      out.write(reinterpret_cast<const char*>(p.data()), 16);
    } else {
      out << p[0] << " " << p[1] << " " << p[2] << " " << p[3] << "\n";
    }
  }
}

// A cache without widths: every particle's scale is half the particles' spacing (neighbours just
// touch), whatever the scene's units.
TEST(Cook, WithoutWidthsTheScaleIsHalfTheSpacing) {
  for (const float spacing : {0.002f, 0.5f, 40.0f}) {
    SCOPED_TRACE(fmt::format("spacing {}", spacing));
    std::vector<float> p;
    for (int z = 0; z < 10; ++z)
      for (int y = 0; y < 10; ++y)
        for (int x = 0; x < 12; ++x) {  // a jittered grid: spacing within 10 % of `spacing`
          const float j = 0.05f * spacing * float((x * 7 + y * 3 + z * 5) % 3 - 1);
          p.insert(p.end(), {float(x) * spacing + j, float(y) * spacing, float(z) * spacing - j});
        }
    const fs::path dir = test::fresh_dir();
    alembic::PointsWriterOptions po;
    po.widths = false;
    po.velocities = false;
    {
      alembic::ArchiveWriter w(dir / "grid.abc", "test", "a grid without widths", 24.0, 0.0, po);
      std::vector<std::uint64_t> ids(p.size() / 3);
      std::iota(ids.begin(), ids.end(), 0);
      for (int f = 0; f < 3; ++f) {
        alembic::PointsSample sample;
        sample.positions = p;
        sample.ids = ids;
        w.write_sample(sample);
      }
      w.close();
    }
    cook::Options o;
    o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
    o.input = dir / "grid.abc";
    o.output = dir / "grid.pstream";
    const cook::Report r = cook::cook(o);
    EXPECT_NEAR(r.default_scale, 0.5 * spacing, 0.08 * spacing);
    const format::Reader reader = format::Reader::open(o.output);
    std::vector<float> records(reader.metadata().frames[0].count * 4);
    reader.read_frame(0, std::as_writable_bytes(std::span(records)));
    for (std::size_t i = 0; i < records.size(); i += 4) ASSERT_EQ(records[i + 3], float(r.default_scale));
  }
}

// NaN/Inf positions in an Alembic cache, through the cooker's fast path: its SIMD body and scalar
// tail, block borders, with and without a transform and widths.
TEST(CookBadInput, NanAndInfPositionsFailTheFrameOrAreDropped) {
  constexpr std::size_t n = 5003;  // not a multiple of any SIMD width: the kernel's tail runs too
  const float nan = std::nanf(""), inf = std::numeric_limits<float>::infinity();
  std::vector<float> p0(n * 3), p1(n * 3), widths(n);
  std::vector<std::uint64_t> ids(n);
  for (std::size_t i = 0; i < n; ++i) {
    const float x = static_cast<float>(i) * 0.25f - 300.0f, y = static_cast<float>(i % 97) - 40.0f,
                z = -static_cast<float>(i) * 0.125f;
    p0[i * 3] = p1[i * 3] = x;
    p0[i * 3 + 1] = y;
    p1[i * 3 + 1] = y + 1.0f;
    p0[i * 3 + 2] = p1[i * 3 + 2] = z;
    widths[i] = 0.01f * static_cast<float>(1 + i % 5);
    ids[i] = i;
  }
  // Around the 4096-record border of a 64 KiB chunk, at both ends, one of each kind.
  const std::pair<std::size_t, float> bad[] = {{3 * 3, nan},         {1000 * 3 + 1, nan}, {2048 * 3, inf},
                                               {4095 * 3 + 1, -inf}, {4096 * 3 + 2, nan}, {5002 * 3 + 2, inf}};
  for (const auto& [at, value] : bad) p0[at] = value;

  // Every SIMD target this machine runs (Highway dispatches to the best one otherwise).
  for (const std::int64_t target : hwy::SupportedAndGeneratedTargets()) {
    hwy::SetSupportedTargetsForTest(target);
    for (const bool translated : {false, true}) {
      for (const bool with_widths : {true, false}) {
        SCOPED_TRACE(fmt::format("{}: translated {} widths {}", hwy::TargetName(target), translated, with_widths));
        const fs::path dir = test::fresh_dir();
        alembic::PointsWriterOptions po;
        po.widths = with_widths;
        po.velocities = false;
        if (translated) {
          po.parent_xform = "xf";
          po.translate = {1.5, -2.0, 0.25};
        }
        {
          alembic::ArchiveWriter w(dir / "in.abc", "test", "NaN positions", 24.0, 0.0, po);
          for (const auto* p : {&p0, &p1}) {
            alembic::PointsSample sample;
            sample.positions = *p;
            sample.ids = ids;
            if (with_widths) sample.widths = widths;
            w.write_sample(sample);
          }
          w.close();
        }
        cook::Options o;
        o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
        o.input = dir / "in.abc";
        o.output = dir / "out.pstream";
        o.chunk_size = format::kMinChunkSize;
        expect_cook_error(o, "frame 0: 6 particles have NaN or infinite positions (the first is particle 3)");

        o.drop_invalid = true;
        const cook::Report report = cook::cook(o);
        EXPECT_EQ(report.dropped_invalid, 6u);
        const format::Reader reader = format::Reader::open(o.output);
        const format::Metadata& m = reader.metadata();
        ASSERT_EQ(m.frame_count(), 2u);
        std::vector<std::byte> buffer(n * 16), scratch(m.chunk_size);
        for (std::uint32_t f = 0; f < 2; ++f) {
          const std::vector<float>& p = f == 0 ? p0 : p1;
          std::vector<float> expected;
          for (std::size_t i = 0; i < n; ++i) {
            if (!std::isfinite(p[i * 3]) || !std::isfinite(p[i * 3 + 1]) || !std::isfinite(p[i * 3 + 2])) continue;
            for (int c = 0; c < 3; ++c) {
              expected.push_back(translated ? static_cast<float>(double{p[i * 3 + c]} + po.translate[c])
                                            : p[i * 3 + c]);
            }
            expected.push_back(with_widths ? widths[i] * 0.5f : static_cast<float>(report.default_scale));
          }
          ASSERT_EQ(m.frames[f].count * 4, expected.size()) << "frame " << f;
          reader.read_frame(f, buffer);
          EXPECT_EQ(std::memcmp(buffer.data(), expected.data(), expected.size() * 4), 0) << "frame " << f;
          EXPECT_EQ(m.frames[f].bounds, bounds_of(expected)) << "frame " << f;
        }
      }
    }
  }
  hwy::SetSupportedTargetsForTest(0);  // back to what the CPU supports
}

TEST(CookPly, AsciiAndBinarySequencesCookExactly) {
  for (bool binary : {false, true}) {
    const fs::path dir = test::fresh_dir();
    for (int f = 1; f <= 3; ++f) {
      std::vector<std::array<float, 4>> pts;
      for (int i = 0; i < 10 * f; ++i) pts.push_back({0.5f * i, 0.25f * f, -1.0f * i, 0.125f});
      write_ply(dir / fmt::format("frame.{:04d}.ply", f), pts, binary);
    }
    cook::Options o;
    o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
    o.input = dir / "frame.0001.ply";
    o.output = dir / "ply.pstream";
    cook::cook(o);
    const format::Reader reader = format::Reader::open(o.output);
    ASSERT_EQ(reader.metadata().frame_count(), 3u);
    std::vector<float> rec(30 * 4);
    std::vector<std::byte> scratch(reader.metadata().chunk_size);
    reader.read_frame(2, std::as_writable_bytes(std::span(rec)));
    EXPECT_EQ(reader.metadata().frames[2].count, 30u);
    EXPECT_EQ(rec[4 * 7 + 0], 3.5f);
    EXPECT_EQ(rec[4 * 7 + 1], 0.75f);
    EXPECT_EQ(rec[4 * 7 + 2], -7.0f);
    EXPECT_EQ(rec[4 * 7 + 3], 0.125f);  // pscale is already a radius
  }
}

TEST(CookPly, GapsMismatchesAndNaN) {
  const fs::path dir = test::fresh_dir();
  write_ply(dir / "a.0001.ply", {{0, 0, 0, 1}}, false);
  write_ply(dir / "a.0003.ply", {{0, 0, 0, 1}}, false);
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.input = dir / "a.0001.ply";
  o.output = dir / "out.pstream";
  expect_cook_error(o, "frame 2 is missing");

  write_ply(dir / "b.0001.ply", {{0, 0, 0, 1}}, false);
  {
    std::ofstream out(dir / "b.0002.ply");
    out << "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float "
           "z\nend_header\n0 0 0\n";
  }
  o.input = dir / "b.0001.ply";
  expect_cook_error(o, "differ from the first file's");

  const float nan = std::nanf("");
  write_ply(dir / "c.0001.ply", {{0, 0, 0, 1}, {nan, 0, 0, 1}, {1, 1, 1, 1}, {0, INFINITY, 0, 1}}, true);
  o.input = dir / "c.0001.ply";
  expect_cook_error(o, "frame 0: 2 particles have NaN or infinite positions (the first is particle 1)");
  o.drop_invalid = true;
  const cook::Report r = cook::cook(o);
  EXPECT_EQ(r.dropped_invalid, 2u);
  EXPECT_EQ(format::Reader::open(o.output).metadata().frames[0].count, 2u);
}

}  // namespace

namespace {

// Particles handed over in memory (cook.hpp: MemoryClip) cook as a file does: every record equals
// what was handed over (raw records: positions exact, scale half the width, colours as RGBA8, ids),
// births and deaths included; inconsistent arrays are refused naming the frame and the array.
// Twelve frames of particles whose ids come and go (births and deaths), every array filled; the
// clip's spans view the arrays held here.
struct MemoryTestClip {
  static constexpr std::size_t kFrames = 12;
  std::vector<std::vector<float>> position{kFrames}, width{kFrames}, velocity{kFrames}, color{kFrames}, age{kFrames},
      uvw{kFrames};
  std::vector<std::vector<std::uint64_t>> id{kFrames};
  pstream::cook::MemoryClip clip;
  MemoryTestClip() {
    clip.name = "memory test";
    clip.fps = 24;
    for (std::size_t f = 0; f < kFrames; ++f) {
      const std::uint64_t first = f * 10, n = 50 + f * 5;  // ids [first, first + n): births and deaths
      for (std::uint64_t i = first; i < first + n; ++i) {
        const float t = float(f) / 24.0f, a = float(i) * 0.37f;
        position[f].insert(position[f].end(), {std::cos(a) + t, std::sin(a) - t * t, float(i % 7) * 0.1f});
        width[f].push_back(0.01f + float(i % 5) * 0.002f);
        velocity[f].insert(velocity[f].end(), {1.0f, -2.0f * t, 0.0f});
        color[f].insert(color[f].end(), {float(i % 3) / 2.0f, 0.5f, 1.0f, 1.0f});
        age[f].push_back(float(f + 1 - i / 10) / 24.0f);
        uvw[f].insert(uvw[f].end(), {float(i) * 0.01f, -float(f), 0.25f});
        id[f].push_back(i);
      }
      pstream::cook::MemoryFrame mf;
      mf.time = double(f + 1) / 24.0;
      mf.count = n;
      mf.position = position[f];
      mf.width = width[f];
      mf.velocity = velocity[f];
      mf.id = id[f];
      mf.color = color[f];
      mf.floats = {{"age", 1, age[f]}, {"uvw", 3, uvw[f]}};
      clip.frames.push_back(mf);
    }
  }
  MemoryTestClip(const MemoryTestClip&) = delete;  // the spans view this object's arrays
};

TEST(Cook, FromMemoryEveryRecordEqualsWhatWasHandedOver) {
  const MemoryTestClip source;
  constexpr std::size_t kFrames = MemoryTestClip::kFrames;
  const pstream::cook::MemoryClip& clip = source.clip;
  const auto &position = source.position, &width = source.width, &velocity = source.velocity, &color = source.color;
  const auto &age = source.age, &uvw = source.uvw;
  const auto& id = source.id;
  const auto dir = pstream::test::fresh_dir();
  pstream::cook::Options o;
  o.output = dir / "memory.pstream";
  o.attributes = {"id", "age", "uvw"};
  pstream::cook::set_codec(o, "raw");
  const pstream::cook::Report r = pstream::cook::cook(o, clip);
  EXPECT_EQ(r.frames, kFrames);
  const auto reader = pstream::format::Reader::open(o.output);
  const auto& m = reader.metadata();
  ASSERT_EQ(m.frame_count(), kFrames);
  EXPECT_DOUBLE_EQ(m.fps, 24.0);
  const auto* pos = m.find("position");
  const auto* scale = m.find("scale");
  const auto* col = m.find("color");
  const auto* vel = m.find("velocity");
  const auto* ids = m.find("id");
  const auto* ages = m.find("age");
  const auto* uvws = m.find("uvw");
  ASSERT_TRUE(pos && scale && col && vel && ids && ages && uvws);
  EXPECT_EQ(uvws->components, 3);
  std::vector<std::byte> records = pstream::format::frame_buffer(m, reader.name());
  for (std::size_t f = 0; f < kFrames; ++f) {
    reader.read_frame(f, records);
    ASSERT_EQ(m.frames[f].count, clip.frames[f].count) << "frame " << f;
    for (std::uint64_t k = 0; k < clip.frames[f].count; ++k) {
      const std::byte* rec = records.data() + k * m.record_size;
      std::uint64_t i;
      std::memcpy(&i, rec + ids->offset, 8);
      const std::uint64_t j = i - id[f].front();  // records are in id order, as handed over
      ASSERT_EQ(j, k) << "frame " << f;
      float p[3], s, v[3];
      std::uint8_t c[4];
      std::memcpy(p, rec + pos->offset, 12);
      std::memcpy(&s, rec + scale->offset, 4);
      std::memcpy(v, rec + vel->offset, 12);
      std::memcpy(c, rec + col->offset, 4);
      for (int a = 0; a < 3; ++a) {
        EXPECT_EQ(p[a], position[f][j * 3 + a]) << "frame " << f << " particle " << j;
        EXPECT_EQ(v[a], velocity[f][j * 3 + a]) << "frame " << f << " particle " << j;
      }
      EXPECT_EQ(s, width[f][j] * 0.5f);
      for (int a = 0; a < 4; ++a) EXPECT_EQ(c[a], pstream::cook::to_unorm8(color[f][j * 4 + a]));
      float g, u[3];
      std::memcpy(&g, rec + ages->offset, 4);
      std::memcpy(u, rec + uvws->offset, 12);
      EXPECT_EQ(g, age[f][j]);
      for (int a = 0; a < 3; ++a) EXPECT_EQ(u[a], uvw[f][j * 3 + a]);
    }
  }
  // What is refused, by name.
  const auto refused = [&](pstream::cook::MemoryClip bad, const std::string& expected) {
    pstream::cook::Options ob = o;
    ob.output = dir / "bad.pstream";
    try {
      pstream::cook::cook(ob, bad);
      ADD_FAILURE() << "accepted; expected: " << expected;
    } catch (const pstream::Error& e) {
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    }
    EXPECT_FALSE(std::filesystem::exists(ob.output));
  };
  auto short_ids = clip;
  short_ids.frames[3].id = short_ids.frames[3].id.first(10);
  refused(short_ids, "memory test: frame 3: the id array holds 10 values, expected 65 (65 particles x 1)");
  auto missing = clip;
  missing.frames[5].color = {};
  refused(missing, "memory test: frame 5 has no color array, but other frames have one");
  auto backwards = clip;
  backwards.frames[7].time = backwards.frames[6].time;
  refused(backwards, "memory test: frame 7 is at time");
  auto no_age = clip;
  no_age.frames[4].floats.erase(no_age.frames[4].floats.begin());
  refused(no_age, "memory test: frame 4 has no 'age' array, but other frames have one");
  auto flat_uvw = clip;
  flat_uvw.frames[2].floats[1].components = 1;
  refused(flat_uvw, "memory test: frame 2: float attribute 'uvw' has 1 components, the other frames 3");
  auto builtin = clip;
  for (auto& f : builtin.frames) f.floats[0].name = "scale";
  refused(builtin, "memory test: frame 0: a float attribute named 'scale': that name is a built-in attribute's");
  auto unknown = o;
  unknown.attributes = {"temperature"};
  unknown.output = dir / "bad.pstream";
  try {
    pstream::cook::cook(unknown, clip);
    ADD_FAILURE() << "an attribute the clip lacks was stored";
  } catch (const pstream::Error& e) {
    EXPECT_NE(std::string(e.what()).find("`attributes` has temperature, but the source has no such attribute"),
              std::string::npos)
        << e.what();
  }
  refused(pstream::cook::MemoryClip{"nothing", "", 24.0, {}}, "nothing: no frames to cook");
}

// The particle codec encodes a keyframe group a thread; Options::group_memory bounds how many
// groups' frames are held at once. One group at a time (a budget smaller than a group) or one a
// thread, the clip is the same bytes.
TEST(Cook, GroupsInFlightFitTheMemoryGivenAndTheClipIsTheSame) {
  const auto dir = pstream::test::fresh_dir();
  pstream::cook::Options o;
  o.input = pstream::test::data_path("sims/blender_sparks.abc");
  o.threads = 2;
  o.particle.keyframe_interval = 8;  // 6 groups of the 48 frames
  o.output = dir / "threads.pstream";
  const pstream::cook::Report wide = pstream::cook::cook(o);
  EXPECT_EQ(wide.groups_in_flight, 2u);
  o.group_memory = 1;  // less than one group: one at a time
  o.output = dir / "one.pstream";
  const pstream::cook::Report narrow = pstream::cook::cook(o);
  EXPECT_EQ(narrow.groups_in_flight, 1u);
  EXPECT_EQ(pstream::test::read_bytes((dir / "one.pstream").string()),
            pstream::test::read_bytes((dir / "threads.pstream").string()));
  EXPECT_EQ(narrow.keyframes, 6u);
}

// The particle cook's progress: each frame of the scan, then the writing's start, then once a
// batch of keyframe groups (encoded together, so that a front end's rate is the batch's pace and
// not a burst of frames written at once).
TEST(Cook, ProgressCountsTheScanThenEachBatchOfGroups) {
  const auto dir = pstream::test::fresh_dir();
  pstream::cook::Options o;
  o.input = pstream::test::data_path("sims/blender_sparks.abc");
  o.output = dir / "progress.pstream";
  o.threads = 2;
  o.particle.keyframe_interval = 8;  // batches of 2 groups: 16 frames
  std::vector<std::uint64_t> scan, write;
  pstream::cook::cook(o, [&](const pstream::cook::Progress& p) {
    (p.stage == pstream::cook::Stage::Scan ? scan : write).push_back(p.frames_done);
    EXPECT_TRUE(write.empty() || p.stage == pstream::cook::Stage::Write) << "a scan after the writing began";
  });
  std::vector<std::uint64_t> frames(48);
  std::iota(frames.begin(), frames.end(), 1);
  EXPECT_EQ(scan, frames);
  EXPECT_EQ(write, (std::vector<std::uint64_t>{0, 16, 32, 48}));
}

// Frames spooled to disk one at a time (cook.hpp: FrameSpool) cook into the very bytes the same
// frames cook into from memory; the spool holds none of a frame's arrays in memory (one
// allocation at most for a million particles), leaves no file in its folder at any time, refuses
// a frame that does not fit those before it without changing, and can leave the ids out.
TEST(Cook, FromASpoolTheSameBytesAsFromMemoryAndNoFileLeft) {
  const MemoryTestClip source;
  const auto dir = pstream::test::fresh_dir();
  const auto spool_dir = dir / "spool";
  std::filesystem::create_directories(spool_dir);
  const auto files_in = [](const std::filesystem::path& folder) {
    return std::distance(std::filesystem::directory_iterator(folder), std::filesystem::directory_iterator{});
  };
  pstream::cook::Options o;
  o.output = dir / "memory.pstream";
  o.attributes = {"id", "uvw", "age"};
  pstream::cook::cook(o, source.clip);
  {
    pstream::cook::FrameSpool spool("memory test", spool_dir);
    for (pstream::cook::MemoryFrame f : source.clip.frames) {
      if (f.time > 0.2) std::swap(f.floats[0], f.floats[1]);  // a frame may list its floats in any order
      spool.add(f);
    }
    EXPECT_EQ(spool.frames(), MemoryTestClip::kFrames);
    EXPECT_EQ(files_in(spool_dir), 0) << "the spool's temporary has a name in its folder";
    o.output = dir / "spool.pstream";
    pstream::cook::cook(o, spool.clip("", 24.0));
    EXPECT_EQ(pstream::test::read_bytes((dir / "spool.pstream").string()),
              pstream::test::read_bytes((dir / "memory.pstream").string()));

    // Refused: named, and the spool is as it was (the next frame still fits).
    const auto refused = [&](pstream::cook::MemoryFrame bad, const std::string& expected) {
      const std::uint64_t frames = spool.frames(), bytes = spool.bytes();
      try {
        spool.add(bad);
        ADD_FAILURE() << "accepted; expected: " << expected;
      } catch (const pstream::Error& e) {
        EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
      }
      EXPECT_EQ(spool.frames(), frames);
      EXPECT_EQ(spool.bytes(), bytes);
    };
    pstream::cook::MemoryFrame next = source.clip.frames.back();
    next.time += 1.0 / 24.0;
    auto no_color = next;
    no_color.color = {};
    refused(no_color, "memory test: frame 12 has no color array, but other frames have one");
    auto early = next;
    early.time = 0.0;
    refused(early, "memory test: frame 12 is at time 0 s, after frame 11 at 0.5 s: times must increase");
    auto short_width = next;
    short_width.width = short_width.width.first(3);
    refused(short_width, "memory test: frame 12: the width array holds 3 values, expected 105 (105 particles x 1)");
    spool.add(next);
    EXPECT_EQ(spool.frames(), MemoryTestClip::kFrames + 1);

    // Without ids: the clip made from the spool has none, so the cook orders nothing by them.
    spool.drop_ids();
    const pstream::cook::MemoryClip without = spool.clip("", 24.0);
    for (const pstream::cook::MemoryFrame& f : without.frames) EXPECT_TRUE(f.id.empty());
    o.output = dir / "no_ids.pstream";
    o.attributes = {"age"};
    pstream::cook::cook(o, without);
    EXPECT_EQ(pstream::format::Reader::open(o.output).metadata().find("id"), nullptr);
  }
  EXPECT_EQ(files_in(spool_dir), 0);

  // A million particles a frame: written, not kept.
  {
    constexpr std::uint64_t kCount = 1'000'000;
    std::vector<float> big(kCount * 3, 0.5f);
    pstream::cook::MemoryFrame f;
    f.count = kCount;
    f.position = big;
    pstream::cook::FrameSpool spool("big", spool_dir);
    spool.add(f);  // the entries' first room
    f.time = 1.0;
    const std::uint64_t before = pstream::test::allocation_count();
    spool.add(f);
    EXPECT_LE(pstream::test::allocation_count() - before, 1u);
    EXPECT_EQ(spool.bytes(), 2 * kCount * 12);
  }
  EXPECT_EQ(files_in(spool_dir), 0);

  // A folder that is not there.
  try {
    pstream::cook::FrameSpool spool("x", dir / "missing");
    ADD_FAILURE() << "a spool in a missing folder";
  } catch (const pstream::Error& e) {
    EXPECT_NE(std::string(e.what()).find("missing: cannot make the frame spool's temporary file there"),
              std::string::npos)
        << e.what();
  }
}

// The spool's fallback for file systems without O_TMPFILE (some network and FUSE ones), which
// this machine's file systems never take: the file it makes works, has no name in its folder
// from the moment it returns (no link at all), and a folder that is not there is named.
TEST(Cook, SpoolFallbackFileHasNoNameOnceMade) {
  const auto dir = pstream::test::fresh_dir();
  const int fd = pstream::cook::named_then_unlinked_file(dir);
  ASSERT_GE(fd, 0);
  EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir), std::filesystem::directory_iterator{}), 0);
  struct stat st {};
  ASSERT_EQ(::fstat(fd, &st), 0);
  EXPECT_EQ(st.st_nlink, 0u);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
  const std::string bytes = "frames written and read back";
  EXPECT_EQ(::pwrite(fd, bytes.data(), bytes.size(), 4096), static_cast<ssize_t>(bytes.size()));
  std::string back(bytes.size(), '\0');
  EXPECT_EQ(::pread(fd, back.data(), back.size(), 4096), static_cast<ssize_t>(back.size()));
  EXPECT_EQ(back, bytes);
  ::close(fd);
  try {
    pstream::cook::named_then_unlinked_file(dir / "missing");
    ADD_FAILURE() << "a file in a missing folder";
  } catch (const pstream::Error& e) {
    EXPECT_NE(std::string(e.what()).find("missing: cannot make the frame spool's temporary file there"),
              std::string::npos)
        << e.what();
  }
}

}  // namespace
