// The GPU playback path (playback::PlaybackPath::Gpu, render::Renderer's compute passes) against
// the CPU path on Mesa's llvmpipe, through the Player on real cooked fixtures: every interpolated
// value within 2 ulps (or 1e-6 relative), ids and colours exact; the GPU order a permutation with
// monotonic depths that equals the CPU order wherever keys differ; images equal within the golden
// tolerance for sprites, shadows, motion blur, the liquid and two merged clips; nothing uploaded
// between cached frames, and no allocation per host frame in the Player.
#include <gtest/gtest.h>

#include <epoxy/gl.h>

#include <algorithm>
#include <array>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <numeric>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "alloc_counter.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/playback.hpp"
#include "particlestream/render.hpp"
#include "particlestream/sort.hpp"
#include "playback/interpolate.hpp"
#include "test_util.hpp"

namespace {

using namespace pstream;
namespace fs = std::filesystem;

// The fixtures, cooked once per test run.
struct Clips {
  fs::path sparks_records, sparks_particle, flip_particle, sparks_no_ids;
};
const Clips& clips() {
  static const Clips c = [] {
    // A folder of their own (each test's process cooks them; the test's folder is its own).
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    const fs::path dir = test::fresh_dir(std::string("GpuPlaybackClips.") + info->name());
    Clips out;
    cook::Options o;
    o.input = test::data_path("sims/blender_sparks.abc");
    o.output = out.sparks_records = dir / "sparks_records.pstream";
    o.attributes = {"velocity", "id"};
    o.frame_begin = 18;
    o.frame_end = 26;
    cook::cook(o);
    o.output = out.sparks_particle = dir / "sparks_particle.pstream";
    cook::set_codec(o, "particle");
    o.attributes = {"velocity", "id"};
    cook::cook(o);
    cook::Options r;  // records without ids: nothing to match by, the nearer frame moved
    r.input = o.input;
    r.output = out.sparks_no_ids = dir / "sparks_no_ids.pstream";
    r.attributes = {"velocity"};
    r.frame_begin = 18;
    r.frame_end = 26;
    cook::cook(r);
    cook::Options f;
    f.input = test::data_path("sims/blender_flip_pour_small.abc");
    f.output = out.flip_particle = dir / "flip_particle.pstream";  // no ids: the codec's matching
    cook::set_codec(f, "particle");
    f.frame_begin = 20;
    f.frame_end = 26;
    cook::cook(f);
    return out;
  }();
  return c;
}

std::vector<std::byte> read_buffer(GLenum target, GLuint index, std::uint64_t bytes) {
  GLint buffer = 0;
  GLint64 start = 0;
  glGetIntegeri_v(target, index, &buffer);
  glGetInteger64i_v(GL_SHADER_STORAGE_BUFFER_START, index, &start);
  std::vector<std::byte> out(bytes);
  glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
  if (bytes) glGetNamedBufferSubData(GLuint(buffer), GLintptr(start), GLsizeiptr(bytes), out.data());
  return out;
}

bool close(float gpu, float cpu) {
  if (std::bit_cast<std::uint32_t>(gpu) == std::bit_cast<std::uint32_t>(cpu)) return true;
  if (!std::isfinite(gpu) || !std::isfinite(cpu)) return false;
  const auto ulps = std::abs(std::int64_t(std::bit_cast<std::int32_t>(gpu)) - std::bit_cast<std::int32_t>(cpu));
  return ulps <= 2 || std::abs(gpu - cpu) <= 1e-6f * std::max(std::abs(cpu), 1.0f);
}

std::unique_ptr<playback::Player> open(const fs::path& file, playback::PlaybackPath path, double speed) {
  playback::PlayerOptions o;
  o.stream.blocking = true;
  o.loop = false;
  o.path = path;
  const fs::path files[] = {file};
  auto p = playback::Player::open(files, std::move(o));
  p->set_speed(speed);
  if (speed < 0) p->seek(p->clip(0).metadata().frames.back().time);
  p->play();
  return p;
}

// Plays `file` on both paths at 120 Hz and `speed`, comparing every host frame's records and order.
void expect_paths_agree(const fs::path& file, double speed, bool expect_between = true) {
  SCOPED_TRACE(fmt::format("{} at speed {}", file.filename().string(), speed));
  render::HeadlessContext context(64, 64);
  context.bind();
  const auto cpu = open(file, playback::PlaybackPath::Cpu, speed);
  const auto gpu = open(file, playback::PlaybackPath::Gpu, speed);
  render::RendererOptions ro;
  ro.max_bytes_per_frame = gpu->max_frame_bytes();
  render::Renderer renderer(ro);
  const format::Metadata& m = cpu->clip(0).metadata();
  const std::vector<render::RecordLane> lanes = playback::record_lanes(m);
  const render::Camera camera{{0.5f, 2.0f, 4.0f}, {0, 0.5f, 0}, {0, 1, 0}};
  const playback::DrawStyle style;
  std::size_t between = 0, compared_values = 0, orders_compared = 0;
  for (int k = 0; k < 40; ++k) {
    const double dt = k == 0 ? 0.0 : 1.0 / 120;
    cpu->advance(dt, camera.view(), sort::SortMode::BackToFront);
    gpu->advance(dt, camera.view(), sort::SortMode::BackToFront);
    ASSERT_EQ(cpu->batches().size(), gpu->batches().size());
    if (cpu->batches().empty()) continue;
    const render::ParticleBatch& c = cpu->batches()[0];
    const render::ParticleBatch& g = gpu->batches()[0];
    ASSERT_EQ(c.count, g.count) << "host frame " << k;
    ASSERT_NE(g.pair, nullptr);
    between += !g.pair->pairs.empty();
    renderer.begin_frame(64, 64, camera, {0, 0, 0, 1});
    renderer.prepare(gpu->draw_data(style));
    const std::vector<std::byte> records = read_buffer(GL_SHADER_STORAGE_BUFFER_BINDING, 0, g.count * m.record_size);
    const std::vector<std::byte> order_bytes = read_buffer(GL_SHADER_STORAGE_BUFFER_BINDING, 1, g.count * 4);
    renderer.end_frame();
    // Values. Floats within 2 ulps, or 1e-6 of the magnitude of the terms the kernels sum (they
    // cancel: a velocity between frames is the difference of positions over dt, a position sums
    // positions and velocities times dt); ids, colours and other integers bit for bit.
    const double fps = g.pair->dt > 0 ? 1.0 / g.pair->dt : m.fps;
    std::size_t bad = 0;
    for (std::uint64_t i = 0; i < c.count; ++i) {
      const std::byte* cr = c.first.data() + i * m.record_size;
      float p[3];
      std::memcpy(p, cr, 12);
      const double magnitude = std::max({std::abs(p[0]), std::abs(p[1]), std::abs(p[2]), 1.0f});
      for (std::size_t w = 0; w < lanes.size(); ++w) {
        std::uint32_t a = 0, b = 0;
        std::memcpy(&a, records.data() + i * m.record_size + w * 4, 4);
        std::memcpy(&b, cr + w * 4, 4);
        bool ok = a == b;
        if (!ok && lanes[w] != render::RecordLane::Copy) {
          const float fg = std::bit_cast<float>(a), fc = std::bit_cast<float>(b);
          const double terms = lanes[w] == render::RecordLane::Velocity ? magnitude * 1.5 * fps : magnitude;
          ok = close(fg, fc) || std::abs(double(fg) - double(fc)) <= 1e-6 * std::max(terms, double(std::abs(fc)));
        }
        if (!ok && ++bad <= 3) {
          ADD_FAILURE() << "host frame " << k << " particle " << i << " word " << w << ": gpu "
                        << std::bit_cast<float>(a) << " cpu " << std::bit_cast<float>(b);
        }
        ++compared_values;
      }
    }
    ASSERT_EQ(bad, 0u);
    // Order: a permutation, depths monotonic (back to front), the CPU's wherever keys differ.
    std::vector<std::uint32_t> order(g.count);
    std::memcpy(order.data(), order_bytes.data(), order_bytes.size());
    std::vector<std::uint32_t> sorted = order;
    std::sort(sorted.begin(), sorted.end());
    for (std::uint32_t i = 0; i < g.count; ++i) ASSERT_EQ(sorted[i], i) << "not a permutation";
    const sort::DepthAxis axis = sort::depth_axis(camera.view());
    const auto depth = [&](const std::byte* recs, std::uint32_t i) {
      float p[3];
      std::memcpy(p, recs + std::uint64_t(i) * m.record_size, 12);
      return p[0] * axis.x + p[1] * axis.y + p[2] * axis.z + axis.offset;
    };
    for (std::uint64_t i = 1; i < g.count; ++i)
      ASSERT_GE(depth(records.data(), order[i - 1]), depth(records.data(), order[i])) << "depth order at " << i;
    ASSERT_EQ(c.order.size(), g.count);
    for (std::uint64_t i = 0; i < g.count; ++i) {
      if (order[i] == c.order[i]) continue;
      // Where they differ, the two particles' CPU keys must be equal (a tie ordered differently
      // only because a GPU value is an ulp away).
      const float dg = depth(c.first.data(), order[i]), dc = depth(c.first.data(), c.order[i]);
      ASSERT_LE(std::abs(dg - dc), 4e-7f * std::max(1.0f, std::abs(dc))) << "order differs at " << i;
    }
    ++orders_compared;
  }
  if (expect_between) {
    EXPECT_GT(between, 5u) << "few host frames fell between cached frames";
  }
  EXPECT_GT(compared_values, 1000u);
  EXPECT_GT(orders_compared, 10u);
}

TEST(GpuPlayback, RecordsClipWithIdsEqualsTheCpuPath) { expect_paths_agree(clips().sparks_records, 1.0); }
TEST(GpuPlayback, ParticleCodecClipEqualsTheCpuPath) { expect_paths_agree(clips().sparks_particle, 1.0); }
TEST(GpuPlayback, ParticleCodecWithoutIdsEqualsTheCpuPath) { expect_paths_agree(clips().flip_particle, 1.0); }
TEST(GpuPlayback, UnmatchedClipEqualsTheCpuPath) { expect_paths_agree(clips().sparks_no_ids, 1.0); }
TEST(GpuPlayback, SlowMotionAndReverseEqualTheCpuPath) {
  expect_paths_agree(clips().sparks_particle, 0.25);
  expect_paths_agree(clips().sparks_records, -1.0);
  expect_paths_agree(clips().flip_particle, -0.5);
}

// The sparks cooked with the records codec (ids) on the GPU path, a renderer for it, and one host
// frame at 120 Hz drawn through both.
struct SparksOnTheGpu {
  render::HeadlessContext context{64, 64};
  std::unique_ptr<playback::Player> gpu;
  std::unique_ptr<render::Renderer> renderer;
  render::Camera camera;
  SparksOnTheGpu() {
    context.bind();
    gpu = open(clips().sparks_records, playback::PlaybackPath::Gpu, 1.0);
    render::RendererOptions ro;
    ro.max_bytes_per_frame = gpu->max_frame_bytes();
    renderer = std::make_unique<render::Renderer>(ro);
  }
  const format::Metadata& metadata() const { return gpu->clip(0).metadata(); }
  render::RendererStats host_frame(int k) {
    gpu->advance(k == 0 ? 0.0 : 1.0 / 120, camera.view(), sort::SortMode::BackToFront);
    renderer->begin_frame(64, 64, camera, {0, 0, 0, 1});
    renderer->prepare(gpu->draw_data({}));
    renderer->end_frame();
    return renderer->stats();
  }
};

// While the pair of cached frames stays, the host thread uploads nothing; when it changes, at most
// one frame's records and the pair table (8 bytes a particle); the CPU path uploads the whole frame
// every host frame.
TEST(GpuPlayback, UploadsOncePerCachedFrame) {
  SparksOnTheGpu rig;
  const format::Metadata& m = rig.metadata();
  // What the host frame draws: the pair of cached frames and the table's version.
  std::array<std::uint64_t, 3> last{~0ull, ~0ull, ~0ull};
  std::uint64_t steady = 0, changes = 0;
  for (int k = 0; k < 40; ++k) {
    const std::uint64_t bytes = rig.host_frame(k).upload_bytes;  // by the host thread
    const render::FramePair& pair = *rig.gpu->batches()[0].pair;
    const std::array<std::uint64_t, 3> now{pair.a_frame, pair.pairs.empty() ? ~0ull : pair.b_frame,
                                           pair.pairs.empty() ? ~0ull : pair.pairs_version};
    if (k > 0 && now == last) {
      EXPECT_EQ(bytes, 0u) << "host frame " << k;
      ++steady;
    } else if (k > 1) {
      // At most one cached frame's records (the other of the pair is resident) and the table.
      const std::uint64_t frame_bytes = (pair.pairs.empty() ? pair.a_count : pair.b_count) * m.record_size;
      EXPECT_LE(bytes, frame_bytes + pair.pairs.size() * sizeof(render::ParticlePair)) << "host frame " << k;
      ++changes;
    }
    last = now;
  }
  EXPECT_GT(steady, 20u);
  EXPECT_GT(changes, 4u);
}

// The frame after the pair on screen is copied towards the GPU on the renderer's staging thread
// once the stream has decoded it, so the host frame that reaches it uploads nothing itself; each
// cached frame's bytes still move once.
TEST(GpuPlayback, TheFrameAheadIsStagedSoReachingItUploadsNothing) {
  SparksOnTheGpu rig;
  const format::Metadata& m = rig.metadata();
  std::uint64_t last = ~0ull, crossings = 0, quiet_crossings = 0, staged = 0, moved = 0, frames_reached = 0;
  for (int k = 0; k < 60; ++k) {
    const render::RendererStats st = rig.host_frame(k);
    staged += st.staged_bytes;
    const render::FramePair* pair = rig.gpu->batches().empty() ? nullptr : rig.gpu->batches()[0].pair;
    if (k > 2 && pair != nullptr && !pair->pairs.empty()) {
      moved += st.upload_bytes + st.staged_bytes;
      if (pair->b_frame != last) {  // the playhead reached a new later frame
        ++crossings;
        quiet_crossings += st.upload_bytes == 0 ? 1 : 0;
        frames_reached += pair->b_count * m.record_size + pair->pairs.size_bytes();
      }
      last = pair->b_frame;
    } else if (pair != nullptr && !pair->pairs.empty()) {
      last = pair->b_frame;
    }
    // The IO worker decodes the frame after next while the host draws (a host frame's work).
    std::this_thread::sleep_for(std::chrono::milliseconds(4));
  }
  ASSERT_GE(crossings, 5u) << m.frame_count() << " frames at " << m.fps;
  EXPECT_GT(staged, 0u);
  // Reaching a staged frame costs the host thread no upload (a crossing can still upload when the
  // frame ahead was not decoded in time on a loaded machine: most must not).
  EXPECT_GE(quiet_crossings * 4, crossings * 3) << quiet_crossings << " of " << crossings;
  // Every byte moves once: no more than the frames and tables reached (and the one ahead).
  EXPECT_LE(moved, frames_reached + 2 * (m.max_count * m.record_size + 2 * m.max_count * sizeof(render::ParticlePair)));
}

// advance() and draw_data() allocate nothing on the GPU path either.
TEST(GpuPlayback, AHostFrameAllocatesNothingInThePlayer) {
  const fs::path files[] = {clips().sparks_particle, clips().sparks_records};
  playback::PlayerOptions o;
  o.stream.blocking = true;
  o.path = playback::PlaybackPath::Gpu;
  const auto p = playback::Player::open(files, std::move(o));
  p->play();
  const render::Camera camera;
  playback::DrawStyle style = playback::look_preset("smoke");
  for (int k = 0; k < 3; ++k) {  // warm up
    p->advance(1.0 / 120, camera.view(), sort::SortMode::BackToFront);
    p->draw_data(style);
  }
  const std::uint64_t before = test::allocation_count();
  for (int k = 0; k < 60; ++k) {
    p->advance(1.0 / 120, camera.view(), sort::SortMode::FrontToBack);
    (void)p->draw_data(style);
  }
  EXPECT_EQ(test::allocation_count(), before);
}

// Images through the GPU path equal the CPU path's within the golden tolerance.
std::vector<std::uint8_t> render_image(const std::vector<fs::path>& files, const std::string& flags,
                                       const std::string& path, const fs::path& out) {
  std::string names;
  for (const fs::path& f : files) names += " '" + f.string() + "'";
  const auto r = test::run_cli(fmt::format("render -q{} --out '{}' --size 240x136 --speed 0.3 --playback {} {}", names,
                                           out.string(), path, flags));
  EXPECT_EQ(r.exit_code, 0) << r.output;
  int w = 0, h = 0;
  return render::read_png(test::nth_frame(out, 2), w, h);  // between cached frames
}

void expect_same_images(const std::vector<fs::path>& files, const std::string& flags) {
  SCOPED_TRACE(flags);
  const fs::path dir = test::fresh_dir();
  const auto g = render_image(files, flags, "gpu", dir / "gpu");
  const auto c = render_image(files, flags, "cpu", dir / "cpu");
  ASSERT_EQ(g.size(), c.size());
  ASSERT_FALSE(g.empty());
  std::size_t off = 0, lit = 0;
  for (std::size_t i = 0; i < g.size(); ++i) {
    off += std::abs(int(g[i]) - int(c[i])) > 8;  // the golden tests' tolerance
    lit += c[i] > 40;
  }
  EXPECT_LE(off, g.size() / 200) << off << " channels differ by more than 8";
  EXPECT_GT(lit, 500u) << "an empty picture proves nothing";
}

TEST(GpuPlayback, SpritesImagesEqualTheCpuPath) { expect_same_images({clips().sparks_records}, "--frames 1:4"); }
TEST(GpuPlayback, ShadowImagesEqualTheCpuPath) {
  expect_same_images({clips().sparks_particle}, "--frames 1:4 --preset smoke");
}
TEST(GpuPlayback, MotionBlurImagesEqualTheCpuPath) {
  expect_same_images({clips().sparks_records}, "--frames 1:4 --preset sparks");
}
TEST(GpuPlayback, LiquidImagesEqualTheCpuPath) {
  expect_same_images({clips().flip_particle}, "--frames 1:4 --look liquid");
}
TEST(GpuPlayback, TwoMergedClipsImagesEqualTheCpuPath) {
  expect_same_images({clips().sparks_records, clips().flip_particle}, "--frames 0:3 --tint-clips");
}

}  // namespace

