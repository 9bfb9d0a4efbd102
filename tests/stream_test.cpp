// The streaming runtime on real cooked files: every frame it hands out equals a direct decode,
// whatever the cache size, codec, speed, looping or seeking; playback allocates nothing; IO
// starvation shows as stalls and recovers; faults end in a clean error state.
#include <gtest/gtest.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <future>
#include <random>
#include <thread>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "alloc_counter.hpp"
#include "capi/callback_io.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"
#include "particlestream/stream.hpp"
#include "test_io.hpp"
#include "test_util.hpp"

namespace {

using namespace pstream;
namespace fs = std::filesystem;

// The stream suite runs five times in each flavour of the test command: with its own IO, through
// the host's IO callbacks (synchronous and asynchronous), and over HTTP from nginx and from the
// fault-injecting server. Cooking its clips was most of each run under the sanitizers: each clip
// is cooked once per CTest run (test::shared_clip), under `name` and its attributes, which with
// the name make every option the helpers below set.
fs::path cook_once(const fs::path& dir, cook::Options o, std::string name) {
  for (const std::string& a : o.attributes) name += "-" + a;
  return test::shared_clip(name, dir / (name + ".pstream"), [&](const fs::path& out) {
    o.output = out;
    cook::cook(o);
  });
}

fs::path cook_fixture(const fs::path& dir, const std::string& fixture, format::Codec codec,
                      std::vector<std::string> attributes = {}, const std::string& object = {}) {
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.object = object;
  o.input = test::data_path("alembic/" + fixture + ".abc");
  o.chunk_size = format::kMinChunkSize;
  o.codec = codec;
  o.attributes = std::move(attributes);
  std::string name = fixture + "-" + std::string(format::codec_name(codec));
  for (const char c : object) name += c == '/' ? '-' : c;  // object "/grid": mesh_vertices-lz4-grid
  return cook_once(dir, std::move(o), std::move(name));
}

// The stream over the file through the IO the run asks for (PSTREAM_TEST_IO, tests/test_io.hpp),
// unless the test brings its own.
std::unique_ptr<stream::ParticleStream> open_stream(const fs::path& file, stream::StreamOptions o = {}) {
  if (!o.io) o.io = test::test_io(file);
  return stream::ParticleStream::open(file, std::move(o));
}

// The same fixture in the particle codec, a keyframe every `keyframes` frames, 64 KiB chunks (so
// packets straddle chunks and the ring's wrap).
fs::path cook_particle(const fs::path& dir, const std::string& fixture, std::vector<std::string> attributes = {},
                       std::uint32_t keyframes = 8) {
  cook::Options o;
  o.input = test::data_path(fixture);
  o.chunk_size = format::kMinChunkSize;
  o.frame_codec = format::FrameCodec::Particle;
  o.particle.keyframe_interval = keyframes;
  o.attributes = std::move(attributes);
  const fs::path source(fixture);
  return cook_once(dir, std::move(o),
                   source.parent_path().filename().string() + "-" + source.stem().string() + "-particle-k" +
                       std::to_string(keyframes));
}

// A synthetic clip: frame f holds `count(f)` records whose floats encode (f, i).
fs::path synthetic_clip(const fs::path& dir, std::uint64_t frames, double fps,
                        const std::function<std::uint64_t(std::uint64_t)>& count,
                        std::uint64_t chunk_size = format::kMinChunkSize) {
  format::Metadata meta;
  meta.fps = fps;
  meta.chunk_size = chunk_size;
  meta.layout = format::default_layout();
  const fs::path path = dir / "synthetic.pstream";
  format::Writer writer(path, meta);
  std::vector<std::byte> stream;
  for (std::uint64_t f = 0; f < frames; ++f) {
    const std::uint64_t n = count(f);
    writer.append_frame(n, double(f) / fps, {0, 0, 0, 1, 1, 1});
    for (std::uint64_t i = 0; i < n; ++i) {
      const float r[4] = {float(f), float(i), float(f * 1000 + i), 0.5f};
      const auto* b = reinterpret_cast<const std::byte*>(r);
      stream.insert(stream.end(), b, b + 16);
    }
  }
  for (std::size_t at = 0; at < stream.size(); at += chunk_size) {
    const std::span<const std::byte> raw(stream.data() + at, std::min<std::size_t>(chunk_size, stream.size() - at));
    writer.append_chunk(raw, format::Codec::Raw, 0, format::checksum(raw));
  }
  writer.commit();
  return path;
}

// Frames decoded directly, the reference the stream must match.
struct Reference {
  explicit Reference(const fs::path& path) : reader(format::Reader::open(path)) {
    const auto& m = reader.metadata();
    std::vector<std::byte> scratch(m.chunk_size);
    for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
      frames.emplace_back(m.frames[f].count * m.record_size);
      reader.read_frame(f, frames.back());
    }
  }
  format::Reader reader;
  std::vector<std::vector<std::byte>> frames;
};

::testing::AssertionResult frame_matches(const stream::ParticleStream& s, const Reference& ref,
                                         std::uint64_t expected_frame) {
  const stream::FrameView v = s.frame();
  if (!v.valid) {
    return ::testing::AssertionFailure() << "no frame"
                                         << (s.state() == stream::PlayState::Error ? ": " + s.error() : std::string());
  }
  if (v.frame != expected_frame)
    return ::testing::AssertionFailure() << "frame " << v.frame << ", expected " << expected_frame;
  const auto& want = ref.frames[expected_frame];
  if (v.bytes() != want.size()) return ::testing::AssertionFailure() << v.bytes() << " bytes, expected " << want.size();
  if (want.empty()) return ::testing::AssertionSuccess();  // an empty frame: no bytes, null spans
  if (std::memcmp(v.first.data(), want.data(), v.first.size()) != 0 ||
      (!v.second.empty() && std::memcmp(v.second.data(), want.data() + v.first.size(), v.second.size()) != 0)) {
    return ::testing::AssertionFailure() << "frame " << expected_frame << " bytes differ";
  }
  std::vector<std::byte> copy(v.bytes());
  s.copy_frame(copy);
  if (copy != want) return ::testing::AssertionFailure() << "copy_frame differs for frame " << expected_frame;
  return ::testing::AssertionSuccess();
}

stream::StreamOptions tiny_cache(bool blocking = true) {
  stream::StreamOptions o;
  o.max_slots = 2;  // raised to what a largest frame needs
  o.blocking = blocking;
  return o;
}

