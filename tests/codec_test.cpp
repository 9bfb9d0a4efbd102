// The particle codec end to end: real caches cooked, every frame decoded and compared with the
// source's records (the records codec), value by value.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <map>
#include <memory>
#include <numeric>
#include <random>
#include <set>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "format/entropy.hpp"
#include "format/particle_common.hpp"  // the decoder's derived-velocity rule, checked against the spec's
#include "particlestream/alembic.hpp"
#include "particlestream/codec.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"
#include "particlestream/io.hpp"
#include "test_util.hpp"
#include "zstd_packets.hpp"

namespace {

using namespace pstream;
namespace fs = std::filesystem;

struct Fixture {
  std::string file, object;
  std::vector<std::string> attributes;
};

// The sims and the Alembic fixtures with particles, with the attributes each can give.
const std::vector<Fixture>& fixtures() {
  static const std::vector<Fixture> all = {
      {"sims/blender_flip_pour_small.abc", "", {"velocity"}},
      {"sims/blender_sparks.abc", "", {"velocity", "id", "age"}},
      {"sims/blender_sparks.abc", "", {}},  // [x y z scale] + colour, ordered by id without storing it
      {"alembic/points_varying.abc", "", {"velocity", "id"}},
      {"alembic/points_large.abc", "", {}},
      {"alembic/points_xform.abc", "", {}},
      {"alembic/points_empty_frames.abc", "", {}},
      {"alembic/points_constant.abc", "", {}},
      {"alembic/mesh_vertices.abc", "/grid", {}},
  };
  return all;
}

fs::path cook_with(const fs::path& dir, const Fixture& fx, const std::string& name, format::FrameCodec codec,
                   const format::ParticleCodecOptions& particle = {}, unsigned threads = 0,
                   bool keep_source_order = false) {
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.keep_source_order = keep_source_order;
  o.input = test::data_path(fx.file);
  o.object = fx.object;
  o.attributes = fx.attributes;
  o.output = dir / (name + ".pstream");
  o.frame_codec = codec;
  o.particle = particle;
  o.chunk_size = format::kMinChunkSize;  // packets straddle chunks
  o.threads = threads;
  cook::cook(o);
  return o.output;
}

// Every frame of both files decoded; returns the comparison.
format::FrameComparison compare_files(const fs::path& decoded_file, const fs::path& source_file) {
  const auto a = format::Reader::open(decoded_file);
  const auto b = format::Reader::open(source_file);
  const auto& ma = a.metadata();
  const auto& mb = b.metadata();
  EXPECT_EQ(ma.frame_count(), mb.frame_count());
  std::vector<std::byte> da(ma.max_count * ma.record_size), db(mb.max_count * mb.record_size);
  format::FrameComparison c;
  c.in_order = ma.codec.order == format::FrameOrder::Id;  // both in id order: particle i is particle i
  for (std::uint64_t f = 0; f < std::min(ma.frame_count(), mb.frame_count()); ++f) {
    a.read_frame(f, da);
    b.read_frame(f, db);
    c.add(ma.layout, da, ma.frames[f].count, mb.layout, db, mb.frames[f].count, &ma.codec);
  }
  return c;
}

TEST(ParticleCodec, EveryDecodedValueIsWithinItsBoundOnEveryFixture) {
  const fs::path dir = test::fresh_dir();
  int n = 0;
  for (const Fixture& fx : fixtures()) {
    SCOPED_TRACE(fx.file);
    const std::string tag = std::to_string(n++);
    const fs::path raw = cook_with(dir, fx, "raw" + tag, format::FrameCodec::Records);
    const fs::path lossy = cook_with(dir, fx, "lossy" + tag, format::FrameCodec::Particle);
    const auto meta = format::Reader::open(lossy).metadata();
    ASSERT_EQ(meta.codec.codec, format::FrameCodec::Particle);
    EXPECT_FALSE(meta.codec.lossless);
    const format::FrameComparison c = compare_files(lossy, raw);
    EXPECT_EQ(c.count_mismatches, 0u);
    EXPECT_EQ(c.unmatched, 0u);
    EXPECT_EQ(c.particles, meta.total_particles());
    std::uint64_t quantized = 0;
    for (std::size_t w = 0; w < meta.codec.words.size(); ++w) {
      const format::WordCodingEntry& e = meta.codec.words[w];
      if (e.coding == format::WordCoding::Quantized) {
        ++quantized;
        EXPECT_LE(c.max_error[w], double(e.error)) << "word " << w;
        EXPECT_GT(e.error, 0.0f);
      } else if (e.coding == format::WordCoding::Relative) {  // scale: within 1 % of each particle's own
        EXPECT_EQ(w, 3u);
        EXPECT_FLOAT_EQ(e.error, 0.01f);
        EXPECT_LE(c.max_relative_error[w], double(e.error)) << "word " << w;
      } else if (e.coding == format::WordCoding::Derived) {  // no bound: DerivedVelocity.* measure it
        EXPECT_NE(meta.codec.order, format::FrameOrder::Matched);
      } else {
        EXPECT_EQ(c.max_error[w], 0.0) << "word " << w << " must be exact";
      }
    }
    // Positions get the default bound, 1e-4 of the clip's bounds diagonal.
    if (meta.codec.words[0].coding == format::WordCoding::Quantized) {
      const auto& b = meta.bounds;
      const double diagonal =
          std::sqrt((b[3] - b[0]) * (b[3] - b[0]) + (b[4] - b[1]) * (b[4] - b[1]) + (b[5] - b[2]) * (b[5] - b[2]));
      EXPECT_NEAR(meta.codec.error, 1e-4 * diagonal, 2e-6 * diagonal);
      EXPECT_GT(quantized, 0u);
    }
  }
}

// The decoder runs with AVX2 where the processor has it (eight values a vector), else with SSE2
// (four): both give the same bits for every frame of every fixture, in its default cook (ids,
// derived velocity, colour) and as [x y z scale] records. PSTREAM_SIMD=baseline picks SSE2 for
// the units made while it is set.
TEST(ParticleCodec, AVX2AndBaselineDecodeTheSameBits) {
  if (format::particle_decoder_simd() != "AVX2") GTEST_SKIP() << "this processor has no AVX2";
  const fs::path dir = test::fresh_dir();
  int n = 0;
  for (const Fixture& fx : fixtures()) {
    SCOPED_TRACE(fx.file);
    const fs::path clip = cook_with(dir, fx, "clip" + std::to_string(n++), format::FrameCodec::Particle);
    const auto frames = [&](bool baseline) {
      if (baseline) ::setenv("PSTREAM_SIMD", "baseline", 1);
      const auto r = format::Reader::open(clip);
      EXPECT_EQ(format::particle_decoder_simd(), baseline ? "SSE2" : "AVX2");
      const auto& m = r.metadata();
      std::vector<std::byte> all, frame(m.max_count * m.record_size);
      for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
        r.read_frame(f, frame);
        all.insert(all.end(), frame.begin(), frame.begin() + std::ptrdiff_t(m.frames[f].count * m.record_size));
      }
      ::unsetenv("PSTREAM_SIMD");
      return all;
    };
    const std::vector<std::byte> avx2 = frames(false), baseline = frames(true);
    EXPECT_GT(avx2.size(), 0u);
    EXPECT_TRUE(avx2 == baseline);
  }
}

// A source that is not in memory (a URL, host callbacks): the Reader asks it for each chunk it
// needs. Counts the reads.
class CountingSource final : public io::ByteSource {
 public:
  explicit CountingSource(const fs::path& path) : name_(path.string()), bytes_(test::read_bytes(name_)) {}
  void read(std::uint64_t offset, std::span<std::byte> out) override {
    ASSERT_LE(offset + out.size(), bytes_.size());
    std::memcpy(out.data(), bytes_.data() + offset, out.size());
    ++reads;
    bytes_read += out.size();
  }
  std::uint64_t size() const override { return bytes_.size(); }
  const std::string& name() const override { return name_; }
  std::uint64_t reads = 0, bytes_read = 0;

 private:
  std::string name_;
  std::vector<std::byte> bytes_;
};

// Frames read in turn mostly share a chunk (a particle packet is small): the Reader reads,
// checks and decompresses each chunk once, not once per frame. Through a source that is not in
// memory, every chunk is fetched exactly once when the frames are read in order, and the frames
// are the same bytes as the mapped file's. Reading backwards still decodes from the keyframe.
TEST(ParticleCodec, FramesReadInTurnFetchEachChunkOnce) {
  const fs::path dir = test::fresh_dir();
  const fs::path file = cook_with(dir, fixtures()[0], "flip", format::FrameCodec::Particle);
  const auto mapped = format::Reader::open(file);
  auto source = std::make_unique<CountingSource>(file);
  const CountingSource& counting = *source;  // the reader owns it from here on
  const auto remote = format::Reader::open(std::move(source));
  const format::Metadata& m = mapped.metadata();
  ASSERT_GT(m.chunk_count(), 2u);
  ASSERT_GT(m.frame_count(), 3 * m.chunk_count()) << "several packets to a chunk";
  const std::uint64_t at_open = counting.reads;
  std::vector<std::byte> a(m.max_count * m.record_size), b(a.size());
  for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
    mapped.read_frame(f, a);
    remote.read_frame(f, b);
    ASSERT_EQ(std::memcmp(a.data(), b.data(), m.frames[f].count * m.record_size), 0) << "frame " << f;
  }
  EXPECT_EQ(counting.reads - at_open, m.chunk_count());
  std::uint64_t stored = 0;
  for (const format::ChunkEntry& c : m.chunks) stored += c.stored_size;
  EXPECT_LE(counting.bytes_read, fs::file_size(file));
  EXPECT_GE(counting.bytes_read, stored);
  for (std::uint64_t f = m.frame_count(); f-- > 0;) {  // backwards: each frame from its keyframe on
    mapped.read_frame(f, a);
    remote.read_frame(f, b);
    ASSERT_EQ(std::memcmp(a.data(), b.data(), m.frames[f].count * m.record_size), 0) << "frame " << f;
  }
}

TEST(ParticleCodec, LosslessModeIsBitExactInTheSourceOrder) {
  const fs::path dir = test::fresh_dir();
  format::ParticleCodecOptions lossless;
  lossless.lossless = true;
  int n = 0;
  for (const Fixture& fx : fixtures()) {
    SCOPED_TRACE(fx.file);
    const std::string tag = std::to_string(n++);
    const fs::path raw = cook_with(dir, fx, "raw" + tag, format::FrameCodec::Records, {}, 0, true);
    const fs::path exact = cook_with(dir, fx, "exact" + tag, format::FrameCodec::Particle, lossless);
    const auto a = format::Reader::open(exact);
    const auto b = format::Reader::open(raw);
    EXPECT_TRUE(a.metadata().codec.lossless);
    EXPECT_EQ(a.metadata().codec.order, format::FrameOrder::Source);
    std::vector<std::byte> da(a.metadata().max_count * a.metadata().record_size), db(da.size());
    for (std::uint64_t f = 0; f < a.metadata().frame_count(); ++f) {
      a.read_frame(f, da);
      b.read_frame(f, db);
      ASSERT_EQ(a.metadata().frames[f].count, b.metadata().frames[f].count);
      ASSERT_EQ(std::memcmp(da.data(), db.data(), a.metadata().frames[f].count * a.metadata().record_size), 0)
          << "frame " << f;
    }
  }
}

TEST(ParticleCodec, FramesWithIdsAreInIdOrderAndIdsAreExact) {
  const fs::path dir = test::fresh_dir();
  const Fixture fx{"sims/blender_sparks.abc", "", {"id"}};
  const fs::path file = cook_with(dir, fx, "sparks", format::FrameCodec::Particle);
  const auto r = format::Reader::open(file);
  const auto& m = r.metadata();
  EXPECT_EQ(m.codec.order, format::FrameOrder::Id);
  const format::Attribute* id = m.find("id");
  ASSERT_NE(id, nullptr);
  EXPECT_EQ(m.codec.words[id->offset / 4].coding, format::WordCoding::Id);
  std::vector<std::byte> rec(m.max_count * m.record_size);
  for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
    r.read_frame(f, rec);
    for (std::uint64_t i = 1; i < m.frames[f].count; ++i) {
      std::uint64_t a, b;
      std::memcpy(&a, rec.data() + (i - 1) * m.record_size + id->offset, 8);
      std::memcpy(&b, rec.data() + i * m.record_size + id->offset, 8);
      ASSERT_LT(a, b) << "frame " << f << " particle " << i;
    }
  }
  // Exactness of the ids themselves: compared by id, every particle finds its partner.
  const fs::path raw = cook_with(dir, fx, "raw", format::FrameCodec::Records);
  const auto c = compare_files(file, raw);
  EXPECT_EQ(c.unmatched, 0u);
}

// Sizes are deterministic: these pin what the codec reaches at the default bound and keyframe
// interval (docs/compression.md), so a change that loses ratio shows up here.
// Pairing by nearest position takes the wrong partner where particles lie closer than twice the
// bound (the demo fountain's dense jet made `verify --against` report errors of 2 % in scale and
// 3x the position bound on a clip within both): decoded A' is nearer B than A, takes it, and
// leaves A to B'. A clip ordered by id against its source in id order pairs particle i with i.
// A particle codec's plan for [x y z scale] in `order`: positions within `error`, scale coded as
// `scale` (within 1 % where relative).
format::CodecInfo xyz_scale_plan(format::FrameOrder order, float error, format::WordCoding scale) {
  format::CodecInfo info;
  info.codec = format::FrameCodec::Particle;
  info.order = order;
  info.words.resize(4);
  for (int w = 0; w < 3; ++w) {
    info.words[w].coding = format::WordCoding::Quantized;
    info.words[w].error = error;
  }
  info.words[3].coding = scale;
  if (scale == format::WordCoding::Relative) info.words[3].error = 0.01f;
  return info;
}

TEST(FrameComparison, InOrderPairsParticleIWithParticleIWhereNearestWouldNot) {
  const std::vector<format::Attribute> layout = format::default_layout();  // x y z scale
  const format::CodecInfo info = xyz_scale_plan(format::FrameOrder::Id, 1.0f, format::WordCoding::Relative);
  const float source[8] = {0.0f, 0, 0, 1, 1.5f, 0, 0, 1}, decoded[8] = {0.9f, 0, 0, 1, 2.4f, 0, 0, 1};
  const auto bytes = [](const float* v) { return std::as_bytes(std::span(v, 8)); };
  format::FrameComparison nearest;
  nearest.add(layout, bytes(decoded), 2, bytes(source), 2, &info);
  EXPECT_NEAR(nearest.max_error[0], 2.4, 1e-6);  // A' took B, B' was left A
  format::FrameComparison in_order;
  in_order.in_order = true;
  in_order.add(layout, bytes(decoded), 2, bytes(source), 2, &info);
  EXPECT_NEAR(in_order.max_error[0], 0.9, 1e-6);
  EXPECT_EQ(in_order.unmatched, 0u);
  format::FrameComparison fewer;  // different counts: no order to trust, nearest again
  fewer.in_order = true;
  fewer.add(layout, bytes(decoded), 2, bytes(source), 1, &info);
  EXPECT_EQ(fewer.count_mismatches, 1u);
}