namespace {

// `pstream bench playback --json`: the rows scripts read, both paths, and what they can promise
// (not timings: those are for the benchmark, not a test).
TEST(GpuPlayback, BenchPlaybackReportsBothPaths) {
  const auto r = test::run_cli("bench playback --particles 20000 --frames 3 --json");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto j = nlohmann::json::parse(r.output.substr(r.output.find('{')));
  ASSERT_EQ(j["rows"].size(), 2u);
  for (const auto& row : j["rows"]) {
    for (const char* key :
         {"path", "particles", "host_thread_ms", "upload_bytes_per_host_frame", "upload_bytes_per_cached_frame"})
      EXPECT_TRUE(row.contains(key)) << key;
    EXPECT_EQ(row["particles"], 20000);
    EXPECT_GT(row["host_thread_ms"].get<double>(), 0.0);
    const double per_host = row["upload_bytes_per_host_frame"], per_cached = row["upload_bytes_per_cached_frame"];
    if (row["path"] == "gpu") {
      EXPECT_EQ(per_host, 0.0);
      EXPECT_GT(per_cached, 0.0);
      EXPECT_LE(per_cached, 20000.0 * (36 + 8));
    } else {
      EXPECT_EQ(row["path"], "cpu");
      EXPECT_GE(per_host, 20000.0 * 36);  // the whole frame, every host frame
    }
  }
}

}  // namespace