TEST(Stream, EveryCookedFileFrameByFrameWithATinyCache) {
  const fs::path dir = test::fresh_dir();
  const std::vector<fs::path> files = {
      cook_fixture(dir, "points_constant", format::Codec::Raw),
      cook_fixture(dir, "points_varying", format::Codec::Lz4, {"velocity", "id"}),  // 40-byte records
      cook_fixture(dir, "points_empty_frames", format::Codec::Zstd),
      cook_fixture(dir, "points_large", format::Codec::Zstd),
      cook_fixture(dir, "points_xform", format::Codec::Raw),
      cook_fixture(dir, "mesh_vertices", format::Codec::Lz4, {}, "/grid"),
      cook_particle(dir, "sims/blender_sparks.abc", {"velocity", "id"}),  // ordered by id
      cook_particle(dir, "sims/blender_flip_pour_small.abc"),             // matched by position
      cook_particle(dir, "alembic/points_large.abc")};
  std::uint64_t wraps = 0;
  for (const fs::path& file : files) {
    SCOPED_TRACE(file.filename().string());
    const Reference ref(file);
    const auto& m = ref.reader.metadata();
    auto s = open_stream(file, tiny_cache());
    EXPECT_EQ(s->debug().slots.size(), stream::cache_slots(m, 0.0));
    s->play();
    s->update(0);
    for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
      if (f > 0) s->update(1.0 / m.fps);
      ASSERT_TRUE(frame_matches(*s, ref, f));
      EXPECT_TRUE(s->frame().second.empty());  // a decoded frame is contiguous
    }
    wraps += s->debug().wrapped_packets;
    s->update(1.0 / m.fps);  // past the end: not looping, so it pauses on the last frame
    EXPECT_EQ(s->state(), stream::PlayState::Paused);
    ASSERT_TRUE(frame_matches(*s, ref, m.frame_count() - 1));
  }
  EXPECT_GT(wraps, 0u) << "no frame's packet crossed the ring's wrap";
}

// A blocking stream (offline rendering) asked for a frame several keyframe groups ahead jumps to
// that frame's keyframe and must still bring it. A chunk the ring kept for the decode under way at
// the jump used to stay where the next load was to go, and the stream waited forever (`pstream
// render --fps 0.2` of the demo clip; here some of these step and ring sizes). A watchdog turns a
// hang into a failure.
TEST(Stream, BlockingStepsOverSeveralKeyframeGroupsBringTheirFrames) {
  const fs::path dir = test::fresh_dir();
  const fs::path file = cook_particle(dir, "sims/blender_sparks.abc", {}, 4);  // a keyframe every 4 frames
  const Reference ref(file);
  const auto& m = ref.reader.metadata();
  auto run = std::async(std::launch::async, [&] {
    for (const std::uint64_t step : {5u, 9u, 13u, 21u, 30u}) {
      for (const std::size_t slots : {2u, 3u, 4u, 6u, 8u}) {
        SCOPED_TRACE(fmt::format("steps of {} frames, {} chunk slots", step, slots));
        stream::StreamOptions o;
        o.blocking = true;
        o.min_slots = o.max_slots = slots;
        auto s = open_stream(file, std::move(o));
        s->play();
        s->update(0);
        ASSERT_TRUE(frame_matches(*s, ref, 0));
        for (std::uint64_t f = step; f < m.frame_count(); f += step) {
          s->update(double(step) / m.fps);
          ASSERT_TRUE(frame_matches(*s, ref, f));
        }
      }
    }
  });
  if (run.wait_for(std::chrono::seconds(120)) != std::future_status::ready) {
    std::fprintf(stderr, "a blocking update() waited more than 120 s: the stream hangs\n");
    std::abort();  // the stream's threads cannot be stopped: end the run rather than hang it
  }
  run.get();
}

TEST(Stream, LoopingAndSpeed) {
  const fs::path dir = test::fresh_dir();
  for (const fs::path& file : {cook_fixture(dir, "points_varying", format::Codec::Raw),
                               cook_particle(dir, "alembic/points_varying.abc", {"velocity", "id"})}) {
    SCOPED_TRACE(file.filename().string());
    const Reference ref(file);
    const auto& m = ref.reader.metadata();
    const std::uint64_t n = m.frame_count();
    {
      auto s = open_stream(file, tiny_cache());
      s->set_loop(true);
      s->play();
      s->update(0);
      for (std::uint64_t k = 0; k < n * 5 / 2; ++k) {
        if (k > 0) s->update(1.0 / m.fps);
        ASSERT_TRUE(frame_matches(*s, ref, k % n)) << "step " << k;
      }
    }
    {
      auto s = open_stream(file, tiny_cache());
      s->set_loop(true);
      s->set_speed(2.5);
      s->play();
      s->update(0);
      for (std::uint64_t k = 1; k < 100; ++k) {
        s->update(1.0 / m.fps);
        // 2.5 frames a step: every other step lands half-way between frames, where rounding of
        // the accumulated time may go either way.
        const double t = std::fmod(2.5 * double(k), double(n));
        const auto lo = static_cast<std::uint64_t>(std::floor(t + 1e-6)) % n,
                   hi = static_cast<std::uint64_t>(std::ceil(t - 1e-6)) % n;
        const auto shown = s->frame().frame;
        ASSERT_TRUE(shown == lo || shown == hi) << "step " << k << " shows " << shown;
        ASSERT_TRUE(frame_matches(*s, ref, shown)) << "step " << k;
      }
    }
  }
}

TEST(Stream, TwoHundredRandomSeeks) {
  const fs::path dir = test::fresh_dir();
  for (const fs::path& file :
       {cook_fixture(dir, "points_large", format::Codec::Lz4), cook_particle(dir, "sims/blender_sparks.abc")}) {
    SCOPED_TRACE(file.filename().string());
    const Reference ref(file);
    const auto& m = ref.reader.metadata();
    stream::StreamOptions o = tiny_cache();
    o.scheduler = std::make_shared<stream::IoScheduler>(1);  // its own worker: decodes are counted alone
    auto s = open_stream(file, std::move(o));
    std::mt19937 rng(42);
    std::uniform_int_distribution<std::uint64_t> pick(0, m.frame_count() - 1);
    for (int i = 0; i < 200; ++i) {
      const std::uint64_t f = pick(rng);
      s->seek(m.frames[f].time + (i % 3 - 1) * 0.2 / m.fps);  // a little off the frame time: nearest
      EXPECT_TRUE(s->seeking());
      const std::uint64_t before = s->debug().frames_decoded;
      s->update(0);
      EXPECT_FALSE(s->seeking());
      ASSERT_TRUE(frame_matches(*s, ref, f)) << "seek " << i;
      // The cost of a seek: the frames from the keyframe up to the target, and the decoded ring
      // filling ahead (3 frames) — never more.
      const std::uint64_t decoded = s->debug().frames_decoded - before;
      EXPECT_LE(decoded, f - format::keyframe_of(m, f) + 1 + 3) << "seek " << i << " to frame " << f;
      if (m.codec.codec == format::FrameCodec::Particle) {
        EXPECT_LE(f - format::keyframe_of(m, f), 7u);
      }
    }
  }
}

// A seek whose first step goes backwards, before the seek's frame is shown: the target is then
// before where the restarted decoding publishes from, so decoding must restart again (found by
// the adversarial tree's C API host: a blocking update() waited forever).
TEST(Stream, ReverseStepRightAfterASeek) {
  const fs::path dir = test::fresh_dir();
  for (const fs::path& file :
       {cook_fixture(dir, "points_large", format::Codec::Lz4), cook_particle(dir, "sims/blender_sparks.abc")}) {
    SCOPED_TRACE(file.filename().string());
    const Reference ref(file);
    const auto& m = ref.reader.metadata();
    auto s = open_stream(file, tiny_cache(true));
    for (const std::uint64_t f : {std::uint64_t{15}, m.frame_count() / 2, m.frame_count() - 1, std::uint64_t{1}}) {
      s->seek(m.frames[f].time);
      s->play();  // the last frame's step forwards paused it
      s->set_speed(-1);
      s->update(1.0 / m.fps);
      EXPECT_FALSE(s->seeking());
      ASSERT_TRUE(frame_matches(*s, ref, f - 1)) << "seek to frame " << f << ", one frame back";
      s->set_speed(1);
      s->update(2.0 / m.fps);
      ASSERT_TRUE(frame_matches(*s, ref, f + 1 < m.frame_count() ? f + 1 : f)) << "and two forwards";
    }
  }
}