// Without ids or order, each decoded particle takes the nearest unused source particle among the
// 27 cells (4 bounds wide) around it, searching first the cells its bound's box overlaps. A
// shuffled copy within the bound pairs every particle within it; a particle moved beyond its bound
// is still found, in the cells around, and its error is reported as it is; one moved past them
// finds no partner.
TEST(FrameComparison, NearestPartnersWithinAndBeyondTheBound) {
  const std::vector<format::Attribute> layout = format::default_layout();  // x y z scale
  const format::CodecInfo info = xyz_scale_plan(format::FrameOrder::Matched, 0.01f, format::WordCoding::Constant);
  constexpr std::size_t n = 4000;
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> place(0.0f, 4.0f), jitter(-0.0099f, 0.0099f);
  std::vector<float> source(n * 4), decoded(n * 4);
  for (std::size_t i = 0; i < n; ++i) {
    for (int c = 0; c < 3; ++c) source[i * 4 + std::size_t(c)] = place(rng);
    source[i * 4 + 3] = 0.5f;
  }
  std::vector<std::size_t> shuffled(n);
  std::iota(shuffled.begin(), shuffled.end(), std::size_t{0});
  std::shuffle(shuffled.begin(), shuffled.end(), rng);
  for (std::size_t d = 0; d < n; ++d) {
    for (int c = 0; c < 4; ++c) decoded[d * 4 + std::size_t(c)] = source[shuffled[d] * 4 + std::size_t(c)];
    for (int c = 0; c < 3; ++c) decoded[d * 4 + std::size_t(c)] += jitter(rng);
  }
  const auto bytes = [](const std::vector<float>& v) { return std::as_bytes(std::span(v)); };
  format::FrameComparison within;
  within.add(layout, bytes(decoded), n, bytes(source), n, &info);
  EXPECT_EQ(within.unmatched, 0u);
  for (int c = 0; c < 3; ++c) {
    EXPECT_LE(within.max_error[std::size_t(c)], 0.0099 + 1e-6);
    EXPECT_GT(within.max_error[std::size_t(c)], 0.009);
  }
  // Particle 10 moved 2.5 bounds along x (within the cells around it), particle 20 moved 20
  // bounds along y (beyond them).
  decoded[10 * 4 + 0] = source[shuffled[10] * 4 + 0] + 0.025f;
  decoded[20 * 4 + 1] = source[shuffled[20] * 4 + 1] + 0.2f;
  format::FrameComparison beyond;
  beyond.add(layout, bytes(decoded), n, bytes(source), n, &info);
  EXPECT_NEAR(beyond.max_error[0], 0.025, 1e-4);
  EXPECT_LE(beyond.max_error[1], 0.0099 + 1e-6);
  EXPECT_EQ(beyond.unmatched, 1u);
}

TEST(ParticleCodec, BytesPerParticleOnTheSims) {
  const fs::path dir = test::fresh_dir();
  const auto bytes_per_particle = [&](const Fixture& fx, const std::string& name) {
    cook::Options o;
    o.input = test::data_path(fx.file);
    o.output = dir / (name + ".pstream");
    o.color_from = "none";  // the [x y z scale] record (the default cook: the particle codec)
    o.keep_velocity = false;
    cook::cook(o);
    const auto m = format::Reader::open(o.output).metadata();
    return double(m.stream_size()) / double(m.total_particles());
  };
  const double sparks = bytes_per_particle({"sims/blender_sparks.abc", "", {}}, "sparks");
  const double flip = bytes_per_particle({"sims/blender_flip_pour_small.abc", "", {}}, "flip");
  EXPECT_LE(sparks, 1.2);  // the issue's target for caches with ids
  EXPECT_LE(flip, 2.3);    // the target is 2.0: missed (docs/compression.md says by how much)
  EXPECT_GT(flip, 1.0);    // guards the measurement itself
  RecordProperty("sparks_bytes_per_particle", std::to_string(sparks));
  RecordProperty("flip_bytes_per_particle", std::to_string(flip));
}

// The default zstd level follows the frame order (format::default_particle_zstd_level): 16 where
// particles have ids, 12 without, where the residuals are a solver's re-sampling noise and level
// 16's optimal parser finds under 2 % more (since the leftovers are paired, nothing: 0.04 % less).
// The file records the level it was cooked at.
TEST(ParticleCodec, DefaultZstdLevelFollowsTheFrameOrder) {
  const fs::path dir = test::fresh_dir();
  const auto cook_at = [&](const std::string& file, const std::string& name, int level) {
    cook::Options o;
    o.input = test::data_path(file);
    o.output = dir / (name + ".pstream");
    o.color_from = "none";
    o.keep_velocity = false;
    o.particle.zstd_level = level;  // 0: the default
    cook::cook(o);
    return format::Reader::open(o.output).metadata();
  };
  const format::Metadata flip = cook_at("sims/blender_flip_pour_small.abc", "flip", 0);
  const format::Metadata flip16 = cook_at("sims/blender_flip_pour_small.abc", "flip16", 16);
  const format::Metadata sparks = cook_at("sims/blender_sparks.abc", "sparks", 0);
  EXPECT_EQ(flip.codec.order, format::FrameOrder::Matched);
  EXPECT_EQ(sparks.codec.order, format::FrameOrder::Id);
  EXPECT_NE(flip.cooked_with.find("codec=particle:12 "), std::string::npos) << flip.cooked_with;
  EXPECT_NE(flip16.cooked_with.find("codec=particle:16 "), std::string::npos) << flip16.cooked_with;
  EXPECT_NE(sparks.cooked_with.find("codec=particle:16 "), std::string::npos) << sparks.cooked_with;
  // The settings say what the cook did: a velocity is derived only where particles have ids.
  EXPECT_NE(flip.cooked_with.find(" velocity=stored "), std::string::npos) << flip.cooked_with;
  EXPECT_NE(sparks.cooked_with.find(" velocity=derived "), std::string::npos) << sparks.cooked_with;
  // Level 16 is not 2 % smaller on the FLIP pour.
  EXPECT_GT(double(flip16.stream_size()), 0.98 * double(flip.stream_size()));
  EXPECT_EQ(format::default_particle_zstd_level(format::FrameOrder::Id, false), format::kDefaultParticleZstdLevel);
  EXPECT_EQ(format::default_particle_zstd_level(format::FrameOrder::Matched, false),
            format::kDefaultMatchedParticleZstdLevel);
  EXPECT_EQ(format::default_particle_zstd_level(format::FrameOrder::Matched, true),
            format::kDefaultLosslessParticleZstdLevel);
}

TEST(ParticleCodec, KeyframesEveryKFramesAndRandomAccess) {
  const fs::path dir = test::fresh_dir();
  const Fixture fx{"sims/blender_flip_pour_small.abc", "", {}};
  format::ParticleCodecOptions every8;
  every8.keyframe_interval = 8;
  const fs::path file = cook_with(dir, fx, "k8", format::FrameCodec::Particle, every8);
  const fs::path raw = cook_with(dir, fx, "raw", format::FrameCodec::Records);
  const auto r = format::Reader::open(file);
  const auto ref = format::Reader::open(raw);
  const auto& m = r.metadata();
  EXPECT_EQ(m.codec.keyframe_interval, 8u);
  for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
    EXPECT_EQ(m.frames[f].keyframe, f % 8 == 0) << f;
    EXPECT_EQ(format::keyframe_of(m, f), f / 8 * 8);
  }
  // Frames read out of order decode from their keyframe and match the source within the bound.
  std::vector<std::byte> a(m.max_count * m.record_size), b(a.size());
  for (const std::uint64_t f : {37u, 3u, 47u, 8u, 9u, 22u}) {
    r.read_frame(f, a);
    ref.read_frame(f, b);
    format::FrameComparison c;
    c.add(m.layout, a, m.frames[f].count, b, m.frames[f].count);
    EXPECT_EQ(c.unmatched, 0u);
    for (int w = 0; w < 3; ++w) EXPECT_LE(c.max_error[std::size_t(w)], double(m.codec.words[std::size_t(w)].error));
  }
}

TEST(ParticleCodec, CookIsDeterministicWhateverTheThreads) {
  const fs::path dir = test::fresh_dir();
  format::ParticleCodecOptions o;
  o.keyframe_interval = 8;  // several groups, encoded in parallel with 2 threads
  for (const Fixture& fx : {fixtures()[0], fixtures()[1]}) {
    const fs::path one = cook_with(dir, fx, "one", format::FrameCodec::Particle, o, 1);
    const fs::path two = cook_with(dir, fx, "two", format::FrameCodec::Particle, o, 2);
    EXPECT_EQ(test::read_bytes(one.string()), test::read_bytes(two.string())) << fx.file;
  }
}