// Played backwards, frame by frame from the last to the first, or scrubbed back by seeks, a
// particle clip with long keyframe groups shows every frame exactly as decoded forwards, with a tiny chunk cache
// (decoding resumes mid-ring) and with a roomy one, interpolating or not. Without saved states each step back decodes
// from the keyframe, but a restart keeps the frames already decoded that the step needs and publishes the frame before
// its target when slots allow: fewer than two thirds of one walk from the keyframe to each frame. The decoder's saved
// states (3, the default) make that at least 3 times cheaper again. Then without blocking, at random host steps:
// whatever frame is shown is right.
TEST(Stream, ReversePlaybackResumesFromSavedStates) {
  const fs::path dir = test::fresh_dir();
  const fs::path file = cook_particle(dir, "sims/blender_sparks.abc", {}, 64);
  const Reference ref(file);
  const auto& m = ref.reader.metadata();
  ASSERT_GE(m.frame_count(), 40u);
  ASSERT_GT(format::FrameDecoder::saved_state_bytes(m), 0u);
  std::uint64_t walks = 0;  // each frame before the last decoded once from its keyframe
  for (std::uint64_t f = 0; f + 1 < m.frame_count(); ++f) walks += f - format::keyframe_of(m, f) + 1;
  // A blocking stream played from its last frame back to the first, one frame a step, every frame
  // checked: the stream, and the decodes it took.
  const auto play_back = [&](stream::StreamOptions o) {
    o.blocking = true;
    auto s = open_stream(file, std::move(o));
    s->seek(m.frames.back().time);
    s->update(0);
    EXPECT_TRUE(frame_matches(*s, ref, m.frame_count() - 1));
    const std::uint64_t before = s->debug().frames_decoded;
    s->set_speed(-1);
    s->play();
    for (std::uint64_t f = m.frame_count() - 1; f-- > 0;) {
      s->update(1.0 / m.fps);
      if (const auto shown = frame_matches(*s, ref, f); !shown) {
        ADD_FAILURE() << "going back: " << shown.message();
        break;
      }
    }
    const std::uint64_t decodes = s->debug().frames_decoded - before;
    return std::pair{std::move(s), decodes};
  };
  for (const bool tiny : {true, false}) {
    for (const bool interpolate : {false, true}) {
      std::uint64_t decodes[2] = {0, 0};
      std::uint64_t memory[2] = {0, 0};
      for (const std::size_t states : {std::size_t{0}, std::size_t{3}}) {
        SCOPED_TRACE(fmt::format("tiny cache {}, interpolate {}, {} saved states", tiny, interpolate, states));
        stream::StreamOptions o = tiny ? tiny_cache(true) : stream::StreamOptions{};
        o.interpolate = interpolate;
        o.saved_states = states;
        auto [s, going_back] = play_back(std::move(o));
        ASSERT_FALSE(HasFailure());
        decodes[states != 0] = going_back;
        memory[states != 0] = s->debug().decode_bytes;
        // Once more, counting allocations: saving and restoring states copies, never allocates.
        // (Not over HTTP: each restart cancels the reads under way, and libcurl allocates for the
        // connection it opens again.)
        s->seek(m.frames.back().time);
        s->update(0);
        s->play();  // reaching the first frame paused it
        const std::uint64_t allocations = test::allocation_count();
        for (std::uint64_t f = m.frame_count() - 1; f-- > 0;) s->update(1.0 / m.fps);
        if (std::string_view(test::io_mode()) != "http") {
          EXPECT_EQ(test::allocation_count(), allocations);
        }
        EXPECT_EQ(s->frame().frame, 0u);
      }
      std::cout << fmt::format(
          "{} frames backwards (tiny cache {}, interpolating {}): {} decodes without saved states ({} walks "
          "from the keyframe), {} with 3 ({:.2f} MiB more)\n",
          m.frame_count() - 1, tiny, interpolate, decodes[0], walks, decodes[1], (memory[1] - memory[0]) / 1048576.0);
      EXPECT_LT(decodes[0] * 3, walks * 2);
      EXPECT_LT(decodes[1] * 3, decodes[0]);
      EXPECT_EQ(memory[1] - memory[0], 3 * format::FrameDecoder::saved_state_bytes(m));
    }
  }
  // More decoded frames hold more of the frames decoded on the way to each step back's target,
  // published for the steps after it: fewer decodes, every frame still right.
  {
    std::uint64_t decodes[2] = {0, 0};
    for (const std::size_t frames : {std::size_t{3}, std::size_t{8}}) {
      SCOPED_TRACE(fmt::format("{} decoded frames", frames));
      stream::StreamOptions o;
      o.interpolate = true;
      o.decoded_frames = frames;
      decodes[frames != 3] = play_back(std::move(o)).second;
      ASSERT_FALSE(HasFailure());
    }
    std::cout << fmt::format("{} frames backwards with 3 saved states: {} decodes with 3 decoded frames, {} with 8\n",
                             m.frame_count() - 1, decodes[0], decodes[1]);
    EXPECT_LT(decodes[1] * 3, decodes[0] * 2);
  }
  // Scrubbing back, paused: a seek to each frame from the last to the first. The seeks save
  // states on the way to their frames too.
  {
    std::uint64_t decodes[2] = {0, 0};
    for (const std::size_t states : {std::size_t{0}, std::size_t{3}}) {
      stream::StreamOptions o = tiny_cache(true);
      o.saved_states = states;
      auto s = open_stream(file, std::move(o));
      const std::uint64_t before = s->debug().frames_decoded;
      for (std::uint64_t f = m.frame_count(); f-- > 0;) {
        s->seek(m.frames[f].time);
        s->update(0);
        ASSERT_TRUE(frame_matches(*s, ref, f)) << "scrubbing back, " << states << " saved states";
      }
      decodes[states != 0] = s->debug().frames_decoded - before;
    }
    std::cout << fmt::format("{} seeks back: {} decodes from keyframes, {} with 3 saved states\n", m.frame_count(),
                             decodes[0], decodes[1]);
    EXPECT_LT(decodes[1] * 2, decodes[0]);
  }
  // Without blocking: the host steps back at random, faster or slower than decoding, wrapping
  // from the first frame to the last.
  auto s = open_stream(file, tiny_cache(false));
  s->set_loop(true);
  s->seek(m.frames.back().time);
  s->set_speed(-1.5);
  s->play();
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> step(0.0, 2.0 / m.fps);
  std::uint64_t checked = 0;
  for (int k = 0; k < 2000 && s->state() == stream::PlayState::Playing; ++k) {
    s->update(step(rng));
    const auto v = s->frame();
    if (v.valid) {
      ASSERT_TRUE(frame_matches(*s, ref, v.frame)) << "host step " << k;
      ++checked;
    }
    std::this_thread::sleep_for(std::chrono::microseconds(300));
  }
  EXPECT_GT(checked, 1000u);
}

TEST(Stream, NonBlockingPlaybackAllocatesNothingAfterOpen) {
  const fs::path dir = test::fresh_dir();
  for (const fs::path& file : {cook_fixture(dir, "points_varying", format::Codec::Zstd, {"velocity"}),
                               cook_particle(dir, "alembic/points_varying.abc", {"velocity"})}) {
    SCOPED_TRACE(file.filename().string());
    const Reference ref(file);
    const auto& m = ref.reader.metadata();
    std::vector<std::byte> gpu_buffer(m.max_count * m.record_size);
    for (bool blocking : {false, true}) {
      auto s = open_stream(file, tiny_cache(blocking));
      std::vector<std::uint64_t> shown;
      shown.reserve(1000);
      const std::uint64_t before = test::allocation_count();
      s->play();
      for (int step = 0; step < 400 && s->state() == stream::PlayState::Playing; ++step) {
        s->update(1.0 / m.fps / 4);  // host frames at 4x the clip's rate
        const auto v = s->frame();
        if (v.valid) {
          s->copy_frame(gpu_buffer);
          shown.push_back(v.frame);
        }
        if (!blocking) std::this_thread::sleep_for(std::chrono::microseconds(500));
      }
      const std::uint64_t after = test::allocation_count();
      EXPECT_EQ(after, before) << "blocking=" << blocking << ": playback allocated " << (after - before) << " times";
      ASSERT_FALSE(shown.empty());
      EXPECT_EQ(shown.back(), m.frame_count() - 1);
      EXPECT_TRUE(std::is_sorted(shown.begin(), shown.end()));
    }
  }
}

// IO that delivers at most `bytes_per_second` (0: unlimited), adjustable while streaming.
class ThrottledIo final : public io::ByteSource {
 public:
  ThrottledIo(std::unique_ptr<io::ByteSource> inner, std::shared_ptr<std::atomic<double>> rate)
      : inner_(std::move(inner)), rate_(std::move(rate)) {}
  void read(std::uint64_t offset, std::span<std::byte> out) override {
    const auto t0 = std::chrono::steady_clock::now();
    inner_->read(offset, out);
    const double rate = rate_->load();
    if (rate > 0) std::this_thread::sleep_until(t0 + std::chrono::duration<double>(double(out.size()) / rate));
  }
  std::uint64_t size() const override { return inner_->size(); }
  const std::string& name() const override { return inner_->name(); }

 private:
  std::unique_ptr<io::ByteSource> inner_;
  std::shared_ptr<std::atomic<double>> rate_;
};