TEST(ParticleCodec, AbsoluteBoundAndBoundsThatCannotBeKept) {
  const fs::path dir = test::fresh_dir();
  const Fixture fx{"sims/blender_sparks.abc", "", {}};
  format::ParticleCodecOptions abs;
  abs.error = 0.002;
  abs.error_relative = false;
  const fs::path file = cook_with(dir, fx, "abs", format::FrameCodec::Particle, abs);
  const auto m = format::Reader::open(file).metadata();
  EXPECT_DOUBLE_EQ(m.codec.error, 0.002);
  const auto c = compare_files(file, cook_with(dir, fx, "raw", format::FrameCodec::Records));
  for (int w = 0; w < 3; ++w) EXPECT_LE(c.max_error[std::size_t(w)], 0.002);

  abs.error = 1e-12;  // far below float precision at metre scale
  try {
    cook_with(dir, fx, "tiny", format::FrameCodec::Particle, abs);
    FAIL() << "a bound below float precision was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("cannot be kept"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("lossless"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(dir / "tiny.pstream"));
}

// Packets whose zstd frame is valid but whose body lies: every field the decoder trusts is
// checked, and the error names the file and the frame.
TEST(ParticleCodec, CorruptBodiesGiveClearErrors) {
  const fs::path dir = test::fresh_dir();
  const fs::path file = cook_with(dir, fixtures()[1], "sparks", format::FrameCodec::Particle);
  const auto r = format::Reader::open(file);
  const auto& m = r.metadata();
  ASSERT_FALSE(m.frames[5].keyframe);
  // The bodies of frames 0 to 5: the packets from the keyframe on are one zstd stream.
  std::vector<std::byte> scratch(m.chunk_size);
  std::vector<std::vector<std::byte>> stored(6);
  for (std::uint64_t f = 0; f <= 5; ++f) {
    stored[f].resize(m.frames[f].packet_size);
    r.read_packet(f, stored[f], scratch);
  }
  const std::vector<std::span<const std::byte>> stored_views(stored.begin(), stored.end());
  const std::vector<std::vector<std::byte>> bodies = test::decompress_packets(stored_views, 1 << 22);
  std::vector<std::byte> body = bodies[5];
  // Frames 0 to 4 as they were, and frame 5's body changed, written again as one stream.
  const auto decode_with = [&](const std::vector<std::byte>& changed) -> std::string {
    std::vector<std::span<const std::byte>> changed_bodies(bodies.begin(), bodies.end());
    changed_bodies[5] = changed;
    const auto packets = test::compress_packets(changed_bodies, true, 3);
    format::FrameDecoder d(m, "clip.pstream");
    std::vector<std::byte> out(m.max_count * m.record_size);
    for (std::uint64_t f = 0; f < 5; ++f) d.decode(f, packets[f], out);
    try {
      d.decode(5, packets[5], std::span(out).first(m.frames[5].count * m.record_size));
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  };
  EXPECT_EQ(decode_with(body), "");  // the re-compressed body itself decodes
  const auto poke = [&](std::size_t at, std::uint32_t v) {
    auto b = body;
    std::memcpy(b.data() + at, &v, 4);
    return b;
  };
  // Version 5: position.x's survivors are packed as nibbles. Two more escapes (a byte of two
  // nibbles below 15 made 0xFF, with escape planes a byte wide) need bytes the body does not hold.
  namespace pc = format::particle;
  const auto u32_at = [&](std::size_t at) {
    std::uint32_t v;
    std::memcpy(&v, body.data() + at, 4);
    return v;
  };
  const std::size_t coded = pc::WordPlan(m.codec).coded.size();
  ASSERT_EQ(std::to_integer<int>(body[pc::kBodyHeader + 6]), pc::kNibbles);
  std::size_t nibbles_at = pc::kBodyHeader + coded * pc::kWordHeader + pc::kIdHeader + u32_at(8) * pc::kOpSize;
  std::uint64_t survivors = 0;
  for (std::uint32_t o = 0; o < u32_at(8); ++o)
    survivors += u32_at(pc::kBodyHeader + coded * pc::kWordHeader + pc::kIdHeader + o * pc::kOpSize);
  nibbles_at += std::to_integer<std::size_t>(body[pc::kBodyHeader + 4]) * ((survivors + 1023) / 1024);  // bias
  while ((std::to_integer<unsigned>(body[nibbles_at]) & 15) == 15 ||
         (std::to_integer<unsigned>(body[nibbles_at]) >> 4) == 15)
    ++nibbles_at;
  auto escaped = body;
  escaped[nibbles_at] = std::byte{0xff};
  if (body[pc::kBodyHeader + 1] == std::byte{0}) escaped[pc::kBodyHeader + 1] = std::byte{1};  // escapes of 15 + 0..255
  auto packing = body;
  packing[pc::kBodyHeader + 6] = std::byte{2};
  for (const auto& [changed, fragment] : std::vector<std::pair<std::vector<std::byte>, std::string>>{
           {escaped, "residual planes need"},
           {packing, "keep packing 2"},
           {poke(0, 7), "particles, the frame index says"},
           {poke(4, 1), "but the previous frame has"},
           {poke(8, 0xffffffu), "operations for"},
           {poke(12, 3), "the operations keep"},
           {poke(16, 0x09u), "position.x: predictor 9"},
           {std::vector<std::byte>(body.begin(), body.end() - 1), "residual planes need"},
       }) {
    const std::string e = decode_with(changed);
    EXPECT_NE(e.find("clip.pstream: frame 5"), std::string::npos) << e;
    EXPECT_NE(e.find(fragment), std::string::npos) << e;
  }
  // A packet cut short ends inside a zstd block; one from another stream does not continue this one.
  for (const bool cut : {true, false}) {
    format::FrameDecoder d(m, "clip.pstream");
    std::vector<std::byte> out(m.max_count * m.record_size), p;
    for (std::uint64_t f = 0; f <= 5; ++f) {
      const std::uint64_t from = cut || f != 5 ? f : 7;
      p.resize(m.frames[from].packet_size);
      r.read_packet(from, p, scratch);
      if (f == 5 && cut) p.pop_back();
      if (f < 5) {
        d.decode(f, p, out);
        continue;
      }
      try {
        d.decode(5, p, out);
        ADD_FAILURE() << "frame 5 decoded from a wrong packet";
      } catch (const Error& e) {
        EXPECT_NE(std::string(e.what()).find("clip.pstream: frame 5: particle packet"), std::string::npos) << e.what();
      }
    }
  }
}

// Survivors [0, n) read in random runs of 1 to 40, split at the blocks' borders, as the decoder
// reads them: with four lanes a vector, and with eight compiled for AVX2 (as the decoder does).
struct RunsCase {
  std::uint32_t n, seed, linear;
  std::uint32_t *q0, *d0;
  const std::uint32_t *q1, *d1;
};
template <unsigned Lanes>
[[gnu::always_inline]] inline void read_runs(format::particle::SurvivorRuns& survivors, const RunsCase& c) {
  namespace pc = format::particle;
  std::uint32_t seed = c.seed;
  const unsigned kind = survivors.kind();
  for (std::uint32_t at = 0; at < c.n;) {
    seed = seed * 1664525u + 1013904223u;
    const std::uint32_t len = std::min({1 + (seed >> 8) % 40, c.n - at, pc::kBlock - (at & (pc::kBlock - 1))});
    survivors.run<Lanes>(kind, at, len, c.q0 + at, c.d0 + at, c.q1 + at, c.d1 + at, c.linear);
    at += len;
  }
}
void read_runs_baseline(format::particle::SurvivorRuns& survivors, const RunsCase& c) { read_runs<4>(survivors, c); }
#if defined(__x86_64__)
[[gnu::target("avx2")]] void read_runs_avx2(format::particle::SurvivorRuns& survivors, const RunsCase& c) {
  read_runs<8>(survivors, c);
}
bool have_avx2() { return __builtin_cpu_supports("avx2"); }
#else
void read_runs_avx2(format::particle::SurvivorRuns&, const RunsCase&) {}
bool have_avx2() { return false; }
#endif

// Version 5's nibbles: any values written as nibbles and escape planes predict survivors as the
// values they hold (unzigzagged, plus their block's bias), whatever their count (odd, under one
// 8-value step, many steps, several blocks of 1024, more than the escape count's 127 steps of 16
// bytes), the runs they are read in (short, long, odd starts) and the width of their escapes
// (none, up to 15 + 240 in one plane, past it, two to four bytes); byte planes too, with either
// predictor.
TEST(ParticleCodec, NibblesAndTheirEscapesReadBackAsTheirValues) {
  namespace pc = format::particle;
  std::uint32_t seed = 12345;
  const auto next = [&] { return seed = seed * 1664525u + 1013904223u; };
  const std::uint32_t largest[] = {0, 14, 15, 255, 256, 270, 271, 65535, 65550, 0xffffff, 0xffffffffu};
  for (const std::uint32_t n : {0u, 1u, 2u, 7u, 15u, 16u, 17u, 33u, 1000u, 2500u, 9001u}) {
    for (const std::uint32_t top : largest) {
      std::vector<std::uint32_t> values(n);
      for (std::uint32_t t = 0; t < n; ++t) values[t] = next() % 15;  // mostly nibbles
      for (std::uint32_t t = 0; t < n; t += 3) values[t] = top == 0 ? 0 : next() % top;
      if (n > 0) values[n / 2] = top;
      SCOPED_TRACE(fmt::format("{} values up to {}", n, top));
      std::vector<std::byte> packed;
      const unsigned width = pc::escape_bytes(values);
      pc::write_nibbles(packed, values, width);
      const auto escapes = static_cast<std::uint32_t>(
          std::count_if(values.begin(), values.end(), [](std::uint32_t v) { return v >= pc::kNibbleEscape; }));
      ASSERT_EQ(packed.size(), (n + 1) / 2 + std::size_t(escapes) * width);
      const auto* bytes = reinterpret_cast<const std::uint8_t*>(packed.data());
      ASSERT_EQ(pc::count_escapes(bytes, n), escapes);
      std::vector<std::uint32_t> bias((n + pc::kBlock - 1) / pc::kBlock);
      for (std::uint32_t& b : bias) b = next();
      std::vector<std::uint32_t> q1(n + pc::kRunPad), d1(n + pc::kRunPad);
      for (std::uint32_t t = 0; t < n; ++t) q1[t] = next(), d1[t] = next();
      // In runs of 1 to 40 survivors, split at the blocks' borders, as the decoder reads them.
      const auto check = [&](std::vector<std::byte> residuals, std::uint8_t packing, unsigned width_or_bytes,
                             std::size_t escape_planes_at, std::uint32_t escape_count) {
        residuals.resize(residuals.size() + pc::kReadPad, std::byte{0xAB});  // what a run may read past
        for (const std::uint32_t linear : {0u, ~0u}) {
          std::vector<std::uint32_t> q0(n + pc::kRunPad), d0(n + pc::kRunPad);
          // The same random runs for four lanes a vector and (where the processor has AVX2) eight.
          const std::uint32_t runs_seed = next();
          for (const unsigned lanes : {4u, 8u}) {
            if (lanes == 8 && !have_avx2()) continue;
            std::fill(q0.begin(), q0.end(), 0u);
            std::fill(d0.begin(), d0.end(), 0u);
            pc::SurvivorRuns survivors(residuals.data(), n, packing, width_or_bytes,
                                       residuals.data() + escape_planes_at, escape_count, bias.data());
            (lanes == 4 ? read_runs_baseline : read_runs_avx2)(
                survivors, {n, runs_seed, linear, q0.data(), d0.data(), q1.data(), d1.data()});
            for (std::uint32_t t = 0; t < n; ++t) {
              const std::uint32_t step = (d1[t] & linear) + pc::unzigzag(values[t]) + bias[t >> pc::kBlockShift];
              ASSERT_EQ(d0[t], step) << t << " linear " << linear << " lanes " << lanes;
              ASSERT_EQ(q0[t], q1[t] + step) << t << " linear " << linear << " lanes " << lanes;
            }
          }
        }
      };
      check(packed, pc::kNibbles, width, (n + 1) / 2, escapes);
      // The same values as byte planes.
      std::vector<std::byte> planes;
      const unsigned plane_bytes = pc::bytes_for(n == 0 ? 0u : *std::max_element(values.begin(), values.end()));
      pc::write_planes(planes, values, plane_bytes);
      check(planes, pc::kBytePlanes, plane_bytes, 0, 0);
    }
  }
}

// The derived velocity's step states of a run of survivors, 16 at a time: each particle's is
// after_step() of its state before, whatever the run's length (the last 16 are made whole).
TEST(ParticleCodec, StepStatesOfARunAreEachAfterStep) {
  namespace pc = format::particle;
  std::uint32_t seed = 99;
  const auto next = [&] { return seed = seed * 1664525u + 1013904223u; };
  for (const std::uint32_t n : {0u, 1u, 15u, 16u, 17u, 33u, 200u}) {
    std::vector<std::uint8_t> before(n + pc::kStepPad), out(n + pc::kStepPad, 0xEE);
    for (std::uint32_t t = 0; t < n; ++t) before[t] = static_cast<std::uint8_t>(next() % 5);  // kNoStep..kAfterSeed
    pc::after_steps(out.data(), before.data(), n);
    for (std::uint32_t t = 0; t < n; ++t) ASSERT_EQ(out[t], pc::after_step(before[t])) << n << " " << t;
  }
}

TEST(ParticleCodec, VersionOneFilesStillRead) {
  // Cooked by the version 1 writer (before the particle codec), kept as it was.
  const auto r = format::Reader::open(test::data_path("pstream_v1/points_varying_lz4.pstream"));
  const auto& m = r.metadata();
  EXPECT_EQ(m.version, 1u);
  EXPECT_EQ(m.codec.codec, format::FrameCodec::Records);
  const fs::path dir = test::fresh_dir();
  // The version 1 writer kept the source's order.
  const fs::path now = cook_with(dir, fixtures()[3], "v2", format::FrameCodec::Records, {}, 0, true);
  const auto r2 = format::Reader::open(now);
  ASSERT_EQ(m.frame_count(), r2.metadata().frame_count());
  std::vector<std::byte> a(m.max_count * m.record_size), b(a.size());
  for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
    r.read_frame(f, a);
    r2.read_frame(f, b);
    ASSERT_EQ(std::memcmp(a.data(), b.data(), m.frames[f].count * m.record_size), 0) << f;
  }
}

}  // namespace