TEST(Stream, ExactBandwidthNoStallsHalfBandwidthStallsAndRecovers) {
  const fs::path dir = test::fresh_dir();
  const double fps = 30;
  const fs::path file = synthetic_clip(dir, 150, fps, [](std::uint64_t) { return 8192; });  // 128 KiB a frame
  const auto m = format::Reader::open(file).metadata();
  const double needed = double(m.stream_size()) / (double(m.frame_count()) / fps);  // bytes per second
  auto rate = std::make_shared<std::atomic<double>>(0.0);
  stream::StreamOptions o;
  o.cache_seconds = 0.5;  // half a second of lead
  o.io = std::make_unique<ThrottledIo>(test::test_io(file), rate);
  o.scheduler = std::make_shared<stream::IoScheduler>(1);
  auto s = open_stream(file, std::move(o));
  // Prime: fill the cache (1 s of frames) at full speed.
  while (s->debug().loads_done < s->debug().slots.size()) {
    s->update(0);
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  const auto play_for = [&](double seconds) {
    const auto start = std::chrono::steady_clock::now();
    auto last = start;
    while (std::chrono::steady_clock::now() - start < std::chrono::duration<double>(seconds) &&
           s->state() == stream::PlayState::Playing) {
      std::this_thread::sleep_for(std::chrono::duration<double>(1.0 / 120));  // a 120 Hz host
      const auto now = std::chrono::steady_clock::now();
      s->update(std::chrono::duration<double>(now - last).count());
      last = now;
    }
  };
  rate->store(needed * 1.02);  // what real time needs (2% for sleep granularity)
  s->play();
  play_for(1.5);
  EXPECT_EQ(s->debug().stalls, 0u) << "at the needed bandwidth";
  rate->store(needed * 0.5);
  play_for(1.5);
  const std::uint64_t starved = s->debug().stalls;
  EXPECT_GT(starved, 0u) << "at half the bandwidth";
  rate->store(0.0);  // bandwidth returns
  play_for(0.3);     // catch up
  const std::uint64_t caught_up = s->debug().stalls;
  play_for(0.6);
  EXPECT_EQ(s->debug().stalls, caught_up) << "no new stalls once the bandwidth is back";
  EXPECT_EQ(s->state(), stream::PlayState::Playing);
}

// IO that fails, or serves another file's bytes (the file replaced while streaming), from a chunk on.
class FaultyIo final : public io::ByteSource {
 public:
  enum class Fault { ReadError, Replaced };
  FaultyIo(std::unique_ptr<io::ByteSource> inner, std::uint64_t from_offset, std::uint64_t to_offset, Fault fault)
      : inner_(std::move(inner)), from_(from_offset), to_(to_offset), fault_(fault) {}
  void read(std::uint64_t offset, std::span<std::byte> out) override {
    inner_->read(offset, out);
    if (offset < from_ || offset >= to_) return;  // chunks from one on; header and tables stay intact
    if (fault_ == Fault::ReadError) throw Error(fmt::format("{}: injected read error at offset {}", name(), offset));
    for (auto& b : out) b = ~b;  // other bytes at the same place
  }
  std::uint64_t size() const override { return inner_->size(); }
  const std::string& name() const override { return inner_->name(); }

 private:
  std::unique_ptr<io::ByteSource> inner_;
  std::uint64_t from_, to_;
  Fault fault_;
};

void play_until_error(stream::ParticleStream& s) {
  s.play();
  for (int i = 0; i < 500 && s.state() != stream::PlayState::Error && s.state() != stream::PlayState::Paused; ++i) {
    s.update(1.0 / 24);
  }
}

TEST(StreamFaults, ChecksumMismatchReadErrorReplacedFileTruncation) {
  const fs::path dir = test::fresh_dir();
  const fs::path file = cook_fixture(dir, "points_constant", format::Codec::Raw);
  const auto m = format::Reader::open(file).metadata();
  const std::uint64_t chunk5 = m.chunks[5].file_offset;
  {  // a flipped byte on disk
    const fs::path bad = dir / "flipped.pstream";
    fs::copy_file(file, bad);
    std::fstream f(bad, std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(static_cast<std::streamoff>(chunk5 + 100));
    const char old = static_cast<char>(f.get());
    f.seekp(static_cast<std::streamoff>(chunk5 + 100));
    f.put(static_cast<char>(old ^ 0x40));  // a flip, whatever the byte was
    f.close();
    ASSERT_NE(test::read_text(bad), test::read_text(file));
    auto s = open_stream(bad, tiny_cache(true));  // blocking: every chunk is read
    play_until_error(*s);
    ASSERT_EQ(s->state(), stream::PlayState::Error);
    EXPECT_NE(s->error().find("chunk 5"), std::string::npos) << s->error();
    EXPECT_NE(s->error().find("checksum mismatch"), std::string::npos) << s->error();
    EXPECT_FALSE(s->frame().valid);
    s->update(0.1);  // the host keeps running
    s->close();
    s->close();
  }
  {  // a particle-coded clip: a replaced chunk fails its checksum before a packet is decoded
    const fs::path particle = cook_particle(dir, "sims/blender_sparks.abc");
    const auto pm = format::Reader::open(particle).metadata();
    ASSERT_GT(pm.chunk_count(), 2u);
    stream::StreamOptions o = tiny_cache(true);
    o.io = std::make_unique<FaultyIo>(test::test_io(particle), pm.chunks[2].file_offset,
                                      pm.chunks.back().file_offset + 1, FaultyIo::Fault::Replaced);
    auto s = open_stream(particle, std::move(o));
    play_until_error(*s);
    ASSERT_EQ(s->state(), stream::PlayState::Error);
    EXPECT_NE(s->error().find("chunk 2"), std::string::npos) << s->error();
    s->close();
  }
  for (auto fault : {FaultyIo::Fault::ReadError, FaultyIo::Fault::Replaced}) {
    stream::StreamOptions o = tiny_cache(true);
    o.io = std::make_unique<FaultyIo>(test::test_io(file), chunk5, m.chunks.back().file_offset + 1, fault);
    auto s = open_stream(file, std::move(o));
    play_until_error(*s);
    ASSERT_EQ(s->state(), stream::PlayState::Error);
    EXPECT_NE(s->error().find(fault == FaultyIo::Fault::ReadError ? "injected read error" : "chunk 5"),
              std::string::npos)
        << s->error();
    s->close();
  }
  {  // truncated, and not a .pstream at all: refused at open
    const fs::path cut = dir / "cut.pstream";
    fs::copy_file(file, cut);
    fs::resize_file(cut, fs::file_size(cut) / 2);
    EXPECT_THROW(open_stream(cut), Error);
    try {
      open_stream(test::data_path("alembic/points_constant.abc"));
      FAIL();
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("not a cooked clip; cook it first"), std::string::npos) << e.what();
    }
  }
}

// A host's IO callbacks that fail from an offset on: synchronously (`read` returns non-zero),
// asynchronously (the completion reports it), or refused (read_async returns non-zero). The
// header and tables (after the chunks) read fine.
struct FailingHostIo {
  std::vector<std::byte> bytes;
  std::uint64_t fail_from = 0, fail_to = 0;
  bool fails(std::uint64_t offset) const { return offset >= fail_from && offset <= fail_to; }
  static int read(void* user, std::uint64_t offset, void* out, std::uint64_t size) {
    auto* h = static_cast<FailingHostIo*>(user);
    if (h->fails(offset)) return 7;
    std::memcpy(out, h->bytes.data() + offset, size);
    return 0;
  }
  static int read_async(void* user, std::uint64_t offset, void* out, std::uint64_t size, pstream_io_done done,
                        void* token) {
    done(token, read(user, offset, out, size));
    return 0;
  }
  static int refuse_async(void* user, std::uint64_t offset, void* out, std::uint64_t size, pstream_io_done done,
                          void* token) {
    if (static_cast<FailingHostIo*>(user)->fails(offset)) return 9;
    done(token, read(user, offset, out, size));
    return 0;
  }
};

TEST(StreamFaults, HostIoCallbacksThatFailEndInACleanError) {
  const fs::path dir = test::fresh_dir();
  const fs::path file = cook_fixture(dir, "points_constant", format::Codec::Raw);
  const auto m = format::Reader::open(file).metadata();
  FailingHostIo host;
  const std::string text = test::read_text(file);
  host.bytes.resize(text.size());
  std::memcpy(host.bytes.data(), text.data(), text.size());
  host.fail_from = m.chunks[5].file_offset;
  host.fail_to = m.chunks.back().file_offset;
  struct Case {
    const char* what;
    bool sync, async, refuse;
    const char* expected;
  };
  for (const Case& c : {Case{"read", true, false, false, "status 7"},
                        Case{"read_async", true, true, false, "(chunk 5) failed with status 7"},
                        Case{"refused read_async", true, false, true, "refused"}}) {
    SCOPED_TRACE(c.what);
    pstream_io io{};
    io.user = &host;
    io.size = host.bytes.size();
    io.name = "pak://clip.pstream";
    io.read = c.sync ? &FailingHostIo::read : nullptr;
    io.read_async = c.async ? &FailingHostIo::read_async : c.refuse ? &FailingHostIo::refuse_async : nullptr;
    stream::StreamOptions o = tiny_cache(true);
    o.io = capi::callback_io(io);
    auto s = stream::ParticleStream::open(file, std::move(o));
    play_until_error(*s);
    ASSERT_EQ(s->state(), stream::PlayState::Error);
    EXPECT_NE(s->error().find("pak://clip.pstream"), std::string::npos) << s->error();
    EXPECT_NE(s->error().find(c.expected), std::string::npos) << s->error();
    EXPECT_NE(s->error().find(std::to_string(host.fail_from)), std::string::npos) << s->error();
    s->update(0.1);
    s->close();
  }
}

TEST(Stream, CacheSizingAndSharedMemoryBudget) {
  const fs::path dir = test::fresh_dir();
  const fs::path file = synthetic_clip(dir, 240, 60, [](std::uint64_t f) { return 4000 + f * 10; });  // T = 6390
  const auto m = format::Reader::open(file).metadata();
  // s = ceil(t * fps * T / p) with p = 65536 / 16 = 4096 particles per chunk.
  EXPECT_EQ(stream::cache_slots(m, 1.0), static_cast<std::size_t>(std::ceil(1.0 * 60 * 6390 / 4096.0)));
  EXPECT_EQ(stream::cache_slots(m, 0.5), static_cast<std::size_t>(std::ceil(0.5 * 60 * 6390 / 4096.0)));
  std::uint64_t span = 0;  // the most chunks one frame touches
  for (const auto& f : m.frames) {
    span = std::max(span, (f.byte_offset + f.count * 16 - 1) / m.chunk_size - f.byte_offset / m.chunk_size + 1);
  }
  EXPECT_EQ(span, 3u);
  EXPECT_EQ(stream::cache_slots(m, 0.0), span);
  EXPECT_EQ(stream::cache_slots(m, 1e6), m.chunk_count());  // never more than the clip
  const std::uint64_t one = stream::cache_slots(m, 1.0) * m.chunk_size;
  auto budget = std::make_shared<stream::MemoryBudget>(one + one / 2 + 4 * 6390 * 16);
  // One load in flight: over HTTP, more would size the cache from the latency measured at open
  // (4 round trips of playback), which a loaded machine can stretch past the second asked for.
  stream::StreamOptions a;
  a.max_loads_in_flight = 1;
  a.budget = budget;
  auto first = open_stream(file, std::move(a));
  EXPECT_EQ(first->debug().cache_bytes, one);
  // The decoded frames (3 of the largest frame) and a packet's staging count too.
  EXPECT_GE(first->debug().decode_bytes, 3 * 6390 * 16u);
  EXPECT_EQ(budget->used(), one + first->debug().decode_bytes);
  stream::StreamOptions b;
  b.max_loads_in_flight = 1;
  b.budget = budget;
  try {
    open_stream(file, std::move(b));
    FAIL() << "second cache fitted a budget too small for it";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("does not fit the memory budget"), std::string::npos) << e.what();
  }
  first.reset();
  EXPECT_EQ(budget->used(), 0u);
  stream::StreamOptions c;
  c.max_loads_in_flight = 1;
  c.budget = budget;
  EXPECT_NO_THROW(open_stream(file, std::move(c)));
}