namespace {

// The tools around the codec, through the CLI: verify --against passes within the bound and fails
// against another source; export writes PLY and Alembic that cook back to the decoded values.
// Sizes that span 100x in a scene 40 units across: each particle's scale within 1 % of its own
// (an absolute bound of 1e-4 of the diagonal, 4 mm here, would turn the smallest into a few
// values), and no two scales that differ by more than twice the bound decode to the same value.
// The metadata a decoder needs for frames encoded in memory: the layout, the coding, and each
// frame's count, keyframe flag and packet size.
format::Metadata metadata_for(const std::vector<format::Attribute>& layout, const format::CodecInfo& info,
                              const std::vector<format::EncodedFrame>& encoded) {
  format::Metadata meta;
  meta.layout = layout;
  meta.record_size = format::record_size_of(layout);
  meta.fps = 24;
  meta.codec = info;
  for (const auto& e : encoded) {
    format::FrameEntry entry;
    entry.count = e.count;
    entry.keyframe = e.keyframe;
    entry.packet_size = e.packet.size();
    meta.frames.push_back(entry);
    meta.max_count = std::max(meta.max_count, e.count);
  }
  return meta;
}

// A generated clip of `count` particles with ids 0..count-1 over `frames` frames, `[x y z scale]`
// from `fill(frame, particle, record)`, and the stats a cook would gather.
struct GeneratedClip {
  std::vector<format::Attribute> layout;
  std::uint32_t rs = 0, count = 0;
  std::vector<std::vector<std::byte>> records;
  std::vector<std::vector<std::uint64_t>> ids;
  format::ClipStats stats;
  template <class Fill>
  GeneratedClip(std::uint32_t n, std::uint32_t frames, const Fill& fill)
      : layout(with_id(format::default_layout())),
        rs(format::record_size_of(layout)),
        count(n),
        records(frames, std::vector<std::byte>(std::size_t(n) * rs)),
        ids(frames, std::vector<std::uint64_t>(n)),
        stats(layout) {
    for (std::uint32_t f = 0; f < frames; ++f) {
      for (std::uint32_t i = 0; i < n; ++i) {
        float r[4];
        fill(f, i, r);
        std::memcpy(records[f].data() + std::size_t(i) * rs, r, 16);
        const std::uint64_t id = i;
        std::memcpy(records[f].data() + std::size_t(i) * rs + 16, &id, 8);
        ids[f][i] = id;
      }
      stats.add(records[f], n);
    }
  }
  std::vector<format::SourceFrame> source_frames() const {
    std::vector<format::SourceFrame> frames;
    for (std::size_t f = 0; f < records.size(); ++f) frames.push_back({records[f], ids[f], count});
    return frames;
  }
  static std::vector<format::Attribute> with_id(std::vector<format::Attribute> layout) {
    format::append_attribute(layout, "id", format::AttributeType::Uint64, 1);
    return layout;
  }
};

// A frame whose records take 1 MiB or more is written with stores that bypass the caches, whole
// cache lines at a time (a record of two 16-byte groups, a few particles at a time), where the
// output allows it (16-byte records or multiples, 16-byte aligned). Frames of 70,003 particles, as
// 16- and 32-byte records: the same bytes when decoded into an aligned buffer and into one that is
// not (ordinary stores), with AVX2 and with SSE2, every value where the source has it.
TEST(ParticleCodec, LargeFramesDecodeTheSameBitsWhereverTheyAreWritten) {
  constexpr std::uint32_t kCount = 70003, kFrames = 3;
  for (const bool wide : {false, true}) {
    SCOPED_TRACE(wide ? "32-byte records" : "16-byte records");
    std::vector<format::Attribute> layout = format::default_layout();
    if (wide) format::append_attribute(layout, "extra", format::AttributeType::Float32, 4);
    const std::uint32_t rs = format::record_size_of(layout);
    ASSERT_EQ(rs, wide ? 32u : 16u);
    ASSERT_GE(std::uint64_t(kCount) * rs, std::uint64_t(1) << 20);
    std::vector<std::vector<float>> records(kFrames, std::vector<float>(std::size_t(kCount) * rs / 4));
    std::vector<std::uint64_t> ids(kCount);
    format::ClipStats stats(layout);
    for (std::uint32_t f = 0; f < kFrames; ++f) {
      for (std::uint32_t i = 0; i < kCount; ++i) {
        float* r = records[f].data() + std::size_t(i) * rs / 4;
        r[0] = float(i % 41) * 0.1f + 0.02f * float(f);
        r[1] = float(i / 41 % 41) * 0.1f - 0.01f * float(f * f);
        r[2] = float(i / 1681) * 0.1f;
        r[3] = 0.01f + 0.001f * float(i % 7);
        for (std::uint32_t x = 4; x < rs / 4; ++x) r[x] = float((i * 31 + x * 7 + f) % 100) * 0.01f;
        ids[i] = i;
      }
      stats.add(std::as_bytes(std::span(records[f])), kCount);
    }
    std::vector<format::SourceFrame> frames;
    for (const auto& r : records) frames.push_back({std::as_bytes(std::span(r)), ids, kCount});
    const format::CodecInfo info = format::plan_particle_codec(layout, stats, 24.0, true, {});
    const auto encoded = format::encode_group(info, frames, {}, 0);
    const format::Metadata meta = metadata_for(layout, info, encoded);
    const float step = info.words[0].step;
    for (const bool baseline : {false, true}) {
      if (baseline && format::particle_decoder_simd() != "AVX2") continue;
      SCOPED_TRACE(baseline ? "SSE2" : format::particle_decoder_simd());
      if (baseline) ::setenv("PSTREAM_SIMD", "baseline", 1);
      format::FrameDecoder aligned_decoder(meta, "generated"), offset_decoder(meta, "generated");
      ::unsetenv("PSTREAM_SIMD");
      std::vector<std::byte> buffer(std::size_t(kCount) * rs + 128), other(buffer.size());
      const auto at = [](std::vector<std::byte>& b, std::size_t off) {
        const std::size_t pad = (64 - reinterpret_cast<std::uintptr_t>(b.data()) % 64) % 64;
        return std::span(b.data() + pad + off, std::size_t(kCount) * 32);
      };
      const std::span<std::byte> aligned = at(buffer, 0), offset = at(other, 4);
      for (std::uint32_t f = 0; f < kFrames; ++f) {
        aligned_decoder.decode(f, encoded[f].packet, aligned);
        offset_decoder.decode(f, encoded[f].packet, offset);
        const std::size_t bytes = std::size_t(kCount) * rs;
        ASSERT_EQ(std::memcmp(aligned.data(), offset.data(), bytes), 0) << "frame " << f;
        double worst = 0.0;
        for (std::uint32_t i = 0; i < kCount; ++i) {
          float dec[4];
          std::memcpy(dec, aligned.data() + std::size_t(i) * rs, 16);
          const float* src = records[f].data() + std::size_t(i) * rs / 4;
          for (int x = 0; x < 3; ++x) worst = std::max(worst, std::abs(double(dec[x]) - double(src[x])));
          ASSERT_NEAR(dec[3], src[3], 0.01 * src[3]) << "frame " << f << ", particle " << i;
        }
        EXPECT_LE(worst, 0.5 * step * 1.001) << "frame " << f;
      }
    }
  }
}

// A large frame without ids (its survivors first, in the previous frame's order, then the new
// particles) is predicted with AVX2 in one pass over the previous particles, eight at a time, the
// survivors moved into the lowest lanes; SSE2 walks the runs between deaths. A generated liquid
// of 60,000 particles a frame: an eighth die and as many are born each frame, the survivors move
// along x at their own speed (a step the linear predictor follows), jitter along y and now and then
// jump (residuals past a nibble). Both decode the same bits, and every particle is within its bound
// of the source.
TEST(ParticleCodec, LargeFramesWithoutIdsDecodeTheSameBitsWithAVX2AndBaseline) {
  if (format::particle_decoder_simd() != "AVX2") GTEST_SKIP() << "this processor has no AVX2";
  constexpr std::uint32_t kCount = 60000, kFrames = 6;
  const std::vector<format::Attribute> layout = format::default_layout();  // x y z scale
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> place(0.0f, 1.0f), speed(0.0005f, 0.002f), jitter(-0.0006f, 0.0006f);
  std::uniform_int_distribution<std::uint32_t> pick(0, 63);
  struct Particle {
    float x, y, z, vx;
  };
  std::vector<Particle> live(kCount);
  for (Particle& p : live) p = {place(rng), place(rng), place(rng), speed(rng)};
  std::vector<std::vector<float>> records(kFrames);
  format::ClipStats stats(layout);
  for (std::uint32_t f = 0; f < kFrames; ++f) {
    if (f > 0) {
      std::vector<Particle> next;
      for (const Particle& p : live) {
        if (pick(rng) < 8) continue;  // an eighth die
        const float jump = pick(rng) == 0 ? 0.01f : 0.0f;
        next.push_back({p.x + p.vx, p.y + jitter(rng) + jump, p.z, p.vx});
      }
      while (next.size() < kCount) next.push_back({place(rng), place(rng), place(rng), speed(rng)});
      std::shuffle(next.begin(), next.end(), rng);  // a source without ids keeps no order
      live = std::move(next);
    }
    for (const Particle& p : live) records[f].insert(records[f].end(), {p.x, p.y, p.z, 0.004f});
    stats.add(std::as_bytes(std::span(records[f])), kCount);
  }
  std::vector<format::SourceFrame> frames;
  for (const auto& r : records) frames.push_back({std::as_bytes(std::span(r)), {}, kCount});
  const format::CodecInfo info = format::plan_particle_codec(layout, stats, 24.0, false, {});
  ASSERT_EQ(info.order, format::FrameOrder::Matched);
  const auto encoded = format::encode_group(info, frames, {}, 0);
  const format::Metadata meta = metadata_for(layout, info, encoded);
  std::uint64_t predicted = 0;
  for (std::uint32_t f = 1; f < kFrames; ++f) predicted += encoded[f].matched;
  EXPECT_GT(predicted, (kFrames - 1) * kCount * 3 / 4) << "most particles are survivors";
  const auto decode = [&](bool baseline) {
    if (baseline) ::setenv("PSTREAM_SIMD", "baseline", 1);
    format::FrameDecoder decoder(meta, "generated");
    ::unsetenv("PSTREAM_SIMD");
    std::vector<std::byte> all, frame(std::size_t(kCount) * 16);
    for (std::uint32_t f = 0; f < kFrames; ++f) {
      decoder.decode(f, encoded[f].packet, frame);
      all.insert(all.end(), frame.begin(), frame.end());
    }
    return all;
  };
  const std::vector<std::byte> avx2 = decode(false), baseline = decode(true);
  ASSERT_EQ(avx2.size(), baseline.size());
  for (std::uint32_t f = 0; f < kFrames; ++f) {
    const std::size_t at = std::size_t(f) * kCount * 16;
    ASSERT_EQ(std::memcmp(avx2.data() + at, baseline.data() + at, std::size_t(kCount) * 16), 0) << "frame " << f;
    format::FrameComparison c;
    c.add(layout, std::span(avx2).subspan(at, std::size_t(kCount) * 16), kCount, std::as_bytes(std::span(records[f])),
          kCount, &info);
    EXPECT_EQ(c.unmatched, 0u) << "frame " << f;
    for (int a = 0; a < 3; ++a)
      EXPECT_LE(c.max_error[std::size_t(a)], info.words[std::size_t(a)].error) << "frame " << f;
  }
}

TEST(ParticleCodec, ScalesSpanning100xKeepTheirRelativeBound) {
  constexpr std::uint32_t kCount = 4000, kFrames = 6;
  const GeneratedClip clip(kCount, kFrames, [](std::uint32_t f, std::uint32_t i, float* r) {
    const double u = double((i * 2654435761u) % kCount) / kCount;
    r[0] = float(20 * std::sin(i * 0.37) + f * 0.05);
    r[1] = float(20 * std::cos(i * 0.11));
    r[2] = float(20 * std::sin(i * 0.73 + 1));
    r[3] = float(0.002 * std::pow(100.0, u) * (1.0 + 0.01 * f));  // 2 mm to 20 cm, growing
  });
  const auto& layout = clip.layout;
  const auto& records = clip.records;
  const std::uint32_t rs = clip.rs;
  const format::CodecInfo info = format::plan_particle_codec(layout, clip.stats, 24.0, true, {});
  ASSERT_EQ(info.words[3].coding, format::WordCoding::Relative);
  const auto encoded = format::encode_group(info, clip.source_frames(), {}, 0);
  const format::Metadata meta = metadata_for(layout, info, encoded);
  format::FrameDecoder decoder(meta, "generated");
  std::vector<std::byte> out(kCount * rs);
  double worst = 0.0;
  for (std::uint32_t f = 0; f < kFrames; ++f) {
    decoder.decode(f, encoded[f].packet, out);
    std::vector<std::pair<float, float>> scales;  // (source, decoded), by id (the frame is in id order)
    for (std::uint32_t i = 0; i < kCount; ++i) {
      float src, dec;
      std::memcpy(&src, records[f].data() + std::size_t(i) * rs + 12, 4);
      std::memcpy(&dec, out.data() + std::size_t(i) * rs + 12, 4);
      worst = std::max(worst, std::abs(double(dec) - double(src)) / double(src));
      scales.push_back({src, dec});
    }
    // Sorted by the source: a scale more than twice the bound above another (1.01 / 0.99) decodes
    // above it, so sizes that far apart never merge or swap; nearer ones may, each within its own
    // bound (the encoder takes, of the codes within it, the one its prediction gives). There are
    // at least as many distinct decoded scales as runs of the source 2 % long.
    std::sort(scales.begin(), scales.end());
    float run_start = scales[0].first, most_below = -INFINITY;  // decoded, of those far enough below
    std::size_t clusters = 1, behind = 0;
    std::set<float> distinct;
    for (std::size_t k = 0; k < scales.size(); ++k) {
      while (behind < k && double(scales[behind].first) * 1.01 / 0.99 < double(scales[k].first))
        most_below = std::max(most_below, scales[behind++].second);
      ASSERT_GT(scales[k].second, most_below) << "frame " << f << ", scale " << scales[k].first;
      distinct.insert(scales[k].second);
      if (double(scales[k].first) > double(run_start) * (1 + 2 * 0.01)) ++clusters, run_start = scales[k].first;
    }
    EXPECT_GE(distinct.size(), clusters) << "frame " << f;
    EXPECT_GT(distinct.size(), 200u);  // 100x spans 230 steps of 2 %
  }
  EXPECT_LE(worst, 0.01);
  EXPECT_GT(worst, 0.001);  // a lossy bound, not an exact copy
  std::printf("scales spanning 100x: worst relative error %.4f%% (bound 1%%)\n", 100 * worst);
}

// A stored velocity is quantised within 4 × the position bound × fps where that is finer than its
// range's fraction: the Hermite curve between two frames weights its tangents (velocity × the
// frame's time h) by t(1 - t)² and t²(1 - t), which sum to at most 1/4, so the velocities' errors
// move it by at most the position bound. Fast particles in a small box, where this rule binds:
// every curve between frames, drawn through the decoded positions, stays within the position
// bound of the same curve through the source's velocities, and within twice it of the source's.
TEST(ParticleCodec, AStoredVelocityMovesTheCurvesBetweenFramesByAtMostThePositionBound) {
  constexpr std::uint32_t kCount = 2000, kFrames = 5;
  constexpr double kFps = 24.0;
  std::vector<format::Attribute> layout = format::default_layout();
  format::append_attribute(layout, "velocity", format::AttributeType::Float32, 3);
  format::append_attribute(layout, "id", format::AttributeType::Uint64, 1);
  const std::uint32_t rs = format::record_size_of(layout);
  ASSERT_EQ(rs, 36u);
  std::vector<std::vector<std::byte>> records(kFrames, std::vector<std::byte>(std::size_t(kCount) * rs));
  std::vector<std::vector<std::uint64_t>> ids(kFrames, std::vector<std::uint64_t>(kCount));
  format::ClipStats stats(layout);
  for (std::uint32_t f = 0; f < kFrames; ++f) {
    for (std::uint32_t i = 0; i < kCount; ++i) {
      const double t = f / kFps;
      const float r[7] = {float(0.5 * std::sin(i * 0.37) + 0.3 * t), float(0.5 * std::cos(i * 0.11) - 0.2 * t),
                          float(0.5 * std::sin(i * 0.73 + 1)),       0.01f,
                          float(40 * std::sin(i * 0.29 + f)),        float(40 * std::cos(i * 0.53 - f)),
                          float(40 * std::sin(i * 0.91 + 2 * f))};
      std::memcpy(records[f].data() + std::size_t(i) * rs, r, sizeof r);
      const std::uint64_t id = i;
      std::memcpy(records[f].data() + std::size_t(i) * rs + 28, &id, 8);
      ids[f][i] = id;
    }
    stats.add(records[f], kCount);
  }
  format::ParticleCodecOptions options;
  options.derive_velocity = false;
  const format::CodecInfo info = format::plan_particle_codec(layout, stats, kFps, true, options);
  const double e = info.error;
  ASSERT_GT(e, 0.0);
  for (std::uint32_t w = 4; w < 7; ++w) {
    ASSERT_EQ(info.words[w].coding, format::WordCoding::Quantized) << "word " << w;
    // 4 e fps binds here (1e-3 of an 80 m/s range is 0.08 m/s); not the stricter e fps.
    EXPECT_LE(double(info.words[w].error), 4 * e * kFps * (1 + 1e-6)) << "word " << w;
    EXPECT_GT(double(info.words[w].error), 2 * e * kFps) << "word " << w;
  }
  std::vector<format::SourceFrame> frames;
  for (std::uint32_t f = 0; f < kFrames; ++f) frames.push_back({records[f], ids[f], kCount});
  const auto encoded = format::encode_group(info, frames, {}, 0);
  const format::Metadata meta = metadata_for(layout, info, encoded);
  format::FrameDecoder decoder(meta, "fast");
  std::vector<std::vector<std::byte>> decoded(kFrames, std::vector<std::byte>(std::size_t(kCount) * rs));
  for (std::uint32_t f = 0; f < kFrames; ++f) decoder.decode(f, encoded[f].packet, decoded[f]);
  const auto value = [&](const std::vector<std::byte>& frame, std::uint32_t i, int word) {
    float v;
    std::memcpy(&v, frame.data() + std::size_t(i) * rs + 4 * std::size_t(word), 4);
    return double(v);
  };
  const double h = 1.0 / kFps;
  // The cubic Hermite curve at t through positions q0, q1 with tangents t0, t1 (in double).
  const auto curve = [](double t, double q0, double q1, double t0, double t1) {
    return (2 * t * t * t - 3 * t * t + 1) * q0 + (t * t * t - 2 * t * t + t) * t0 + (-2 * t * t * t + 3 * t * t) * q1 +
           (t * t * t - t * t) * t1;
  };
  double worst_velocity = 0, worst_source = 0, worst_velocity_error = 0;
  for (std::uint32_t f = 0; f + 1 < kFrames; ++f) {
    for (std::uint32_t i = 0; i < kCount; ++i) {
      for (int a = 0; a < 3; ++a) {
        const double p0 = value(decoded[f], i, a), p1 = value(decoded[f + 1], i, a);
        const double m0 = h * value(decoded[f], i, 4 + a), m1 = h * value(decoded[f + 1], i, 4 + a);
        const double s0 = value(records[f], i, a), s1 = value(records[f + 1], i, a);
        const double n0 = h * value(records[f], i, 4 + a), n1 = h * value(records[f + 1], i, 4 + a);
        worst_velocity_error = std::max(worst_velocity_error, std::abs(m0 - n0) / h);
        for (int k = 1; k < 8; ++k) {
          const double t = k / 8.0, ours = curve(t, p0, p1, m0, m1);
          worst_velocity = std::max(worst_velocity, std::abs(ours - curve(t, p0, p1, n0, n1)));
          worst_source = std::max(worst_source, std::abs(ours - curve(t, s0, s1, n0, n1)));
        }
      }
    }
  }
  EXPECT_LE(worst_velocity, e * (1 + 1e-6));
  EXPECT_LE(worst_source, 2 * e * (1 + 1e-6));
  EXPECT_GT(worst_velocity_error, e * kFps);  // the velocity is coarser than the old e × fps rule
  std::printf(
      "fast particles: velocity error up to %.4g m/s (4 e fps = %.4g), curves moved %.3g e by it, %.3g e from "
      "the source's\n",
      worst_velocity_error, 4 * e * kFps, worst_velocity / e, worst_source / e);
}

// A Relative word is coded in the loop: of the codes within the bound (the plan's grid is two bits
// finer than the bound needs, so about five), the encoder takes the one its prediction gives.
// Sizes that shrink over each particle's life, as a fountain's do, then cost far less than on the
// coarsest grid that keeps the bound, and every value stays within it.
TEST(ParticleCodec, ScalesThatChangeOverLifeAreCodedInTheLoop) {
  constexpr std::uint32_t kCount = 3000, kFrames = 40;
  const auto sizes = [](bool change) {
    return [change](std::uint32_t f, std::uint32_t i, float* r) {
      // Each its own size and life (so the grid's rounding falls differently for each).
      const double u = double((i * 2654435761u) % 65536) / 65536.0, v = double((i * 40503u) % 65536) / 65536.0;
      const double life = 60.0 + 60.0 * v;  // frames
      r[0] = float(i % 50) * 0.1f + 0.01f * float(f);
      r[1] = float(i / 50) * 0.1f;
      r[2] = 1.0f;
      r[3] = float((0.02 + 0.06 * u) * (1.0 - (change ? 0.6 * double(f) / life : 0.0)));  // shrinks along its life
    };
  };
  const GeneratedClip clip(kCount, kFrames, sizes(true));
  // The same clip with each particle's first size throughout: what the positions and ids cost.
  const GeneratedClip constant(kCount, kFrames, sizes(false));
  const auto& layout = clip.layout;
  const auto& records = clip.records;
  const std::uint32_t rs = clip.rs;
  const auto& stats = clip.stats;
  const std::vector<format::SourceFrame> frames = clip.source_frames(), constant_frames = constant.source_frames();
  const format::CodecInfo planned = format::plan_particle_codec(layout, stats, 24.0, true, {});
  ASSERT_EQ(planned.words[3].coding, format::WordCoding::Relative);
  EXPECT_EQ(planned.words[3].base, format::relative_shift_for(0.01) - 2);  // two bits finer
  format::CodecInfo coarsest = planned;
  coarsest.words[3].base = format::relative_shift_for(0.01);
  const auto bytes_and_worst = [&](const format::CodecInfo& info) {
    const auto encoded = format::encode_group(info, frames, {}, 0);
    const format::Metadata meta = metadata_for(layout, info, encoded);
    format::FrameDecoder decoder(meta, "generated");
    std::vector<std::byte> out(kCount * rs);
    std::size_t bytes = 0;
    double worst = 0.0;
    for (std::uint32_t f = 0; f < kFrames; ++f) {
      bytes += encoded[f].packet.size();
      decoder.decode(f, encoded[f].packet, out);
      for (std::uint32_t i = 0; i < kCount; ++i) {
        float src, dec;
        std::memcpy(&src, records[f].data() + std::size_t(i) * rs + 12, 4);
        std::memcpy(&dec, out.data() + std::size_t(i) * rs + 12, 4);
        worst = std::max(worst, std::abs(double(dec) - double(src)) / double(src));
      }
    }
    return std::pair{bytes, worst};
  };
  const auto [fine, fine_worst] = bytes_and_worst(planned);
  const auto [coarse, coarse_worst] = bytes_and_worst(coarsest);
  std::size_t base = 0;
  for (const format::EncodedFrame& e : format::encode_group(planned, constant_frames, {}, 0)) base += e.packet.size();
  EXPECT_LE(fine_worst, 0.01);
  EXPECT_LE(coarse_worst, 0.01);
  ASSERT_GT(coarse, base);
  // What the changing sizes cost: on the finer grid two thirds of the coarsest's (0.66 here; the
  // demo fountain's 1.5 MB against 2.65 open-loop; the coarsest grid is coded in the loop too,
  // with less choice).
  const double fine_cost = double(fine) - double(base), coarse_cost = double(coarse) - double(base);
  EXPECT_LT(fine_cost, 0.8 * coarse_cost) << fine << " and " << coarse << " bytes, " << base << " without";
  std::printf("shrinking sizes cost %.0f bytes on the finer grid, %.0f on the coarsest (worst %.3f%%, %.3f%%)\n",
              fine_cost, coarse_cost, 100 * fine_worst, 100 * coarse_worst);
}

// Two frames of a jittered lattice of side^3 particles, spacing 1, each within 0.2 of its node;
// `move(i, jitter)` gives particle i's move along each axis into the second frame, which lists the
// particles in another order (particle i at position (i * 389) % count). [x y z scale] records.
struct LatticePair {
  std::uint32_t count;
  std::vector<format::Attribute> layout = format::default_layout();
  std::uint32_t rs = format::record_size_of(layout);
  std::vector<std::array<float, 3>> where[2];
  std::vector<std::vector<std::byte>> records;
  format::ClipStats stats{layout};