TEST(Stream, SmallestCacheIsTwoSlots) {
  const fs::path dir = test::fresh_dir();
  const fs::path file = cook_fixture(dir, "points_constant", format::Codec::Raw);  // 16 KB frames, 64 KiB chunks
  auto s = open_stream(file, tiny_cache());
  EXPECT_EQ(s->debug().slots.size(), 2u);
}

TEST(Stream, StreamsShareOneScheduler) {
  const fs::path dir = test::fresh_dir();
  const fs::path a_file = cook_fixture(dir, "points_varying", format::Codec::Lz4);
  const fs::path b_file = cook_fixture(dir, "points_large", format::Codec::Raw);
  const Reference a_ref(a_file), b_ref(b_file);
  auto scheduler = std::make_shared<stream::IoScheduler>(1);  // one load in flight across both
  stream::StreamOptions ao = tiny_cache(), bo = tiny_cache();
  ao.scheduler = bo.scheduler = scheduler;
  auto a = open_stream(a_file, std::move(ao));
  auto b = open_stream(b_file, std::move(bo));
  a->play();
  b->play();
  a->update(0);
  b->update(0);
  for (std::uint64_t f = 1; f < 20; ++f) {
    a->update(1.0 / 30);
    b->update(1.0 / 24);
    ASSERT_TRUE(frame_matches(*a, a_ref, f));
    ASSERT_TRUE(frame_matches(*b, b_ref, f));
  }
}

TEST(Stream, DebugInfoRangeAndStop) {
  const fs::path dir = test::fresh_dir();
  const fs::path file = synthetic_clip(dir, 100, 25, [](std::uint64_t) { return 3000; });
  auto s = open_stream(file, tiny_cache());
  const auto d0 = s->debug();
  EXPECT_EQ(d0.slots.size(), stream::cache_slots(s->metadata(), 0.0));
  EXPECT_EQ(d0.cache_bytes, d0.slots.size() * s->metadata().chunk_size);
  s->set_range(s->metadata().frames[40].time, s->metadata().frames[49].time);
  s->set_loop(true);
  s->play();
  s->update(0);
  for (int k = 0; k < 25; ++k) {
    const auto v = s->frame();
    ASSERT_TRUE(v.valid);
    EXPECT_EQ(v.frame, 40u + k % 10) << k;
    float rec[4];
    std::memcpy(rec, v.first.data(), 16);
    EXPECT_EQ(rec[0], float(v.frame));  // the synthetic record encodes its frame
    s->update(1.0 / 25);
  }
  const auto d = s->debug();
  EXPECT_GT(d.loads_done, 0u);
  EXPECT_EQ(d.slots[d.read_slot].state, stream::SlotState::Ready);
  s->stop();
  s->update(0);
  EXPECT_EQ(s->state(), stream::PlayState::Stopped);
  EXPECT_EQ(s->frame().frame, 40u);
}

// `pstream bench stream --json` gives the host's cost a frame in wall time and in the host
// thread's CPU time: both there, each 99th percentile at or above its median, and the CPU time
// within the wall time (over the same interval a thread cannot run longer than the clock does).
// Not timings: those are the benchmark's.
TEST(Stream, BenchReportsTheHostCostInWallAndThreadCpuTime) {
  const auto r = test::run_cli("bench stream --particles 20000 --frames 8 --codec particle --laps 1 --json");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto j = nlohmann::json::parse(r.output.substr(r.output.find('{')));
  const double wall = j.at("frame_ms_median"), wall_p99 = j.at("frame_ms_p99");
  const double cpu = j.at("frame_cpu_ms_median"), cpu_p99 = j.at("frame_cpu_ms_p99");
  EXPECT_GT(cpu, 0.0);
  EXPECT_GE(wall_p99, wall);
  EXPECT_GE(cpu_p99, cpu);
  EXPECT_LE(cpu, wall + 0.01) << r.output;
}

}  // namespace

// ---- Remote streaming (run by StreamOverHttp.faulty: tests/http/with_server.sh faulty) ----------

namespace {

bool fault_server() {
  const char* server = std::getenv("PSTREAM_TEST_SERVER");
  return server != nullptr && std::string(server) == "faulty";
}

// A clip with many chunks, larger than the source's prefix (so chunk loads are range requests).
fs::path remote_clip(const fs::path& dir) {
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;
  o.input = test::data_path("alembic/points_large.abc");
  o.output = dir / "remote.pstream";
  o.chunk_size = format::kMinChunkSize;
  o.codec = format::Codec::Lz4;
  cook::cook(o);
  return o.output;
}

io::HttpOptions quick() {  // faults end in seconds
  io::HttpOptions o;
  o.retries = 3;
  o.retry_base_seconds = 0.02;
  o.stall_timeout_seconds = 1;
  o.connect_timeout_seconds = 2;
  return o;
}

// Plays the whole clip in blocking mode; the stream's state at the end.
stream::PlayState play_through(stream::ParticleStream& s, const Reference* ref) {
  const auto& m = s.metadata();
  s.play();
  s.update(0);
  for (std::uint64_t f = 0; f < m.frame_count() && s.state() != stream::PlayState::Error; ++f) {
    if (f > 0) s.update(1.0 / m.fps);
    if (ref != nullptr && s.state() != stream::PlayState::Error) {
      EXPECT_TRUE(frame_matches(s, *ref, f));
    }
  }
  return s.state();
}

}  // namespace

TEST(Http, TransientFaultsAreRetriedAndTheFramesAreExact) {
  if (!fault_server()) GTEST_SKIP() << "needs tests/http/with_server.sh faulty (CTest: StreamOverHttp.faulty)";
  const fs::path dir = test::fresh_dir();
  const fs::path file = remote_clip(dir);
  const Reference ref(file);
  for (const std::string faults : {"/~fail=503x3", "/~fail=500x2", "/~drop=3", "/~latency=20/~rate=20000000"}) {
    SCOPED_TRACE(faults);
    stream::StreamOptions o = tiny_cache(true);
    o.io = io::open_url(test::test_url(file, faults), quick());
    const io::ByteSource* source = o.io.get();
    auto s = stream::ParticleStream::open(file, std::move(o));
    EXPECT_NE(play_through(*s, &ref), stream::PlayState::Error) << s->error();
    const io::SourceStats st = source->stats();
    EXPECT_GT(st.requests, 10u);
    EXPECT_GT(s->debug().source.requests, 10u);  // the stream passes the source's counts on (the viewer shows them)
    if (faults.find("fail") != std::string::npos || faults.find("drop") != std::string::npos) {
      EXPECT_GE(st.retries, 2u);
    }
  }
  // The format's reader over a URL: every frame equal to the file's.
  const format::Reader remote = format::Reader::open(io::open_url(test::test_url(file, "/~fail=503x1"), quick()));
  std::vector<std::byte> frame;
  for (std::uint64_t f = 0; f < ref.frames.size(); ++f) {
    frame.resize(ref.frames[f].size());
    remote.read_frame(f, frame);
    ASSERT_EQ(frame, ref.frames[f]) << "frame " << f;
  }
}