  template <class Move>
  LatticePair(std::uint32_t side, std::uint32_t seed, const Move& move,
              const std::function<void(std::vector<std::array<float, 3>>*)>& adjust = {})
      : count(side * side * side) {
    const auto jitter = [&](double most) {
      seed = seed * 1664525u + 1013904223u;
      return most * (double(seed >> 8) / double(1u << 24) * 2 - 1);
    };
    for (std::uint32_t i = 0; i < count; ++i) {
      const std::uint32_t c[3] = {i % side, i / side % side, i / (side * side)};
      std::array<float, 3> p{}, q{};
      for (int a = 0; a < 3; ++a) {
        p[std::size_t(a)] = float(c[a] + jitter(0.2));  // neighbours at least 0.6 apart
        q[std::size_t(a)] = float(p[std::size_t(a)] + move(i, jitter));
      }
      where[0].push_back(p);
      where[1].push_back(q);
    }
    if (adjust) adjust(where);
    std::vector<std::uint32_t> source_of(count);
    for (std::uint32_t i = 0; i < count; ++i) source_of[(i * 389) % count] = i;
    records.assign(2, std::vector<std::byte>(std::size_t(count) * rs));
    for (int f = 0; f < 2; ++f) {
      for (std::uint32_t t = 0; t < count; ++t) {
        const std::uint32_t i = f == 0 ? t : source_of[t];
        const float r[4] = {where[f][i][0], where[f][i][1], where[f][i][2], 0.05f};
        std::memcpy(records[std::size_t(f)].data() + std::size_t(t) * rs, r, 16);
      }
      stats.add(records[std::size_t(f)], count);
    }
  }

  // The particle a decoded record of frame f is: the nearest source position (the lowest index
  // where particles share one; errors are far below 0.3).
  std::uint32_t particle_at(int f, const std::byte* record) const {
    float r[3];
    std::memcpy(r, record, 12);
    std::uint32_t nearest = 0;
    double best = 1e30;
    for (std::uint32_t i = 0; i < count; ++i) {
      double d = 0;
      for (int a = 0; a < 3; ++a)
        d += (double(r[a]) - where[f][i][std::size_t(a)]) * (double(r[a]) - where[f][i][std::size_t(a)]);
      if (d < best) best = d, nearest = i;
    }
    EXPECT_LT(best, 0.01);
    return nearest;
  }

  // Encodes both frames with `info`, decodes them, and calls visit(previous record, record) for
  // each pair the second frame's operations keep; returns how many pairs there were.
  std::uint32_t pairs(const format::CodecInfo& info,
                      const std::function<void(const std::byte*, const std::byte*)>& visit) const {
    std::vector<format::SourceFrame> frames;
    for (int f = 0; f < 2; ++f) frames.push_back({records[std::size_t(f)], {}, count});
    const auto encoded = format::encode_group(info, frames, {}, 0);
    EXPECT_EQ(encoded[1].matched, count);
    const format::Metadata meta = metadata_for(layout, info, encoded);
    format::FrameDecoder decoder(meta, "lattice");
    std::vector<std::byte> before(std::size_t(count) * rs), after(std::size_t(count) * rs);
    std::vector<format::MatchRun> runs(2 * std::size_t(count) + 1);
    decoder.decode(0, encoded[0].packet, before);
    const std::size_t n = decoder.decode(1, encoded[1].packet, after, runs);
    EXPECT_NE(n, format::kNoMatching);
    if (n == format::kNoMatching) return 0;
    std::uint32_t i = 0, j = 0, kept = 0;
    for (std::size_t r = 0; r < n; ++r) {
      for (std::uint32_t t = 0; t < runs[r].keep; ++t, ++i, ++j, ++kept)
        visit(before.data() + std::size_t(i) * rs, after.data() + std::size_t(j) * rs);
      i += runs[r].drop;
      j += runs[r].insert;
    }
    return kept;
  }
};

// Without ids the encoder pairs particles closest first among each one's 6 nearest. On a jittered
// lattice whose particles each move a tenth of the spacing, written in another order in the second
// frame, every particle is paired with itself: at the default bound (cells of side `cell` few
// enough for the indexed search, and `cell` below 2048 grid steps) and at an absolute bound fine
// enough that `cell` is 5000 grid steps (the general search).
TEST(ParticleCodec, WithoutIdsEachParticlePairsWithItselfAfterASmallMove) {
  const LatticePair clip(10, 7, [](std::uint32_t, const auto& jitter) { return jitter(0.1); });
  for (const double bound : {-1.0, 1e-4}) {  // the default; an absolute 0.1 mm
    SCOPED_TRACE(bound < 0 ? "default bound" : "absolute bound 1e-4");
    format::ParticleCodecOptions options;
    if (bound > 0) options.error = bound, options.error_relative = false;
    const format::CodecInfo info = format::plan_particle_codec(clip.layout, clip.stats, 24.0, false, options);
    ASSERT_EQ(info.order, format::FrameOrder::Matched);
    std::uint32_t wrong = 0;
    const std::uint32_t pairs = clip.pairs(info, [&](const std::byte* a, const std::byte* b) {
      wrong += clip.particle_at(0, a) != clip.particle_at(1, b);
    });
    EXPECT_EQ(pairs, clip.count);
    EXPECT_EQ(wrong, 0u);
  }
}

// Without ids, a particle that stays exactly where it was (a FLIP inflow re-seeds its particles
// in the same places) is paired with itself without a search, and decodes to the same bits in both
// frames; a second particle at the same place is searched and paired too. On a jittered lattice
// whose even particles stay put and odd ones move a tenth of the spacing, with particles 0 and 1
// at one place in both frames, written in another order in the second frame, every particle is
// paired with itself.
TEST(ParticleCodec, WithoutIdsParticlesThatStayPutPairWithThemselves) {
  const LatticePair clip(
      12, 11, [](std::uint32_t i, const auto& jitter) { return i % 2 == 0 ? 0.0 : jitter(0.1); },
      [](std::vector<std::array<float, 3>>* where) {
        for (int f = 0; f < 2; ++f) where[f][1] = where[f][0];
      });
  const format::CodecInfo info = format::plan_particle_codec(clip.layout, clip.stats, 24.0, false, {});
  ASSERT_EQ(info.order, format::FrameOrder::Matched);
  std::uint32_t wrong = 0, still = 0, same_bits = 0;
  const std::uint32_t pairs = clip.pairs(info, [&](const std::byte* a, const std::byte* b) {
    const std::uint32_t was = clip.particle_at(0, a);
    wrong += was != clip.particle_at(1, b);
    if (was % 2 == 0) {
      ++still;
      same_bits += std::memcmp(a, b, 12) == 0;
    }
  });
  EXPECT_EQ(pairs, clip.count);
  EXPECT_EQ(wrong, 0u);
  EXPECT_EQ(still, clip.count / 2 + 1);  // the even ones, and particle 1 at particle 0's place
  EXPECT_EQ(same_bits, still);
}

// The zstd stream's saved state (EntropyDecoder::save_stream): a packet decoded after the state
// was put back comes out as it did the first time, again and again, with the window, repeat
// offsets and entropy tables of the packets before it; without the saved bytes the stream is
// closed, and the next packet is refused rather than decoded against a stale window.
TEST(ParticleCodec, TheZstdStreamsSavedStateContinuesItExactly) {
  std::mt19937 rng(5);
  std::vector<std::vector<std::byte>> bodies(4);
  for (std::size_t k = 0; k < bodies.size(); ++k) {  // repetitive across packets: matches reach back
    bodies[k].resize(200000);
    for (std::size_t i = 0; i < bodies[k].size(); ++i) bodies[k][i] = std::byte(((i * 7) % 251) ^ (rng() % 4) ^ k);
  }
  const std::vector<std::span<const std::byte>> spans(bodies.begin(), bodies.end());
  const auto packets = test::compress_packets(spans, true, 3);
  format::EntropyDecoder d(format::particle::kStreamWindowLog);
  ASSERT_TRUE(format::EntropyDecoder::can_save_stream());
  ASSERT_GT(d.saved_stream_bytes(), std::uint64_t{1} << format::particle::kStreamWindowLog);
  std::vector<std::byte> out(300000), saved(d.saved_stream_bytes());
  std::string why;
  for (std::size_t k = 0; k < 2; ++k) {
    ASSERT_EQ(d.zstd_stream(out, packets[k], k == 0, why), bodies[k].size()) << why;
  }
  ASSERT_TRUE(d.save_stream(saved));
  for (int pass = 0; pass < 3; ++pass) {
    d.restore_stream(saved);
    for (std::size_t k = 2; k < bodies.size(); ++k) {
      ASSERT_EQ(d.zstd_stream(out, packets[k], false, why), bodies[k].size()) << why;
      ASSERT_TRUE(std::equal(bodies[k].begin(), bodies[k].end(), out.begin())) << "pass " << pass << " packet " << k;
    }
  }
  d.restore_stream({});
  EXPECT_EQ(d.zstd_stream(out, packets[2], false, why), format::EntropyDecoder::kFailed);
  EXPECT_NE(why.find("not decoded just before"), std::string::npos) << why;
}

// Saved states (FrameDecoder's `saved_states`, for reverse play): going back through every frame
// of a clip, last to first, each decoded from resume_frame() on (a saved state restored, its zstd
// stream included), gives the same records and the same matching, bit for bit, as one forward pass,
// for every codec layout the fixtures give and every format version with a particle codec. And it
// decodes far fewer frames than starting each one at its keyframe.
// Keyframes link their particles to the frame before (format version 6, id order): the matching
// a keyframe gives is the one its ids give, exactly, in a clip that keeps the ids and in a default
// cook that keeps none (whose export then keeps every particle's id across the keyframes); a
// version 5 clip's keyframes give none, as before.
TEST(ParticleCodec, KeyframesLinkTheirParticlesToTheFrameBefore) {
  const fs::path dir = test::fresh_dir();
  const std::string sparks = test::data_path("sims/blender_sparks.abc");
  const auto runs_of = [](const format::Reader& reader, std::uint64_t f, std::vector<std::byte>& out) {
    std::vector<format::MatchRun> runs(2 * reader.metadata().max_count + 1);
    const std::size_t n = reader.read_frame(f, out, runs);
    return n == format::kNoMatching ? std::vector<format::MatchRun>{}
                                    : std::vector<format::MatchRun>(runs.begin(), runs.begin() + n);
  };
  const auto same = [](const std::vector<format::MatchRun>& a, const std::vector<format::MatchRun>& b) {
    return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](const auto& x, const auto& y) {
             return x.keep == y.keep && x.drop == y.drop && x.insert == y.insert;
           });
  };
  for (const char* attributes : {"id", ""}) {
    SCOPED_TRACE(attributes);
    const fs::path clip = dir / (*attributes ? "k8_ids.pstream" : "k8.pstream");
    const fs::path with_ids = dir / "k8_ids.pstream";
    ASSERT_EQ(test::run_cli(fmt::format("cook {} -o {} -q --keyframe-interval 8{}", sparks, clip.string(),
                                        *attributes ? " --attributes id" : ""))
                  .exit_code,
              0);
    const auto reader = format::Reader::open(clip);
    const auto ids = format::Reader::open(with_ids);  // made first: ids to check against
    const format::Metadata& m = reader.metadata();
    ASSERT_EQ(m.version, 6u);
    ASSERT_EQ(m.codec.order, format::FrameOrder::Id);
    std::vector<std::byte> prev(ids.metadata().max_count * ids.metadata().record_size), cur(prev.size()),
        out(m.max_count * m.record_size);
    std::vector<format::MatchRun> expected(2 * m.max_count + 1);
    int keyframes = 0;
    for (std::uint64_t f = 1; f < m.frame_count(); ++f) {
      ids.read_frame(f - 1, prev);
      ids.read_frame(f, cur);
      const std::size_t n = format::match_by_id(ids.metadata(), prev, ids.metadata().frames[f - 1].count, cur,
                                                ids.metadata().frames[f].count, expected);
      ASSERT_NE(n, format::kNoMatching);
      const auto got = runs_of(reader, f, out);
      EXPECT_TRUE(same(got, std::vector<format::MatchRun>(expected.begin(), expected.begin() + n))) << "frame " << f;
      keyframes += m.frames[f].keyframe ? 1 : 0;
    }
    EXPECT_EQ(keyframes, 5);  // frames 8, 16, 24, 32 and 40 are linked; frame 0 has nothing before it
    std::vector<std::byte> first(m.max_count * m.record_size);
    EXPECT_TRUE(runs_of(reader, 0, first).empty());
  }
  // The default cook's export: one id a source particle, across all five linked keyframes.
  ASSERT_EQ(test::run_cli(fmt::format("export {} -o {} -q", (dir / "k8.pstream").string(), (dir / "k8.abc").string()))
                .exit_code,
            0);
  const auto exported = alembic::Archive::open((dir / "k8.abc").string());
  const alembic::Points points(*exported.find("/particles"));
  std::set<std::uint64_t> distinct;
  for (std::uint32_t s = 0; s < points.num_samples(); ++s) {
    const alembic::SampleView v = points.ids(s);
    for (std::uint64_t i = 0; i < v.scalar_count(); ++i) distinct.insert(v.value_u64(i));
  }
  EXPECT_EQ(distinct.size(), 10000u);
  // A version 5 clip (sparks, keyframes every 5 frames in its cook): no links, no matching there.
  const auto v5 = format::Reader::open(test::data_path("pstream/sparks_particle_v5.pstream"));
  ASSERT_EQ(v5.metadata().version, 5u);
  std::vector<std::byte> out5(v5.metadata().max_count * v5.metadata().record_size);
  int v5_keyframes = 0;
  for (std::uint64_t f = 1; f < v5.metadata().frame_count(); ++f) {
    if (v5.metadata().frames[f].keyframe) {
      EXPECT_TRUE(runs_of(v5, f, out5).empty()) << "frame " << f;
      ++v5_keyframes;
    }
  }
  EXPECT_EQ(v5_keyframes, 2);
}

TEST(ParticleCodec, SavedStatesResumeBitForBitGoingBackwards) {
  const fs::path dir = test::fresh_dir();
  std::vector<fs::path> files;
  for (const Fixture& fx : fixtures())
    files.push_back(cook_with(dir, fx, "default" + std::to_string(files.size()), format::FrameCodec::Particle));
  {  // the default cook of the sparks: colours and velocity derived from the matching
    cook::Options o;
    o.input = test::data_path("sims/blender_sparks.abc");
    o.output = dir / "sparks-default.pstream";
    cook::cook(o);
    files.push_back(o.output);
  }
  for (const char* v : {"sparks_particle_v2", "sparks_particle_v3", "sparks_particle_v4", "sparks_particle_v5"})
    files.push_back(test::data_path(fmt::format("pstream/{}.pstream", v)));
  int saving_clips = 0;
  for (const fs::path& file : files) {
    SCOPED_TRACE(file.filename().string());
    const auto reader = format::Reader::open(file);
    const format::Metadata& m = reader.metadata();
    if (m.frame_count() < 3) continue;
    const std::uint64_t bytes = m.max_count * m.record_size;
    std::vector<std::byte> packet, scratch(m.chunk_size), out(bytes);
    std::vector<std::vector<std::byte>> forward(m.frame_count());
    std::vector<std::vector<format::MatchRun>> forward_runs(m.frame_count());
    std::vector<format::MatchRun> runs(2 * m.max_count + 1);
    const auto decode = [&](format::FrameDecoder& d, std::uint64_t f) {
      packet.resize(m.frames[f].packet_size);
      reader.read_packet(f, packet, scratch);
      const std::size_t n = d.decode(f, packet, out, runs);
      return n == format::kNoMatching ? std::vector<format::MatchRun>{}
                                      : std::vector<format::MatchRun>(runs.begin(), runs.begin() + n);
    };
    {
      format::FrameDecoder straight(m, "straight");
      for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
        forward_runs[f] = decode(straight, f);
        forward[f].assign(out.begin(), out.begin() + m.frames[f].count * m.record_size);
      }
    }
    std::uint64_t decodes[2] = {0, 0};
    for (const std::size_t states : {std::size_t{0}, std::size_t{3}}) {
      format::FrameDecoder d(m, "backwards", 0, states);
      if (states != 0 && d.saved_states() != 0) {
        ++saving_clips;
        EXPECT_EQ(d.state_bytes(), format::FrameDecoder::base_state_bytes(m) +
                                       d.saved_states() * format::FrameDecoder::saved_state_bytes(m));
      }
      for (std::uint64_t f = m.frame_count(); f-- > 0;) {
        d.set_target(f);
        for (std::uint64_t g = d.resume_frame(f); g <= f; ++g) {
          ASSERT_TRUE(d.can_decode(g)) << "frame " << g << " on the way to " << f;
          const auto r = decode(d, g);
          ++decodes[states != 0];
          if (g != f) continue;
          ASSERT_TRUE(std::equal(forward[f].begin(), forward[f].end(), out.begin())) << "frame " << f;
          ASSERT_EQ(r.size(), forward_runs[f].size()) << "frame " << f;
          for (std::size_t i = 0; i < r.size(); ++i) {
            const format::MatchRun &a = r[i], &b = forward_runs[f][i];
            ASSERT_TRUE(a.keep == b.keep && a.drop == b.drop && a.insert == b.insert) << "frame " << f << " run " << i;
          }
        }
      }
    }
    // The Reader (Python's Clip.read_frame, pstream_clip_read_frame) read last to first: it makes
    // its decoder again with saved states at the first read that goes back.
    const auto back = format::Reader::open(file);
    std::vector<std::byte> read(bytes);
    for (std::uint64_t f = m.frame_count(); f-- > 0;) {
      back.read_frame(f, read);
      ASSERT_TRUE(std::equal(forward[f].begin(), forward[f].end(), read.begin())) << "Reader, frame " << f;
    }
    std::cout << file.filename().string() << ": " << m.frame_count() << " frames backwards, " << decodes[0]
              << " decodes from keyframes, " << decodes[1] << " with 3 saved states, " << back.frames_decoded()
              << " by the Reader\n";
    EXPECT_LE(decodes[1], decodes[0]);
    EXPECT_LE(back.frames_decoded(), decodes[0]);
    if (m.codec.codec == format::FrameCodec::Particle && format::FrameDecoder::saved_state_bytes(m) != 0 &&
        m.frame_count() >= 32) {
      EXPECT_LT(decodes[1] * 2, decodes[0]) << "saved states should at least halve the decodes";
      EXPECT_LT(back.frames_decoded() * 2, decodes[0]) << "the Reader's too";
    }
  }
  EXPECT_GE(saving_clips, 8);
}

// Without ids the matching pairs what it can: once the closest pairs are taken, the particles
// left over in both frames are paired among themselves, closest first (a previous particle is left
// over when closer pairs took each of its few nearest candidates). On the FLIP pour no particle
// that ends is then within half the matching's cell (the side of a cube holding one particle of
// the frame's box, about four particle spacings here) of one that starts: the frame has few
// operations, and its survivors come in long runs.
TEST(ParticleCodec, WithoutIdsNoParticleThatEndsIsNearOneThatStarts) {
  const fs::path dir = test::fresh_dir();
  const fs::path file =
      cook_with(dir, {"sims/blender_flip_pour_small.abc", "", {}}, "flip", format::FrameCodec::Particle);
  const auto reader = format::Reader::open(file);
  const format::Metadata& m = reader.metadata();
  ASSERT_EQ(m.codec.order, format::FrameOrder::Matched);
  format::FrameDecoder decoder(m, "flip");
  std::vector<std::byte> before(m.max_count * m.record_size), after(before.size()), packet, scratch(m.chunk_size);
  std::vector<format::MatchRun> runs(2 * m.max_count + 1);
  const auto position = [&](const std::vector<std::byte>& records, std::uint64_t i) {
    std::array<float, 3> p{};
    std::memcpy(p.data(), records.data() + i * m.record_size, 12);
    return p;
  };
  std::uint64_t predicted = 0, particles = 0, operations = 0, ended = 0, started = 0, near = 0;
  double nearest = std::numeric_limits<double>::infinity();  // over every frame, in cells
  for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
    packet.resize(m.frames[f].packet_size);
    reader.read_packet(f, packet, scratch);
    const std::size_t count = decoder.decode(f, packet, after, runs);
    const std::uint64_t n = m.frames[f].count;
    if (f > 0 && !m.frames[f].keyframe) {
      ASSERT_NE(count, format::kNoMatching) << "frame " << f;
      // The encoder's cell: the side of a cube holding one particle of the frame's box.
      std::array<float, 3> lo = position(after, 0), hi = lo;
      for (std::uint64_t j = 0; j < n; ++j) {
        const auto p = position(after, j);
        for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], p[a]), hi[a] = std::max(hi[a], p[a]);
      }
      const double cell = std::cbrt(double(hi[0] - lo[0]) * (hi[1] - lo[1]) * (hi[2] - lo[2]) / double(n));
      std::vector<std::array<float, 3>> gone, come;
      std::uint64_t i = 0, j = 0;
      for (std::size_t r = 0; r < count; ++r) {
        i += runs[r].keep, j += runs[r].keep;
        for (std::uint32_t t = 0; t < runs[r].drop; ++t) gone.push_back(position(before, i++));
        for (std::uint32_t t = 0; t < runs[r].insert; ++t) come.push_back(position(after, j++));
      }
      for (const auto& g : gone) {
        for (const auto& c : come) {
          double d2 = 0;
          for (int a = 0; a < 3; ++a) d2 += double(g[a] - c[a]) * double(g[a] - c[a]);
          const double d = std::sqrt(d2) / cell;
          nearest = std::min(nearest, d);
          near += d < 0.5 ? 1 : 0;
        }
      }
      ++predicted;
      particles += n;
      operations += count;
      ended += gone.size();
      started += come.size();
    }
    std::swap(before, after);
  }
  ASSERT_GT(predicted, 40u);
  EXPECT_EQ(near, 0u) << "pairs of an ending and a starting particle within half a cell; the nearest at " << nearest
                      << " cells";
  RecordProperty("operations_per_frame", std::to_string(double(operations) / double(predicted)));
  RecordProperty("particles_per_frame", std::to_string(double(particles) / double(predicted)));
  RecordProperty("ended_per_frame", std::to_string(double(ended) / double(predicted)));
  RecordProperty("started_per_frame", std::to_string(double(started) / double(predicted)));
}

// A clump of particles a grid step apart beside one stray particle far away: the cells are sized
// for the whole box, so one cell holds the clump, and each search reads at most kMostRead of its
// particles (it read all of them, and the leftovers' pairing read them again each round: 8,000
// particles took 6.8 s to cook). The clip still holds every particle within the bound.
TEST(ParticleCodec, WithoutIdsAClumpBesideAStrayParticleCooksWithinItsBound) {
  constexpr std::uint32_t kCount = 8000;
  constexpr int kFrames = 3;
  std::uint32_t seed = 11;
  const auto unit = [&] {
    seed = seed * 1664525u + 1013904223u;
    return float(seed >> 8) / float(1u << 24);
  };
  std::vector<std::vector<float>> position(kFrames);
  cook::MemoryClip clip;
  clip.name = "clump";
  for (int f = 0; f < kFrames; ++f) {
    std::vector<float>& p = position[std::size_t(f)];
    for (std::uint32_t i = 0; i + 1 < kCount; ++i)
      for (int a = 0; a < 3; ++a) p.push_back(1e-3f * unit());  // within a millimetre
    p.insert(p.end(), {100.0f, 100.0f, 100.0f + float(f)});     // the stray one, 170 m away
  }
  for (int f = 0; f < kFrames; ++f) {
    cook::MemoryFrame frame;
    frame.time = f / 24.0;
    frame.count = kCount;
    frame.position = position[std::size_t(f)];
    clip.frames.push_back(frame);
  }
  const fs::path dir = test::fresh_dir();
  cook::Options o;
  o.output = dir / "clump.pstream";
  cook::cook(o, clip);
  const auto reader = format::Reader::open(o.output);
  const format::Metadata& m = reader.metadata();
  ASSERT_EQ(m.codec.order, format::FrameOrder::Matched);
  const double bound = m.codec.words[0].error;  // the position bound the encoder guarantees
  std::vector<std::byte> records(m.max_count * m.record_size);
  for (int f = 0; f < kFrames; ++f) {
    ASSERT_EQ(m.frames[std::size_t(f)].count, kCount);
    reader.read_frame(std::uint64_t(f), records);
    std::uint32_t clumped = 0, stray = 0;
    for (std::uint32_t j = 0; j < kCount; ++j) {
      float q[3];
      std::memcpy(q, records.data() + std::size_t(j) * m.record_size, 12);
      const bool far = q[0] > 50;
      const float expect[3] = {100.0f, 100.0f, 100.0f + float(f)};
      for (int a = 0; a < 3; ++a) {
        if (far) {
          EXPECT_LE(std::abs(q[a] - expect[a]), bound) << "frame " << f;
        } else {
          EXPECT_GE(q[a], -bound) << "frame " << f;
          EXPECT_LE(q[a], 1e-3 + bound) << "frame " << f;
        }
      }
      (far ? stray : clumped) += 1;
    }
    EXPECT_EQ(stray, 1u) << "frame " << f;
    EXPECT_EQ(clumped, kCount - 1) << "frame " << f;
  }
}