TEST(Http, FaultsEndInTheErrorStateNamingTheUrl) {
  if (!fault_server()) GTEST_SKIP() << "needs tests/http/with_server.sh faulty (CTest: StreamOverHttp.faulty)";
  const fs::path dir = test::fresh_dir();
  const fs::path file = remote_clip(dir);
  const struct {
    const char* faults;
    const char* message;
  } cases[] = {
      {"/~full200=1", "200 with the whole file instead of 206"},
      {"/~change=3", "the file changed since it was opened"},
      {"/~short=1", "after 3 retries"},
      {"/~hang=1", "(after 1 retry)"},  // a stall is retried once (stall_retries)
      {"/~garbage=1", "HTTP/0.9"},      // libcurl's words for a reply that is no HTTP
      {"/~infinite=1", "longer than the"},
      {"/~fail=503x100", "HTTP 503 (after 3 retries)"},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.faults);
    const std::string url = test::test_url(file, c.faults);
    const auto started = std::chrono::steady_clock::now();
    try {
      stream::StreamOptions o = tiny_cache(true);
      o.io = io::open_url(url, quick());
      auto s = stream::ParticleStream::open(file, std::move(o));
      EXPECT_EQ(play_through(*s, nullptr), stream::PlayState::Error);
      EXPECT_NE(s->error().find(url), std::string::npos) << s->error();
      EXPECT_NE(s->error().find(c.message), std::string::npos) << s->error();
      EXPECT_NE(s->error().find("(chunk "), std::string::npos) << s->error();
    } catch (const Error& e) {  // a fault on the open's own requests
      EXPECT_NE(std::string(e.what()).find(url), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(c.message), std::string::npos) << e.what();
    }
    EXPECT_LT(std::chrono::steady_clock::now() - started, std::chrono::seconds(30)) << "a fault must not hang";
  }
  // A file that is not there, and a server that is not there.
  EXPECT_THROW(
      {
        try {
          io::open_url(test::test_url(dir / "missing.pstream"), quick());
        } catch (const Error& e) {
          EXPECT_NE(std::string(e.what()).find("HTTP 404"), std::string::npos) << e.what();
          throw;
        }
      },
      Error);
  EXPECT_THROW(io::open_url("http://127.0.0.1:1/x.pstream", quick()), Error);
}

// A seek ends the remote reads it made useless (they would otherwise hold the connections while
// the new position waits): over a slow link, the loads in flight at the seek are cancelled, and
// the frame after it is exact.
TEST(Http, ASeekCancelsTheReadsItMadeUseless) {
  if (!fault_server()) GTEST_SKIP() << "needs tests/http/with_server.sh faulty (CTest: StreamOverHttp.faulty)";
  const fs::path dir = test::fresh_dir();
  const fs::path file = remote_clip(dir);
  const Reference ref(file);
  stream::StreamOptions o;
  o.blocking = true;
  o.cache_seconds = 2.0;  // many chunks ahead, each slow to come
  o.io = io::open_url(test::test_url(file, "/~rate=400000"), quick());
  const io::ByteSource* source = o.io.get();
  auto s = stream::ParticleStream::open(file, std::move(o));
  const auto& m = s->metadata();
  s->play();
  s->update(0);
  ASSERT_TRUE(frame_matches(*s, ref, 0));
  ASSERT_GT(s->debug().loads_in_flight, 1u);  // reads under way ahead of the playhead
  const std::uint64_t target = m.frame_count() - 2;
  s->seek(m.frames[target].time);
  s->update(0);
  ASSERT_NE(s->state(), stream::PlayState::Error) << s->error();
  EXPECT_TRUE(frame_matches(*s, ref, target));
  EXPECT_GE(source->stats().cancelled, 1u);
  std::printf("seek over a slow link: %llu reads cancelled\n",
              static_cast<unsigned long long>(source->stats().cancelled));
}