// Format version 4: a packet continues the zstd frame of the one before (a small body), or starts
// one (a keyframe, or a body of 512 KiB or more); the decoder follows either, frame by frame.
TEST(ParticleCodec, PacketsContinueOneZstdFrameUnlessTheyStartOne) {
  const std::uint32_t counts[] = {3000, 3000, 150000, 150000, 3000};
  std::vector<format::Attribute> layout = format::default_layout();
  format::append_attribute(layout, "id", format::AttributeType::Uint64, 1);
  const std::uint32_t rs = format::record_size_of(layout);
  std::vector<std::vector<std::byte>> records;
  std::vector<std::vector<std::uint64_t>> ids;
  format::ClipStats stats(layout);
  for (std::uint32_t f = 0; f < std::size(counts); ++f) {
    records.emplace_back(std::size_t(counts[f]) * rs);
    ids.emplace_back(counts[f]);
    for (std::uint32_t i = 0; i < counts[f]; ++i) {
      const std::uint32_t h = (i * 2654435761u) ^ (f * 40503u);
      // Noise of up to a few hundred grid steps: residuals of two bytes, large bodies.
      const float r[4] = {float(i % 500) * 0.01f + 0.3f * float(h % 1000) / 1000.0f + 0.03f * float(f),
                          float(i / 500 % 300) * 0.01f + 0.3f * float(h / 1000 % 1000) / 1000.0f, 0.1f, 0.01f};
      std::memcpy(records[f].data() + std::size_t(i) * rs, r, 16);
      const std::uint64_t id = i;
      std::memcpy(records[f].data() + std::size_t(i) * rs + 16, &id, 8);
      ids[f][i] = id;
    }
    stats.add(records[f], counts[f]);
  }
  const format::CodecInfo info = format::plan_particle_codec(layout, stats, 24.0, true, {});
  std::vector<format::SourceFrame> frames;
  for (std::uint32_t f = 0; f < std::size(counts); ++f) frames.push_back({records[f], ids[f], counts[f]});
  const auto encoded = format::encode_group(info, frames, {}, 0);
  const auto starts_frame = [](const std::vector<std::byte>& packet) {
    std::uint32_t magic = 0;
    std::memcpy(&magic, packet.data(), 4);
    return magic == format::particle::kZstdMagic;
  };
  const bool expected[] = {true, false, true, true, false};  // keyframe, small, large, large, small
  format::Metadata meta = metadata_for(layout, info, encoded);
  meta.version = format::kVersion;
  format::FrameDecoder decoder(meta, "generated");
  std::vector<std::byte> out(std::size_t(meta.max_count) * rs);
  for (std::uint32_t f = 0; f < std::size(counts); ++f) {
    EXPECT_EQ(starts_frame(encoded[f].packet), expected[f]) << "frame " << f;
    decoder.decode(f, encoded[f].packet, out);
    double worst = 0;
    for (std::uint32_t i = 0; i < counts[f]; ++i) {
      for (int c = 0; c < 3; ++c) {
        float a, b;
        std::memcpy(&a, records[f].data() + std::size_t(i) * rs + 4 * c, 4);
        std::memcpy(&b, out.data() + std::size_t(i) * rs + 4 * c, 4);
        worst = std::max(worst, double(std::abs(a - b)));
      }
    }
    EXPECT_LE(worst, info.words[0].error) << "frame " << f;
  }
}

// verify --against reads the source frame by frame beside the clip and writes nothing: it used to
// cook the whole source into a temporary (2 GB in /tmp for the demo's clip, left there by Ctrl-C).
// With TMPDIR naming no folder, any temporary would fail. A clip of some of the source's frames
// is compared on those frames alone; progress goes to stderr, a line a stage, when it is long.
TEST(ParticleCodecCli, VerifyAgainstReadsTheSourceWithoutATemporary) {
  const fs::path dir = test::fresh_dir();
  const std::string sparks = test::data_path("sims/blender_sparks.abc");
  const fs::path clip = dir / "part.pstream";
  ASSERT_EQ(test::run_cli(fmt::format("cook {} -o {} --frames 10:20 -q", test::q(sparks), test::q(clip))).exit_code, 0);
  const std::string tmp = "TMPDIR=" + (dir / "no-such-folder").string() + " ";
  auto r = test::run_cli_raw(tmp + PSTREAM_CLI +
                             fmt::format(" verify {} --against {} --json", test::q(clip), test::q(sparks)));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto j = nlohmann::json::parse(r.output.substr(r.output.find('{')));
  EXPECT_TRUE(j["ok"].get<bool>()) << r.output;
  EXPECT_EQ(j["against"]["frames_compared"], 10) << r.output;
  std::uint64_t particles = 0;
  const auto reader = format::Reader::open(clip);
  for (const auto& fr : reader.metadata().frames) particles += fr.count;
  EXPECT_EQ(j["against"]["particles"].get<std::uint64_t>(), particles);
  // The same through bench codec, which reads the source the same way.
  r = test::run_cli_raw(tmp + PSTREAM_CLI +
                        fmt::format(" bench codec {} --frames 3 --repetitions 1 --codec raw --json", test::q(sparks)));
  EXPECT_EQ(r.exit_code, 0) << r.output;
  // Against another cache: its error, named.
  test::expect_error(test::run_cli(fmt::format("verify {} --against {}", test::q(clip),
                                               test::q(test::data_path("alembic/points_varying.abc")))),
                     "no object '/Emitter/Sparks'");
}

TEST(ParticleCodecCli, VerifyAgainstTheSourceAndExportRoundTrips) {
  const fs::path dir = test::fresh_dir();
  const std::string sparks = test::data_path("sims/blender_sparks.abc");
  const fs::path clip = dir / "sparks.pstream";
  ASSERT_EQ(test::run_cli(
                fmt::format("cook {} -o {} --codec particle --attributes id,velocity,age -q", sparks, clip.string()))
                .exit_code,
            0);
  auto r = test::run_cli(fmt::format("verify {} --against {} --json", clip.string(), sparks));
  EXPECT_EQ(r.exit_code, 0) << r.output;
  const auto j = nlohmann::json::parse(r.output.substr(r.output.find('{')));
  EXPECT_TRUE(j["ok"].get<bool>());
  for (const auto& a : j["against"]["attributes"]) {
    EXPECT_TRUE(a["ok"].get<bool>());
    // Every attribute but the positions counts its distinct values; the clip keeps at least those
    // the bound keeps apart, and an exact attribute every one.
    EXPECT_EQ(a.contains("distinct_clip"), a["name"] != "position") << a.dump();
    if (a.contains("distinct_clip") && !a.value("derived", false)) {
      EXPECT_GE(a["distinct_clip"].get<std::uint64_t>(), a["kept_apart"].get<std::uint64_t>()) << a.dump();
      if (a["bound"].get<double>() == 0.0) {
        EXPECT_EQ(a["kept_apart"], a["distinct_source"]) << a.dump();
        EXPECT_EQ(a["distinct_clip"], a["distinct_source"]) << a.dump();
      }
    }
    if (a.value("derived", false)) {  // a derived velocity: reported against the source's, no bound
      EXPECT_EQ(a["name"], "velocity");
      EXPECT_LT(a["rms_error"].get<double>(), 0.15 * a["rms_source"].get<double>()) << a.dump();
      continue;
    }
    EXPECT_LE(a["max_error"].get<double>(), a["bound"].get<double>()) << a.dump();
    if (a["name"] == "scale") {  // each attribute against its own bound: scale relative to itself
      EXPECT_TRUE(a["relative"].get<bool>());
      EXPECT_DOUBLE_EQ(a["bound"].get<double>(), double(0.01f));
      EXPECT_GT(a["distinct_clip"].get<std::uint64_t>(), 20u);
      // The sparks' 512 sizes span 2.5 times: at 1 % of each, values whose bounds do not overlap
      // are at least 1.01 / 0.99 times apart, so at most 46 of them (43 measured).
      EXPECT_GE(a["kept_apart"].get<std::uint64_t>(), 40u) << a.dump();
      EXPECT_LE(a["kept_apart"].get<std::uint64_t>(), 46u) << a.dump();
    }
    if (a["name"] == "id") {
      EXPECT_EQ(a["distinct_clip"].get<std::uint64_t>(), 10000u) << a.dump();
    }
  }
  // The text report prints each attribute's error beside its bound.
  r = test::run_cli(fmt::format("verify {} --against {}", clip.string(), sparks));
  EXPECT_NE(r.output.find("scale"), std::string::npos);
  EXPECT_NE(r.output.find("% of each value"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("of which the bound keeps"), std::string::npos) << r.output;
  const std::size_t position_line = r.output.find("  position ");
  ASSERT_NE(position_line, std::string::npos) << r.output;
  EXPECT_EQ(r.output.substr(position_line, r.output.find('\n', position_line) - position_line).find("distinct"),
            std::string::npos)
      << r.output;
  // Against another cache the values are far off: a failure, naming the attribute.
  r = test::run_cli(
      fmt::format("verify {} --against {}", clip.string(), test::data_path("alembic/points_varying.abc")));
  EXPECT_NE(r.exit_code, 0) << r.output;

  // Export, then cook the export: the decoded values come back exactly (floats are written as
  // they are; scale as a radius in PLY, as a diameter width in Alembic).
  ASSERT_EQ(test::run_cli(fmt::format("export {} -o {} -q", clip.string(), (dir / "back.abc").string())).exit_code, 0);
  ASSERT_EQ(test::run_cli(fmt::format("export {} --out {} -q", clip.string(), (dir / "ply").string())).exit_code, 0);
  EXPECT_TRUE(fs::exists(dir / "ply" / "frame.0001.ply"));
  EXPECT_TRUE(fs::exists(dir / "ply" / "frame.0048.ply"));
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.input = dir / "back.abc";
  o.output = dir / "back.pstream";
  o.attributes = {"id", "velocity", "age"};
  cook::cook(o);
  const auto a = format::Reader::open(clip);
  const auto b = format::Reader::open(o.output);
  ASSERT_EQ(a.metadata().frame_count(), b.metadata().frame_count());
  std::vector<std::byte> da(a.metadata().max_count * a.metadata().record_size), db(da.size());
  for (std::uint64_t f = 0; f < a.metadata().frame_count(); ++f) {
    a.read_frame(f, da);
    b.read_frame(f, db);
    format::FrameComparison c;
    c.add(a.metadata().layout, da, a.metadata().frames[f].count, db, b.metadata().frames[f].count);
    EXPECT_EQ(c.unmatched, 0u);
    for (std::size_t w = 0; w < c.max_error.size(); ++w) {
      // Colour goes through Cd as float/255 and back: exact for unorm8.
      EXPECT_EQ(c.max_error[w], 0.0) << "frame " << f << " word " << w;
    }
  }
  o.input = dir / "ply" / "frame.0001.ply";
  o.output = dir / "from_ply.pstream";
  o.fps = 24;
  o.attributes = {"velocity"};
  cook::cook(o);
  EXPECT_EQ(format::Reader::open(o.output).metadata().frame_count(), a.metadata().frame_count());
}

// A default cook keeps no ids but matches the sparks by theirs: exported to PLY as to Alembic,
// every particle gets the id the codec's matching keeps, one per particle of the source, the same
// in both formats, and the PLY sequence cooks back matched by id.
TEST(ParticleCodecCli, ExportGivesADefaultCookWithIdsTheMatchingsIdsInBothFormats) {
  const fs::path dir = test::fresh_dir();
  const std::string sparks = test::data_path("sims/blender_sparks.abc");
  const fs::path clip = dir / "sparks.pstream";
  ASSERT_EQ(test::run_cli(fmt::format("cook {} -o {} -q", sparks, clip.string())).exit_code, 0);
  ASSERT_EQ(format::Reader::open(clip).metadata().find("id"), nullptr);
  ASSERT_EQ(test::run_cli(fmt::format("export {} -o {} -q", clip.string(), (dir / "back.abc").string())).exit_code, 0);
  ASSERT_EQ(test::run_cli(fmt::format("export {} --out {} -q", clip.string(), (dir / "ply").string())).exit_code, 0);
  const auto cooked = [&](const fs::path& input, const std::string& name) {
    cook::Options o;
    o.frame_codec = format::FrameCodec::Records;
    o.input = input;
    o.output = dir / name;
    o.fps = 24;
    o.attributes = {"id", "velocity"};
    cook::cook(o);
    return format::Reader::open(o.output);
  };
  const auto from_abc = cooked(dir / "back.abc", "abc.pstream");
  const auto from_ply = cooked(dir / "ply" / "frame.0001.ply", "ply.pstream");
  const format::Metadata& m = from_ply.metadata();
  ASSERT_EQ(m.frame_count(), 48u);
  ASSERT_EQ(from_abc.metadata().record_size, m.record_size);
  const format::Attribute* id = m.find("id");
  ASSERT_NE(id, nullptr);
  std::vector<std::byte> a(m.max_count * m.record_size), b(a.size());
  std::set<std::uint64_t> ids;
  for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
    from_abc.read_frame(f, a);
    from_ply.read_frame(f, b);
    ASSERT_EQ(from_abc.metadata().frames[f].count, m.frames[f].count);
    EXPECT_EQ(std::memcmp(a.data(), b.data(), m.frames[f].count * m.record_size), 0) << "frame " << f;
    for (std::uint64_t i = 0; i < m.frames[f].count; ++i) {
      std::uint64_t v = 0;
      std::memcpy(&v, b.data() + i * m.record_size + id->offset, id->type == format::AttributeType::Uint64 ? 8 : 4);
      ids.insert(v);
    }
  }
  std::set<std::uint64_t> source_ids;
  const auto archive = alembic::Archive::open(sparks);
  const alembic::Points points(*archive.find("/Emitter/Sparks"));
  for (std::uint32_t s = 0; s < points.num_samples(); ++s) {
    const alembic::SampleView v = points.ids(s);
    for (std::uint64_t i = 0; i < v.scalar_count(); ++i) source_ids.insert(v.value_u64(i));
  }
  EXPECT_EQ(ids.size(), source_ids.size());
  const auto r = test::run_cli(fmt::format("info {}", (dir / "ply" / "frame.0001.ply").string()));
  EXPECT_NE(r.output.find("ids from 'id' (particles matched by id)"), std::string::npos) << r.output;
}

}  // namespace

namespace {

// `pstream bench codec --json`: every codec asked for, in one table, with the ratios of ours to
// its baseline and its peer taken within repetitions (values, not timings: timings are for the
// benchmark, not a test).
TEST(ParticleCodecCli, BenchCodecReportsTheCodecsAndOursAgainstItsPeers) {
  const std::string sparks = test::data_path("sims/blender_sparks.abc");
  const auto r = test::run_cli(
      fmt::format("bench codec {} --frames 4 --repetitions 3 --codec 'particle (ours)' --codec 'meshopt + zstd -3' "
                  "--codec 'zstd -3' --json",
                  sparks));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto j = nlohmann::json::parse(r.output.substr(r.output.find('{')));
  EXPECT_EQ(j["clock"], "thread CPU time");
  EXPECT_EQ(j["repetitions"], 3);
  // Which instructions our decoder ran with (this process's choice: the CLI's is the same).
  EXPECT_EQ(j["ours_decoder_simd"], std::string(format::particle_decoder_simd()));
  ASSERT_EQ(j["codecs"].size(), 3u);
  std::map<std::string, nlohmann::json> by_name;
  for (const auto& c : j["codecs"]) by_name[c["codec"].get<std::string>()] = c;
  ASSERT_TRUE(by_name.count("particle (ours)") && by_name.count("meshopt + zstd -3") && by_name.count("zstd -3"));
  const auto& ours = by_name["particle (ours)"];
  const double bound = j["error_bound"];
  EXPECT_LE(ours["max_error_position"].get<double>(), bound);
  EXPECT_LT(ours["bytes_per_particle"].get<double>(), by_name["meshopt + zstd -3"]["bytes_per_particle"].get<double>());
  EXPECT_EQ(by_name["zstd -3"]["max_error_position"].get<double>(), 0.0);  // lossless
  for (const auto& c : j["codecs"]) {
    EXPECT_GT(c["decode_gb_s"].get<double>(), 0.0) << c.dump();
    EXPECT_GT(c["decode_first_pass_gb_s"].get<double>(), 0.0) << c.dump();
    EXPECT_GT(c["encode_mb_s"].get<double>(), 0.0) << c.dump();
    // Encodes are timed as the median of up to --repetitions runs (fewer only past 2 s of CPU,
    // which 4 frames of the sparks are far from).
    EXPECT_EQ(c["encode_runs"].get<int>(), 3) << c.dump();
  }
  EXPECT_GT(j["ours_decode_vs_zstd"].get<double>(), 0.0);
  EXPECT_GT(j["ours_decode_vs_meshopt"].get<double>(), 0.0);
  EXPECT_GT(j["ours_first_pass_vs_zstd"].get<double>(), 0.0);
  EXPECT_GT(j["ours_first_pass_vs_meshopt"].get<double>(), 0.0);
  // Without its peers in the run, no ratio to them.
  const auto alone =
      test::run_cli(fmt::format("bench codec {} --frames 2 --repetitions 1 --codec 'particle (ours)' --json", sparks));
  ASSERT_EQ(alone.exit_code, 0) << alone.output;
  const auto k = nlohmann::json::parse(alone.output.substr(alone.output.find('{')));
  EXPECT_EQ(k["ours_decode_vs_zstd"].get<double>(), 0.0);
  EXPECT_EQ(k["ours_decode_vs_meshopt"].get<double>(), 0.0);
  EXPECT_EQ(k["ours_first_pass_vs_meshopt"].get<double>(), 0.0);
  EXPECT_EQ(k["codecs"][0]["encode_runs"].get<int>(), 1);
}

// `bench codec --error`: every lossy codec of the run keeps the bound asked for (cook's syntax:
// abs: in scene units here), and a looser bound costs ours fewer bytes. A mistyped bound fails
// before any frame loads, naming the flag and what it expects.
TEST(ParticleCodecCli, BenchCodecComparesTheCodecsAtTheBoundAskedFor) {
  const std::string flip = test::data_path("sims/blender_flip_pour_small.abc");
  const auto at = [&](const std::string& bound) {
    const auto r = test::run_cli(
        fmt::format("bench codec {} --frames 6 --repetitions 1 --codec 'particle (ours)' --codec 'meshopt + zstd -3' "
                    "--codec draco --error {} --scale-error 2% --json",
                    flip, bound));
    EXPECT_EQ(r.exit_code, 0) << r.output;
    return nlohmann::json::parse(r.output.substr(r.output.find('{')));
  };
  const auto fine = at("abs:0.0005"), coarse = at("abs:0.002");
  EXPECT_DOUBLE_EQ(fine["error_bound"].get<double>(), 0.0005);
  EXPECT_EQ(fine["error_bound_spec"], "abs:0.0005");
  EXPECT_DOUBLE_EQ(fine["scale_error"].get<double>(), 0.02);
  EXPECT_DOUBLE_EQ(coarse["error_bound"].get<double>(), 0.002);
  double ours_fine = 0, ours_coarse = 0;
  for (const auto* j : {&fine, &coarse}) {
    const double bound = (*j)["error_bound"];
    ASSERT_EQ((*j)["codecs"].size(), 3u);
    for (const auto& c : (*j)["codecs"]) {
      EXPECT_LE(c["max_error_position"].get<double>(), bound) << c.dump();
      EXPECT_GT(c["max_error_position"].get<double>(), 0.0) << c.dump();  // lossy: the bound was used
      if (c["codec"] == "particle (ours)") (j == &fine ? ours_fine : ours_coarse) = c["bytes_per_particle"];
    }
  }
  EXPECT_GT(ours_fine, 0.0);
  EXPECT_LT(ours_coarse, ours_fine);
  const auto bad = test::run_cli(fmt::format("bench codec {} --error 1e-4x", flip));
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.output.find("--error '1e-4x': expected a fraction of the bounds diagonal"), std::string::npos)
      << bad.output;
  const auto bad_scale = test::run_cli(fmt::format("bench codec {} --scale-error 80%", flip));
  EXPECT_NE(bad_scale.exit_code, 0);
  EXPECT_NE(bad_scale.output.find("--scale-error '80%'"), std::string::npos) << bad_scale.output;
  // A codec's name mistyped: the names, and the nearest.
  const auto bad_codec = test::run_cli(fmt::format("bench codec {} --codec 'particle (our)'", flip));
  EXPECT_NE(bad_codec.exit_code, 0);
  EXPECT_NE(bad_codec.output.find("--codec 'particle (our)': expected one of 'raw', 'lz4'"), std::string::npos)
      << bad_codec.output;
  EXPECT_NE(bad_codec.output.find("(did you mean 'particle (ours)'?)"), std::string::npos) << bad_codec.output;
}

// `bench codec --svg`: one point per codec, placed by the JSON's figures on logarithmic axes, and
// every label readable (no two labels' boxes overlap, nor a label and another codec's point).
TEST(ParticleCodecCli, BenchCodecPlotPlacesEveryCodecAndItsLabelApart) {
  const std::string sparks = test::data_path("sims/blender_sparks.abc");
  const auto dir = test::fresh_dir();
  const std::string svg = (dir / "plot.svg").string();
  const auto r = test::run_cli(fmt::format("bench codec {} --frames 3 --repetitions 1 --json --svg {}", sparks, svg));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto j = nlohmann::json::parse(r.output.substr(r.output.find('{')));
  std::ifstream in(svg);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_NE(text.find("</svg>"), std::string::npos);
  const auto attr = [](const std::string& tag, const std::string& name) {
    const auto at = tag.find(" " + name + "=\"");
    return at == std::string::npos ? std::nan("") : std::stod(tag.substr(at + name.size() + 3));
  };
  struct Box {
    double x0, y0, x1, y1;
  };
  std::vector<std::pair<double, double>> points;
  std::map<std::string, Box> labels;
  for (std::size_t at = 0; (at = text.find('<', at)) != std::string::npos; ++at) {
    const std::size_t end = text.find('>', at);
    const std::string tag = text.substr(at, end - at + 1);
    if (tag.rfind("<circle", 0) == 0) points.emplace_back(attr(tag, "cx"), attr(tag, "cy"));
    if (tag.rfind("<text", 0) == 0 && tag.find("text-anchor") == std::string::npos &&
        tag.find("rotate") == std::string::npos) {
      const std::string name = text.substr(end + 1, text.find('<', end) - end - 1);
      const double x = attr(tag, "x"), y = attr(tag, "y");
      labels[name] = {x, y - 11, x + 7.0 * double(name.size()), y + 2};
    }
  }
  const auto& codecs = j["codecs"];
  ASSERT_EQ(points.size(), codecs.size());
  for (const auto& c : codecs) EXPECT_TRUE(labels.count(c["codec"].get<std::string>())) << c["codec"];
  // Faster is further right and smaller further down, point for point.
  for (std::size_t a = 0; a < codecs.size(); ++a) {
    for (std::size_t b = 0; b < codecs.size(); ++b) {
      if (codecs[a]["decode_gb_s"].get<double>() < codecs[b]["decode_gb_s"].get<double>()) {
        EXPECT_LE(points[a].first, points[b].first) << codecs[a]["codec"] << " " << codecs[b]["codec"];
      }
      if (codecs[a]["bytes_per_particle"].get<double>() < codecs[b]["bytes_per_particle"].get<double>()) {
        EXPECT_GE(points[a].second, points[b].second) << codecs[a]["codec"] << " " << codecs[b]["codec"];
      }
    }
  }
  const auto overlap = [](const Box& p, const Box& q) {
    return p.x0 < q.x1 && q.x0 < p.x1 && p.y0 < q.y1 && q.y0 < p.y1;
  };
  for (auto a = labels.begin(); a != labels.end(); ++a) {
    for (auto b = std::next(a); b != labels.end(); ++b) {
      EXPECT_FALSE(overlap(a->second, b->second)) << a->first << " and " << b->first;
    }
    for (const auto& [x, y] : points) {
      EXPECT_FALSE(overlap(a->second, {x - 4, y - 4, x + 4, y + 4})) << a->first << " covers a point";
    }
  }
}

// The registry: every frame codec has both halves under one name, and a clip planned and encoded
// through its encoding half decodes through its decoding half (FrameDecoder finds it there):
// records exactly, the particle codec within its bounds, with births and deaths.
TEST(FrameCodecRegistry, EveryCodecRoundTripsThroughItsTwoHalves) {
  EXPECT_EQ(format::frame_codec_encoders().size(), format::frame_codec_decoders().size());
  EXPECT_EQ(format::find_frame_codec(static_cast<format::FrameCodec>(7)), nullptr);
  EXPECT_EQ(format::find_frame_codec_encoder(static_cast<format::FrameCodec>(7)), nullptr);
  for (int c = 0; c <= 5; ++c) {  // every coding a type with its name; nothing past the last
    const format::WordCodingType* t = format::find_word_coding(static_cast<format::WordCoding>(c));
    ASSERT_NE(t, nullptr);
    EXPECT_EQ(static_cast<int>(t->id), c);
    EXPECT_FALSE(t->name.empty());
  }
  EXPECT_EQ(format::find_word_coding(static_cast<format::WordCoding>(6)), nullptr);
  constexpr std::uint32_t kFrames = 6;
  std::vector<format::Attribute> layout = format::default_layout();
  format::append_attribute(layout, "id", format::AttributeType::Uint64, 1);
  const std::uint32_t rs = format::record_size_of(layout);
  std::vector<std::vector<std::byte>> records(kFrames);
  std::vector<std::vector<std::uint64_t>> ids(kFrames);
  format::ClipStats stats(layout);
  for (std::uint32_t f = 0; f < kFrames; ++f) {
    for (std::uint64_t id = f; id < 300 + 10 * f; ++id) {  // particles born and dying every frame
      const float r[4] = {float(id % 17) * 0.1f + 0.05f * float(f), float(id / 17) * 0.1f - 0.01f * float(f * f), 0.5f,
                          0.02f + 0.001f * float(id % 5)};
      records[f].resize(records[f].size() + rs);
      std::memcpy(records[f].data() + records[f].size() - rs, r, 16);
      std::memcpy(records[f].data() + records[f].size() - rs + 16, &id, 8);
      ids[f].push_back(id);
    }
    stats.add(records[f], ids[f].size());
  }
  for (const format::FrameCodecEncoding& encoding : format::frame_codec_encoders()) {
    SCOPED_TRACE(std::string(encoding.name));
    const format::FrameCodecDecoding* decoding = format::find_frame_codec(encoding.id);
    ASSERT_NE(decoding, nullptr);
    EXPECT_EQ(decoding->name, encoding.name);
    EXPECT_EQ(format::frame_codec_name(encoding.id), encoding.name);
    const format::CodecInfo info = encoding.plan(layout, stats, 24.0, true, {});
    EXPECT_EQ(info.codec, encoding.id);
    std::vector<format::SourceFrame> frames;
    for (std::uint32_t f = 0; f < kFrames; ++f) frames.push_back({records[f], ids[f], ids[f].size()});
    const auto encoded = encoding.encode_group(info, frames, {}, 0);
    ASSERT_EQ(encoded.size(), kFrames);
    const format::Metadata meta = metadata_for(layout, info, encoded);
    format::FrameDecoder decoder(meta, "registry");
    EXPECT_EQ(decoder.state_bytes(), decoding->state_bytes(meta));
    std::vector<std::byte> out(meta.max_count * rs);
    for (std::uint32_t f = 0; f < kFrames; ++f) {
      decoder.decode(f, encoded[f].packet, out);
      ASSERT_EQ(encoded[f].count, ids[f].size());
      for (std::size_t i = 0; i < ids[f].size(); ++i) {  // both keep the ascending id order given
        std::uint64_t id;
        std::memcpy(&id, out.data() + i * rs + 16, 8);
        ASSERT_EQ(id, ids[f][i]);
        for (int w = 0; w < 4; ++w) {
          float a, b;
          std::memcpy(&a, out.data() + i * rs + 4 * w, 4);
          std::memcpy(&b, records[f].data() + i * rs + 4 * w, 4);
          if (encoding.id == format::FrameCodec::Records)
            ASSERT_EQ(a, b);
          else
            ASSERT_LE(std::abs(double(a) - double(b)), w < 3 ? meta.codec.error : 0.01 * double(b));
        }
      }
    }
  }
}

// The decoder derives velocity a run at a time, in 32-bit lanes when every step is below 2^27
// (derive_run()). docs/format.md states the rule in 64-bit integers: both must give the same bits
// for every state, for the steps of valid clips (below 2^25) and for any other (corrupt) steps,
// in runs that mix both.
TEST(DerivedVelocity, TheDecodersVectorRuleIsTheSpecsSixtyFourBitRule) {
  namespace pc = pstream::format::particle;
  std::uint64_t seed = 0x9e3779b97f4a7c15ull;
  const auto next = [&] {
    seed ^= seed << 13, seed ^= seed >> 7, seed ^= seed << 17;
    return seed;
  };
  const std::uint32_t edges[] = {0u,
                                 1u,
                                 0xffffffffu,
                                 (1u << 25) - 1,
                                 0u - (1u << 25),
                                 (1u << 27) - 1,
                                 1u << 27,
                                 0u - (1u << 27),
                                 0u - (1u << 27) - 1,
                                 0x7fffffffu,
                                 0x80000000u};
  for (const float step : {1e-4f, 0.37f, 3.0e5f}) {
    for (int run = 0; run < 200; ++run) {
      const std::uint32_t n = 1 + next() % 40;
      std::vector<std::uint32_t> d0(n), d1(n), out(n);
      std::vector<std::uint8_t> state(n);
      const bool valid = run % 2 == 0;  // half the runs hold valid steps only
      for (std::uint32_t t = 0; t < n; ++t) {
        const auto pick = [&]() -> std::uint32_t {
          if (valid) return static_cast<std::uint32_t>(static_cast<std::int32_t>(next() % (1u << 26)) - (1 << 25));
          return next() % 3 == 0 ? edges[next() % std::size(edges)] : static_cast<std::uint32_t>(next());
        };
        d0[t] = pick(), d1[t] = pick();
        state[t] = static_cast<std::uint8_t>(next() % 5);
      }
      pc::derive_run(out.data(), d0.data(), d1.data(), state.data(), n, step);
      for (std::uint32_t t = 0; t < n; ++t) {
        ASSERT_EQ(out[t], std::bit_cast<std::uint32_t>(pc::derived_value(d0[t], d1[t], state[t], step)))
            << "d0 " << d0[t] << " d1 " << d1[t] << " state " << int(state[t]) << " step " << step;
      }
    }
  }
}

}  // namespace