// Reads waiting for a connection go out as one request when their ranges are neighbours (at most
// merge_gap apart, the bytes between dropped): each read gets exactly its bytes, a far read keeps
// its own request, and a read cancelled while riding in a merged request fails alone.
TEST(Http, NeighbouringReadsShareOneRequest) {
  if (!fault_server()) GTEST_SKIP() << "needs tests/http/with_server.sh faulty (CTest: StreamOverHttp.faulty)";
  const fs::path dir = test::fresh_dir();
  const fs::path file = remote_clip(dir);
  std::vector<std::byte> whole(fs::file_size(file));
  std::ifstream(file, std::ios::binary)
      .read(reinterpret_cast<char*>(whole.data()), static_cast<std::streamsize>(whole.size()));
  io::HttpOptions ho = quick();
  ho.connections = 1;  // the first read holds the connection; the others queue behind it
  auto source = io::open_url(test::test_url(file, "/~latency=150"), ho);
  ASSERT_GT(whole.size(), 2u << 20);
  struct Read {
    std::uint64_t offset, size;
    std::vector<std::byte> out;
    std::atomic<int> status{-1};
  };
  const std::uint64_t base = 1u << 20;  // past the prefix fetched at open
  std::array<Read, 5> reads = {{{base, 1000, {}},
                                {base + 5000, 3000, {}},                // 4,000 B after the first
                                {base + 8000, 4096, {}},                // right after the one before
                                {base + 8000 + 4096 + 30000, 512, {}},  // 30,000 B after it (dropped)
                                {base + (1u << 20), 700, {}}}};         // 1 MiB on: its own request
  const auto done = [](void* context, int status) { static_cast<Read*>(context)->status.store(status); };
  // The first read goes out alone and holds the connection for 150 ms; the others queue behind
  // it, and when it is done its three neighbours go out as one request (the far one after them).
  // The third read is cancelled while its merged request is under way. A machine slow enough to
  // shift these moments changes which reads share a request, not what the test checks.
  for (std::size_t i = 0; i < reads.size(); ++i) {
    Read& r = reads[i];
    r.out.assign(r.size, std::byte{0xEE});
    ASSERT_TRUE(source->start_read(r.offset, r.out, done, &r));
    if (i == 0) std::this_thread::sleep_for(std::chrono::milliseconds(40));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(180));
  source->cancel(&reads[2]);  // under way or queued, merged or not: it alone fails
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  for (const Read& r : reads) {
    while (r.status.load() < 0 && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
  }
  for (std::size_t i = 0; i < reads.size(); ++i) {
    const Read& r = reads[i];
    SCOPED_TRACE(i);
    if (i == 2) {
      EXPECT_GT(r.status.load(), 0);
      EXPECT_NE(source->failure_message(r.status.load()).find("cancelled"), std::string::npos)
          << source->failure_message(r.status.load());
      continue;
    }
    ASSERT_EQ(r.status.load(), 0) << source->failure_message(r.status.load());
    EXPECT_TRUE(std::equal(r.out.begin(), r.out.end(), whole.begin() + static_cast<std::ptrdiff_t>(r.offset)));
  }
  const io::SourceStats st = source->stats();
  // After the probe at open, every read went out in a request of its own, rode in another's
  // (merged), or was ended before it went out (cancelled). The second and fourth reads always
  // share one (30,000 bytes apart); the far read never shares: 2 or 3 requests after the open's.
  EXPECT_EQ(st.requests - 1 + st.merged + st.cancelled, reads.size());
  EXPECT_GE(st.merged, 1u);
  EXPECT_GE(st.requests, 3u);
  EXPECT_LE(st.requests, 4u);
  std::printf(
      "5 reads: %llu requests after the open's, %llu reads merged, %llu ended before they went out (the "
      "cancelled read %s)\n",
      static_cast<unsigned long long>(st.requests - 1), static_cast<unsigned long long>(st.merged),
      static_cast<unsigned long long>(st.cancelled),
      st.cancelled == 0 ? "rode in a merged request" : "was still queued");
}

// A clip of small chunks streamed over a slow round trip: the stream queues several loads per
// connection, and neighbouring loads share requests; every frame is still exact.
TEST(Http, SmallChunksMergeIntoFewerRequests) {
  if (!fault_server()) GTEST_SKIP() << "needs tests/http/with_server.sh faulty (CTest: StreamOverHttp.faulty)";
  const fs::path dir = test::fresh_dir();
  const fs::path file = remote_clip(dir);  // 64 KiB chunks
  const Reference ref(file);
  stream::StreamOptions o;
  o.blocking = true;
  o.io = io::open_url(test::test_url(file, "/~latency=40"), quick());
  const io::ByteSource* source = o.io.get();
  EXPECT_EQ(source->preferred_reads_in_flight(format::kMinChunkSize), 24u);  // 6 connections x 4
  EXPECT_EQ(source->preferred_reads_in_flight(format::kDefaultChunkSize), 6u);
  auto s = stream::ParticleStream::open(file, std::move(o));
  EXPECT_NE(play_through(*s, &ref), stream::PlayState::Error) << s->error();
  const io::SourceStats st = source->stats();
  const std::uint64_t loads = s->debug().loads_done;
  EXPECT_GT(st.merged, 0u);
  EXPECT_LT(st.requests, loads);
  std::printf("%llu chunk loads in %llu requests (%llu merged)\n", static_cast<unsigned long long>(loads),
              static_cast<unsigned long long>(st.requests), static_cast<unsigned long long>(st.merged));
}

// An Alembic cache at a URL: info, cook, verify --against and bench codec read it whole into
// memory (alembic::Archive over the URL's byte source). The cook is the local cook's, byte for
// byte: a clip records its source's file name and content hash, not where it was read. A
// transient fault is retried; a missing file, and a PLY sequence (found by listing its folder),
// get their errors.
TEST(Http, AlembicCachesAreReadFromAUrl) {
  if (!fault_server()) GTEST_SKIP() << "needs tests/http/with_server.sh faulty (CTest: StreamOverHttp.faulty)";
  const fs::path dir = test::fresh_dir();
  const std::string abc = test::data_path("sims/blender_sparks.abc");
  const std::string url = test::test_url(abc);
  const auto strip = [](std::string s, const std::string& name) {
    for (std::size_t at; (at = s.find(name)) != std::string::npos;) s.erase(at, name.size());
    return s;
  };
  const auto local_info = test::run_cli("info '" + abc + "' --json");
  const auto remote_info = test::run_cli("info '" + url + "' --json");
  ASSERT_EQ(remote_info.exit_code, 0) << remote_info.output;
  EXPECT_EQ(strip(remote_info.output, url), strip(local_info.output, abc));
  const fs::path local = dir / "local.pstream", remote = dir / "remote.pstream";
  ASSERT_EQ(test::run_cli("cook '" + abc + "' -o '" + local.string() + "' -q").exit_code, 0);
  const auto cooked =
      test::run_cli("cook '" + test::test_url(abc, "/~fail=503x1") + "' -o '" + remote.string() + "' -q");
  ASSERT_EQ(cooked.exit_code, 0) << cooked.output;
  EXPECT_EQ(test::read_text(remote), test::read_text(local));
  // The library's cook reports the fetch (bytes) before its frames.
  cook::Options o;
  o.input = url;
  o.output = dir / "library.pstream";
  std::vector<cook::Progress> seen;
  cook::cook(o, [&](const cook::Progress& p) { seen.push_back(p); });
  ASSERT_FALSE(seen.empty());
  EXPECT_EQ(seen.front().stage, cook::Stage::Fetch);
  const auto last_fetch =
      std::find_if(seen.rbegin(), seen.rend(), [](const auto& p) { return p.stage == cook::Stage::Fetch; });
  ASSERT_NE(last_fetch, seen.rend());
  EXPECT_EQ(last_fetch->bytes_in, fs::file_size(abc));
  EXPECT_EQ(last_fetch->bytes_total, fs::file_size(abc));
  EXPECT_EQ(std::find_if(seen.begin(), last_fetch.base(), [](const auto& p) { return p.stage != cook::Stage::Fetch; }),
            last_fetch.base());  // no frame before the fetch ends
  EXPECT_EQ(test::read_text(o.output), test::read_text(local));
  const auto verified = test::run_cli("verify '" + remote.string() + "' --against '" + url + "'");
  EXPECT_EQ(verified.exit_code, 0) << verified.output;
  EXPECT_NE(verified.output.find("every value within its bound"), std::string::npos) << verified.output;
  const auto bench = test::run_cli("bench codec '" + url + "' --frames 2 --repetitions 1 --codec raw --json");
  EXPECT_EQ(bench.exit_code, 0) << bench.output;
  test::expect_error(
      test::run_cli("cook '" + test::test_url(dir / "nope.abc") + "' -o '" + (dir / "x.pstream").string() + "'"),
      "HTTP 404");
  test::expect_error(
      test::run_cli("cook '" + test::test_url(dir / "frame.0001.ply") + "' -o '" + (dir / "x.pstream").string() + "'"),
      "read from local files");
  EXPECT_FALSE(fs::exists(dir / "x.pstream"));
}

TEST(Http, CommandsTakeUrls) {
  if (!fault_server()) GTEST_SKIP() << "needs tests/http/with_server.sh faulty (CTest: StreamOverHttp.faulty)";
  const fs::path dir = test::fresh_dir();
  const fs::path file = remote_clip(dir);
  const std::string url = test::test_url(file);
  const auto verify = test::run_cli("verify '" + url + "'");
  EXPECT_EQ(verify.exit_code, 0) << verify.output;
  EXPECT_NE(verify.output.find("OK"), std::string::npos) << verify.output;
  const auto local = test::run_cli("info '" + file.string() + "' --json --frames");
  const auto remote = test::run_cli("info '" + url + "' --json --frames");
  ASSERT_EQ(remote.exit_code, 0) << remote.output;
  auto strip = [](std::string s, const std::string& name) {  // the file's name differs, nothing else
    for (std::size_t at; (at = s.find(name)) != std::string::npos;) s.erase(at, name.size());
    return s;
  };
  EXPECT_EQ(strip(remote.output, url), strip(local.output, file.string()));
  const auto exported = test::run_cli("export '" + url + "' --out '" + (dir / "ply").string() + "' -q");
  EXPECT_EQ(exported.exit_code, 0) << exported.output;
  EXPECT_TRUE(fs::exists(dir / "ply"));
  const auto bench = test::run_cli("bench stream '" + url + "' --laps 1 --json");
  EXPECT_EQ(bench.exit_code, 0) << bench.output;
  const auto missing = test::run_cli("verify '" + test::test_url(dir / "nope.pstream") + "'");
  EXPECT_NE(missing.exit_code, 0);
  EXPECT_NE(missing.output.find("HTTP 404"), std::string::npos) << missing.output;
}
