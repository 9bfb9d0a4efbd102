// Golden images, rendered headless with Mesa's llvmpipe (what CI has): the depth order of alpha
// blending from two opposite cameras, additive blending's order independence, the world
// transform. References live in tests/data/render; PSTREAM_UPDATE_GOLDEN=1 rewrites them.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "particlestream/cook.hpp"
#include "particlestream/demo.hpp"
#include "particlestream/format.hpp"
#include "particlestream/playback.hpp"
#include "particlestream/render.hpp"
#include "particlestream/sort.hpp"
#include "test_util.hpp"

namespace {

using namespace pstream;
using namespace pstream::render;
namespace fs = std::filesystem;

// `pstream cook` of a test data file with no flags (the default a user gets) into `clip`; once per
// CTest run (test::shared_clip), copied for each test.
int cook_default(const std::string& data, const fs::path& clip) {
  int exit_code = 0;
  std::string key = "cli-default-" + data;
  std::replace(key.begin(), key.end(), '/', '-');
  const fs::path cooked = test::shared_clip(key, clip, [&](const fs::path& out) {
    exit_code = test::run_cli(fmt::format("cook -q '{}' -o '{}'", test::data_path(data), out.string())).exit_code;
  });
  if (exit_code == 0 && cooked != clip) fs::copy_file(cooked, clip, fs::copy_options::overwrite_existing);
  return exit_code;
}

constexpr int kW = 160, kH = 120;

struct Particle {
  float x, y, z, scale;
  std::uint32_t rgba;  // R in the lowest byte
};

ParticleBatch batch_of(const std::vector<Particle>& ps, const Mat4& world = identity()) {
  ParticleBatch b;
  b.first = std::as_bytes(std::span(ps));
  b.count = ps.size();
  b.record_size = sizeof(Particle);
  b.color_offset = 16;
  b.world = world;
  return b;
}

std::vector<std::uint8_t> draw(HeadlessContext& ctx, Renderer& r, const Camera& cam, const std::vector<Particle>& ps,
                               std::vector<std::uint32_t> order, BlendMode blend, const Mat4& world = identity()) {
  ParticleBatch b = batch_of(ps, world);
  b.order = order;
  b.blend = blend;
  ctx.bind();
  r.begin_frame(kW, kH, cam, {0, 0, 0, 1});
  r.draw(b);
  r.end_frame();
  return ctx.read_rgba();
}

// Same size, and no pixel channel more than `tolerance` apart except for a few rasteriser edge pixels.
void expect_matches_golden(const std::vector<std::uint8_t>& image, const std::string& name, int tolerance = 8) {
  const fs::path path = test::data_path("render/" + name + ".png");
  if (std::getenv("PSTREAM_UPDATE_GOLDEN") != nullptr) write_png(path, kW, kH, image);
  int w = 0, h = 0;
  const auto golden = read_png(path, w, h);
  ASSERT_EQ(w, kW);
  ASSERT_EQ(h, kH);
  std::size_t off = 0;
  for (std::size_t i = 0; i < golden.size(); ++i) off += std::abs(int(golden[i]) - int(image[i])) > tolerance;
  EXPECT_LE(off, golden.size() / 200) << name << ": " << off << " channels differ by more than " << tolerance;
}

std::array<int, 3> pixel(const std::vector<std::uint8_t>& img, int x, int y) {
  const std::size_t i = (std::size_t(y) * kW + x) * 4;
  return {img[i], img[i + 1], img[i + 2]};
}

class RenderTest : public ::testing::Test {
 protected:
  HeadlessContext ctx{kW, kH};
  Renderer renderer;
};

TEST_F(RenderTest, AlphaBlendingIsInDepthOrderFromBothSides) {
  // Red at the origin, blue 1 unit behind it and a little to the right: overlapping on screen.
  const std::vector<Particle> ps = {{0, 0, 0, 0.6f, 0xff2020e0u}, {0.4f, 0.1f, -1, 0.6f, 0xffe02020u}};
  Camera front, back;
  front.eye = {0, 0, 5};
  back.eye = {0, 0, -5};
  // Back to front: from +z the blue one is farther, from -z the red one.
  const auto a = draw(ctx, renderer, front, ps, {1, 0}, BlendMode::Alpha);
  const auto b = draw(ctx, renderer, back, ps, {0, 1}, BlendMode::Alpha);
  // The overlap: from the front the red particle covers it, from the back the blue one.
  const auto pa = pixel(a, kW / 2 + 6, kH / 2), pb = pixel(b, kW / 2 - 6, kH / 2);
  EXPECT_GT(pa[0], 2 * pa[2]) << "front view: red should be in front";
  EXPECT_GT(pb[2], 2 * pb[0]) << "back view: blue should be in front";
  expect_matches_golden(a, "alpha_front");
  expect_matches_golden(b, "alpha_back");
}

TEST_F(RenderTest, AdditiveBlendingIgnoresOrder) {
  const std::vector<Particle> ps = {
      {0, 0, 0, 0.6f, 0x80ff4010u}, {0.3f, 0, -1, 0.6f, 0x801040ffu}, {-0.3f, 0.2f, 0.5f, 0.5f, 0x8040ff40u}};
  Camera cam;
  const auto a = draw(ctx, renderer, cam, ps, {0, 1, 2}, BlendMode::Additive);
  const auto b = draw(ctx, renderer, cam, ps, {2, 0, 1}, BlendMode::Additive);
  for (std::size_t i = 0; i < a.size(); ++i) ASSERT_LE(std::abs(int(a[i]) - int(b[i])), 1) << i;
  expect_matches_golden(a, "additive");
}

TEST_F(RenderTest, WorldTransformMovesTheStream) {
  const std::vector<Particle> ps = {{0, 0, 0, 0.4f, 0xffffffffu}};
  Camera cam;
  const auto centroid = [](const std::vector<std::uint8_t>& img) {
    double sx = 0, sw = 0;
    for (int y = 0; y < kH; ++y) {
      for (int x = 0; x < kW; ++x) {
        const double w = img[(std::size_t(y) * kW + x) * 4];
        sx += w * x;
        sw += w;
      }
    }
    return sx / sw;
  };
  const auto still = draw(ctx, renderer, cam, ps, {}, BlendMode::Alpha);
  const auto moved = draw(ctx, renderer, cam, ps, {}, BlendMode::Alpha, translation({1, 0, 0}));
  // One unit at 5 units' distance with a 45 degree field of view: about 0.24 of the height.
  const double expected = 1.0 / (5.0 * std::tan(22.5 * 3.14159265 / 180.0)) * kH / 2;
  EXPECT_NEAR(centroid(moved) - centroid(still), expected, 1.5);
  expect_matches_golden(moved, "world_transform");
}

TEST_F(RenderTest, AlphaTestIsOpaqueWithDepth) {
  const std::vector<Particle> ps = {{0, 0, 0, 0.6f, 0xff2020e0u}, {0.4f, 0.1f, -1, 0.6f, 0xffe02020u}};
  Camera cam;
  // Drawn front first: the depth test, not the order, keeps the red one in front.
  const auto img = draw(ctx, renderer, cam, ps, {0, 1}, BlendMode::AlphaTest);
  const auto p = pixel(img, kW / 2 + 6, kH / 2);
  EXPECT_GT(p[0], 2 * p[2]);
  expect_matches_golden(img, "alphatest");
}

TEST_F(RenderTest, OverlappingStreamsBlendInOneMergedOrder) {
  // Stream A: a near and a far red particle; stream B, with its own transform, a blue one between.
  const std::vector<Particle> a = {{0, 0, 0, 0.6f, 0xff2020e0u}, {0.6f, 0, -2, 0.6f, 0xff2020e0u}};
  const std::vector<Particle> b = {{0.3f, 0, -0.5f, 0.6f, 0xffe02020u}};
  const Mat4 b_world = translation({0, 0, -0.5f});  // the blue one ends at z = -1
  Camera cam;
  ParticleBatch ba = batch_of(a), bb = batch_of(b, b_world);
  pstream::sort::DepthSorter sorter(3);
  const std::vector<pstream::sort::DepthSorter::Source> sources = {
      {ba.first.data(), 2, sizeof(Particle), multiply(cam.view(), ba.world)},
      {bb.first.data(), 1, sizeof(Particle), multiply(cam.view(), bb.world)}};
  const auto order = sorter.sort_merged(sources, pstream::sort::SortMode::BackToFront);
  ASSERT_EQ(order.size(), 3u);
  EXPECT_EQ(order[0], 1u);        // stream A's far particle first
  EXPECT_EQ(order[1], 1u << 28);  // then stream B's
  EXPECT_EQ(order[2], 0u);        // stream A's near one last
  const std::vector<ParticleBatch> batches = {ba, bb};
  ctx.bind();
  renderer.begin_frame(kW, kH, cam, {0, 0, 0, 1});
  renderer.draw_merged(batches, order);
  renderer.end_frame();
  const auto merged = ctx.read_rgba();
  // Where the near red particle overlaps the blue one, red is in front; drawn stream after
  // stream, blue would cover it.
  const auto p = pixel(merged, kW / 2 + 8, kH / 2);
  EXPECT_GT(p[0], 2 * p[2]) << "near red should cover blue";
  ctx.bind();
  renderer.begin_frame(kW, kH, cam, {0, 0, 0, 1});
  const std::vector<std::uint32_t> a_order = {1, 0};  // stream A alone, back to front
  ba.order = a_order;
  renderer.draw(ba);
  renderer.draw(bb);
  renderer.end_frame();
  const auto q = pixel(ctx.read_rgba(), kW / 2 + 8, kH / 2);
  EXPECT_GT(q[2], q[0]) << "stream after stream, blue lands on top: the case merging fixes";
  expect_matches_golden(merged, "merged_streams");
}

TEST(RenderCommand, WritesFramesAndAnMp4WithTheRightFrameCount) {
  const fs::path dir = test::fresh_dir();
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.input = test::data_path("alembic/points_varying.abc");
  o.output = dir / "v.pstream";
  cook::cook(o);
  const auto r = test::run_cli("render -q '" + o.output.string() + "' --out '" + (dir / "frames").string() +
                               "' --frames 10:22 --size 96x64 --video '" + (dir / "v.mp4").string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::size_t pngs = 0, lit = 0;
  for (const auto& e : fs::directory_iterator(dir / "frames")) {
    ++pngs;
    int w = 0, h = 0;
    const auto img = read_png(e.path(), w, h);
    EXPECT_EQ(w, 96);
    std::size_t bright = 0;
    for (std::size_t i = 0; i < img.size(); i += 4) bright += img[i] + img[i + 1] + img[i + 2] > 60;
    lit += bright > 0;
  }
  EXPECT_EQ(pngs, 12u);
  EXPECT_EQ(lit, 12u) << "blank frames";
  const auto probe = test::run_cli_raw(
      "ffprobe -v error -count_frames -select_streams v:0 -show_entries stream=nb_read_frames "
      "-of csv=p=0 '" +
      (dir / "v.mp4").string() + "'");
  EXPECT_EQ(probe.output, "12\n");
}

// Slow motion: `render --speed 0.25` on a 24 fps cache makes four images per cached frame, each
// interpolated, so no two follow-on images are the same; with --interpolation none they repeat.
TEST(RenderCommand, SlowMotionRendersInterpolatedImages) {
  const fs::path dir = test::fresh_dir();
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.input = test::data_path("sims/blender_sparks.abc");
  o.output = dir / "sparks.pstream";
  o.attributes = {"velocity", "id"};
  cook::cook(o);
  const auto images = [&](const std::string& interpolation) {
    const fs::path out = dir / interpolation;
    const auto r =
        test::run_cli("render -q '" + o.output.string() + "' --out '" + out.string() +
                      "' --frames 30:33 --size 160x96 --speed 0.25 --camera fixed --interpolation " + interpolation);
    EXPECT_EQ(r.exit_code, 0) << r.output;
    std::vector<std::vector<std::uint8_t>> frames;
    for (int k = 0;; ++k) {
      const fs::path png = test::nth_frame(out, k);
      if (!fs::exists(png)) break;
      int w = 0, h = 0;
      frames.push_back(read_png(png, w, h));
    }
    return frames;
  };
  const auto smooth = images("hermite");
  ASSERT_EQ(smooth.size(), 9u);  // 2 cached frame steps at 0.25 speed, 24 images a second, and the last
  for (std::size_t k = 1; k < smooth.size(); ++k) EXPECT_NE(smooth[k], smooth[k - 1]) << "image " << k;
  const auto stepped = images("none");
  ASSERT_EQ(stepped.size(), 9u);
  std::size_t repeats = 0;
  for (std::size_t k = 1; k < stepped.size(); ++k) repeats += stepped[k] == stepped[k - 1];
  EXPECT_GE(repeats, 5u);
}

// A default cook (no flags) has what the looks need: the particle codec keeps the source's
// velocities and matches particles, so colouring by speed is not black, sparks streak, and slow
// motion of a liquid without ids is interpolated; a clip without velocities says so, naming the
// flag, instead of drawing a black picture.
TEST(RenderCommand, ADefaultCookHasWhatTheLooksNeed) {
  const fs::path dir = test::fresh_dir();
  const fs::path sparks = dir / "sparks.pstream", flip = dir / "flip.pstream", bare = dir / "bare.pstream";
  for (const auto& [in, out, flags] :
       {std::tuple{"sims/blender_sparks.abc", sparks, ""}, std::tuple{"sims/blender_flip_pour_small.abc", flip, ""},
        std::tuple{"sims/blender_sparks.abc", bare, " --no-velocity"}}) {
    const auto r = test::run_cli(fmt::format("cook '{}' -o '{}' -q{}", test::data_path(in), out.string(), flags));
    ASSERT_EQ(r.exit_code, 0) << r.output;
  }
  const auto image = [&](const fs::path& clip, const std::string& name, const std::string& flags) {
    const fs::path out = dir / name;
    const auto r = test::run_cli(
        fmt::format("render -q '{}' --out '{}' --size 480x270 --backdrop none {}", clip.string(), out.string(), flags));
    EXPECT_EQ(r.exit_code, 0) << r.output;
    int w = 0, h = 0;
    return read_png(test::nth_frame(out, 0), w, h);
  };
  const auto count = [](const std::vector<std::uint8_t>& img, auto&& pixel) {
    std::size_t n = 0;
    for (std::size_t i = 0; i < img.size(); i += 4) n += pixel(img.data() + i) ? 1 : 0;
    return n;
  };
  // Speed colours: the fire ramp over the clip's speeds (0 to 4 units/s: black to white through
  // red and orange), not the black of speed 0: hundreds of bright, red-dominated pixels.
  const auto speed = image(sparks, "speed", "--frames 20:21 --color-by speed --ramp fire --ramp-range 0,4");
  EXPECT_GT(count(speed, [](const std::uint8_t* p) { return p[0] > 80 && p[0] >= p[2]; }), 200u);
  // Sparks streak: the same frame with the preset's shutter and without differ in thousands of
  // pixels (LooksTest.MotionBlurLengthIsProportionalToVelocity measures the streaks' length).
  const auto streaks = image(sparks, "streaks", "--frames 20:21 --preset sparks");
  const auto dots = image(sparks, "dots", "--frames 20:21 --preset sparks --shutter 0");
  ASSERT_EQ(streaks.size(), dots.size());
  std::size_t changed = 0;
  for (std::size_t i = 0; i < streaks.size(); i += 4) changed += std::abs(int(streaks[i]) - int(dots[i])) > 12;
  EXPECT_GT(changed, 1000u);
  // Slow motion of the FLIP liquid (no ids): each image interpolated, none repeated (the camera
  // fixed, so that only the particles can tell the images apart).
  std::vector<std::vector<std::uint8_t>> slow{image(flip, "slow", "--frames 30:32 --speed 0.25 --camera fixed")};
  for (int k = 1; k < 5; ++k) {
    int w = 0, h = 0;
    slow.push_back(read_png(test::nth_frame(dir / "slow", k), w, h));
    EXPECT_NE(slow[std::size_t(k)], slow[std::size_t(k - 1)]) << "image " << k << " repeats";
  }
  // A clip without velocities: the look that needs them says so before anything is written.
  for (const std::string flags : {"--color-by speed", "--preset sparks"}) {
    const auto r =
        test::run_cli(fmt::format("render -q '{}' --out '{}' {}", bare.string(), (dir / "no").string(), flags));
    EXPECT_NE(r.exit_code, 0) << flags;
    EXPECT_NE(r.output.find("needs velocities"), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("--attributes velocity"), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(dir / "no"));
  }
}

// A re-render into the same folder leaves exactly its own frames (an earlier, longer render's
// extra ones removed), or with --no-clobber refuses; a video that cannot be written is refused
// before the first frame.
TEST(RenderCommand, OutputsAreCheckedBeforeTheFirstFrameAndOldFramesReplaced) {
  const fs::path dir = test::fresh_dir();
  const fs::path clip = dir / "clip.pstream";
  ASSERT_EQ(cook_default("alembic/points_varying.abc", clip), 0);
  const auto render = [&](const std::string& flags) {
    return test::run_cli(
        fmt::format("render -q '{}' --out '{}' --size 64x36 {}", clip.string(), (dir / "out").string(), flags));
  };
  const auto frames_in = [&](const fs::path& d) {
    std::size_t n = 0;
    for (const auto& e : fs::directory_iterator(d)) n += e.path().extension() == ".png";
    return n;
  };
  ASSERT_EQ(render("--frames 0:5").exit_code, 0);
  EXPECT_EQ(frames_in(dir / "out"), 5u);
  auto r = render("--frames 0:2");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(frames_in(dir / "out"), 2u);  // frames 2..4 of the earlier render are gone
  r = render("--frames 0:3 --no-clobber");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("holds 2 frames of an earlier render"), std::string::npos) << r.output;
  // A video into a folder that does not exist: refused before anything is rendered.
  fs::remove_all(dir / "out");
  r = render(fmt::format("--frames 0:3 --video '{}'", (dir / "no" / "such" / "v.mp4").string()));
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("does not exist"), std::string::npos) << r.output;
  EXPECT_TRUE(!fs::exists(dir / "out") || frames_in(dir / "out") == 0u);
}

// Colouring by speed spans the clip's own speeds unless told otherwise: from 0 to the 99th
// percentile (computed here independently from the same frames), so a fast effect is not white.
TEST(RenderCommand, ASpeedRampSpansTheClipsSpeeds) {
  const fs::path dir = test::fresh_dir();
  const fs::path clip = dir / "sparks.pstream";
  ASSERT_EQ(cook_default("sims/blender_sparks.abc", clip), 0);
  const fs::path files[] = {clip};
  const std::array<float, 2> range = playback::ramp_range(files);
  const format::Reader reader = format::Reader::open(clip);
  const format::Metadata& m = reader.metadata();
  const format::Attribute* v = m.find("velocity");
  ASSERT_NE(v, nullptr);
  std::vector<float> speeds;
  std::vector<std::byte> records = format::frame_buffer(m, "clip");
  for (const double at : {0.25, 0.5, 0.75, 1.0}) {
    const auto f = std::uint64_t(at * double(m.frame_count() - 1));
    reader.read_frame(f, records);
    for (std::uint64_t i = 0; i < m.frames[f].count; ++i) {
      float w[3];
      std::memcpy(w, records.data() + i * m.record_size + v->offset, 12);
      speeds.push_back(std::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]));
    }
  }
  std::sort(speeds.begin(), speeds.end());
  EXPECT_EQ(range[0], 0.0f);
  EXPECT_EQ(range[1], speeds[std::size_t(0.99 * double(speeds.size() - 1))]);
  // A range far below the clip's speeds puts every spark at the ramp's top; the automatic one
  // spreads them along it.
  const auto colours = [&](const std::string& flags) {
    const fs::path out = dir / "out";
    fs::remove_all(out);
    const auto r =
        test::run_cli(fmt::format("render -q '{}' --out '{}' --size 320x180 --frames 20:21 --backdrop none "
                                  "--color-by speed --ramp fire {}",
                                  clip.string(), out.string(), flags));
    EXPECT_EQ(r.exit_code, 0) << r.output;
    int w = 0, h = 0;
    const auto img = read_png(test::nth_frame(out, 0), w, h);
    // The fire ramp runs black, red, orange, yellow, white: green over red grows along it.
    std::size_t lit = 0;
    double green_over_red = 0.0;
    for (std::size_t i = 0; i < img.size(); i += 4) {
      if (img[i] <= 60) continue;
      ++lit;
      green_over_red += double(img[i + 1]) / double(img[i]);
    }
    return std::pair{lit, lit ? green_over_red / double(lit) : 0.0};
  };
  const auto [lit_low, hue_low] = colours(fmt::format("--ramp-range 0,{}", range[1] / 20));
  const auto [lit_auto, hue_auto] = colours("");
  std::printf("green/red of lit pixels: range 0..%g %.3f, automatic 0..%g %.3f\n", range[1] / 20, hue_low, range[1],
              hue_auto);
  EXPECT_GT(lit_low, 100u);
  EXPECT_GT(lit_auto, 100u);
  EXPECT_GT(hue_low, hue_auto + 0.15) << "the automatic range should leave the sparks red and orange, not yellow";
}

// The 50k-particle fixture in 64 KiB chunks (frames straddle chunks), for the viewer's runs.
cook::Options large_clip(const fs::path& dir) {
  cook::Options o;
  o.frame_codec = format::FrameCodec::Records;  // the exact records (the default is the particle codec)
  o.input = test::data_path("alembic/points_large.abc");
  o.output = dir / "large.pstream";
  o.chunk_size = 64 << 10;
  cook::cook(o);
  return o;
}

// Does a lossy cook look like the exact clip? The FLIP pour as a liquid and the sparks as sprites,
// cooked with the records as they are (`--codec raw`, velocities kept), by default (the particle
// codec at 1e-4 of the diagonal) and at 4 times that bound (1 mm on the pour), then rendered from
// one explicit camera (an automatic one follows the decoded bounds, which move by up to the
// bound, and would shift the whole picture by a fraction of a pixel). docs/compression.md, "Size
// against the bound".
TEST(RenderCommand, ALossyCookLooksLikeTheExactClip) {
  const fs::path dir = test::fresh_dir();
  const auto cook = [&](const std::string& source, const std::string& flags, const std::string& name) {
    const fs::path clip = dir / (name + ".pstream");
    const auto c = test::run_cli(
        fmt::format("cook '{}' -o '{}' -q --frames 30:32 {}", test::data_path(source), clip.string(), flags));
    EXPECT_EQ(c.exit_code, 0) << c.output;
    return clip;
  };
  const auto image = [&](const fs::path& clip, const std::string& name, const std::string& look) {
    const auto r = test::run_cli(fmt::format("render -q '{}' --out '{}' --size 320x180 --frames 1:2 {}", clip.string(),
                                             (dir / name).string(), look));
    EXPECT_EQ(r.exit_code, 0) << r.output;
    int w = 0, h = 0;
    auto img = read_png(test::nth_frame(dir / name, 0), w, h);
    EXPECT_EQ(w, 320);
    return img;
  };
  struct Case {
    std::string source, look;
    std::size_t least_effect;  // pixels the effect covers, at the least
  };
  for (const Case& k : {Case{"sims/blender_flip_pour_small.abc", "--look liquid --camera 2.2,1.5,2.2:0,0.45,0", 3000},
                        Case{"sims/blender_sparks.abc", "--camera 2.5,1.6,3.5:0,0.9,0", 600}}) {
    SCOPED_TRACE(k.source);
    const fs::path exact_clip = cook(k.source, "--codec raw --attributes velocity", "exact");
    const auto exact = image(exact_clip, "exact", k.look);
    // The effect's pixels: where the same clip drawn with vanishing particles differs (the
    // backdrop alone would match any clip).
    const auto backdrop = image(exact_clip, "backdrop", k.look + " --size-multiplier 1e-4");
    ASSERT_EQ(backdrop.size(), exact.size());
    const auto differ = [](const std::vector<std::uint8_t>& a, const std::vector<std::uint8_t>& b, std::size_t i) {
      int d = 0;
      for (std::size_t c = 0; c < 3; ++c) d = std::max(d, std::abs(int(a[i + c]) - int(b[i + c])));
      return d;
    };
    std::vector<std::size_t> effect;
    for (std::size_t i = 0; i < exact.size(); i += 4)
      if (differ(exact, backdrop, i) > 24) effect.push_back(i);
    EXPECT_GT(effect.size(), k.least_effect);
    // The default bound, then 4 times it: the most each may change the effect's pixels, in mean
    // levels and in the share off by more than 16 (measured: the pour 0.46 and 1.18 levels,
    // 0.06 % and 0.50 %; the sparks, whose sprites are a pixel or two across, 1.04 and 3.48
    // levels, 0 % and 0.73 %).
    for (const auto& [bound, most_mean, most_off] :
         {std::tuple{std::string(), 1.5, 0.005}, std::tuple{std::string("--error 4e-4"), 5.0, 0.02}}) {
      SCOPED_TRACE(bound);
      const std::string name = bound.empty() ? "default" : "loose";
      const auto lossy = image(cook(k.source, bound, name), name, k.look);
      ASSERT_EQ(lossy.size(), exact.size());
      // Over the effect's pixels: the mean difference in levels, and the share off by more than 16.
      double sum = 0;
      std::size_t off = 0;
      for (const std::size_t i : effect) {
        const int d = differ(exact, lossy, i);
        sum += d;
        off += d > 16;
      }
      const double n = double(std::max<std::size_t>(effect.size(), 1));
      EXPECT_LT(sum / n, most_mean);
      EXPECT_LT(double(off) / n, most_off);
    }
  }
}

// The liquid look from the command line, with two clips in one picture; a mistyped look flag is
// refused before anything is written.
TEST(RenderCommand, LiquidLookAndSeveralClips) {
  const fs::path dir = test::fresh_dir();
  const fs::path clip = dir / "flip.pstream";
  ASSERT_EQ(test::run_cli(fmt::format("cook '{}' -o '{}' -q --frames 30:33",
                                      test::data_path("sims/blender_flip_pour_small.abc"), clip.string()))
                .exit_code,
            0);
  const auto r =
      test::run_cli(fmt::format("render '{0}' '{0}' --look liquid --foam-speed 2 --size 320x180 -q --out '{1}'",
                                clip.string(), (dir / "liquid").string()));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  int w = 0, h = 0;
  const auto img = read_png(test::nth_frame(dir / "liquid", 0), w, h);
  ASSERT_EQ(w, 320);
  // The liquid's blue-green is in the picture (the backdrop is grey and sky blue: its pixels have
  // red close to green).
  std::size_t liquid = 0;
  for (std::size_t i = 0; i < img.size(); i += 4) liquid += int(img[i + 1]) - int(img[i]) > 40;
  EXPECT_GT(liquid, 500u);
  EXPECT_EQ(std::distance(fs::directory_iterator(dir / "liquid"), fs::directory_iterator{}), 3);

  const auto bad = test::run_cli(fmt::format("render '{}' --look liquid --liquid-filter median -q --out '{}'",
                                             clip.string(), (dir / "bad").string()));
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.output.find("liquid filter 'median'"), std::string::npos) << bad.output;
  EXPECT_FALSE(fs::exists(dir / "bad"));
}

TEST(Viewer, RunsUnderXvfbAndShowsThePanel) {
  if (test::run_cli_raw("command -v xvfb-run").exit_code != 0) GTEST_SKIP() << "xvfb-run is not installed";
  const fs::path dir = test::fresh_dir();
  const cook::Options o = large_clip(dir);
  const fs::path shot = dir / "shot.png";
  const auto r = test::run_cli_raw("xvfb-run -a -s '-screen 0 800x600x24' " + std::string(PSTREAM_CLI) + " play '" +
                                   o.output.string() + "' --width 800 --height 600 --frames-to-run 20 --screenshot '" +
                                   shot.string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  int w = 0, h = 0;
  const auto img = read_png(shot, w, h);
  ASSERT_EQ(w, 800);
  ASSERT_EQ(h, 600);
  std::size_t title = 0, particles = 0;
  int title_right = 0;  // the panel's right edge: it leaves most of the picture (#26: was 460 pixels)
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const std::uint8_t* p = &img[(std::size_t(y) * w + x) * 4];
      // ImGui's dark style: the active title bar is (41, 74, 122).
      if (y < 40 && x < 480 && std::abs(p[0] - 41) < 14 && std::abs(p[1] - 74) < 14 && std::abs(p[2] - 122) < 16) {
        ++title;
        title_right = std::max(title_right, x);
      }
      if (x > 480 && p[0] + p[1] + p[2] > 90) ++particles;  // lit pixels right of the panel
    }
  }
  EXPECT_GT(title, 2000u) << "no ImGui panel in the screenshot";
  EXPECT_LT(title_right, 340) << "the panel covers too much of the picture";
  EXPECT_GT(particles, 500u) << "no particles in the screenshot";
}

// With a ramp, the viewer shows its legend at the timeline's right end: the fire ramp's colours
// from dark red to near white. With the stored colours, there is none.
TEST(Viewer, ARampShowsItsLegendBesideTheTimeline) {
  if (test::run_cli_raw("command -v xvfb-run").exit_code != 0) GTEST_SKIP() << "xvfb-run is not installed";
  const fs::path dir = test::fresh_dir();
  const fs::path clip = dir / "sparks.pstream";
  ASSERT_EQ(cook_default("sims/blender_sparks.abc", clip), 0);
  std::size_t reds[2] = {0, 0}, whites[2] = {0, 0};
  for (const int ramp : {0, 1}) {
    const fs::path shot = dir / fmt::format("shot_{}.png", ramp);
    const auto r = test::run_cli_raw(
        fmt::format("xvfb-run -a -s '-screen 0 1280x720x24' {} play '{}' {} --frames-to-run 5 --screenshot '{}'",
                    PSTREAM_CLI, clip.string(), ramp ? "--color-by speed" : "", shot.string()));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    int w = 0, h = 0;
    const auto img = read_png(shot, w, h);
    for (int y = h - 44; y < h; ++y) {  // the timeline's last 300 pixels
      for (int x = w - 300; x < w; ++x) {
        const std::uint8_t* p = &img[(std::size_t(y) * w + x) * 4];
        if (p[0] > 120 && p[0] > p[2] + 80 && p[1] < p[0]) ++reds[ramp];
        if (p[0] > 235 && p[1] > 225 && p[2] > 180) ++whites[ramp];
      }
    }
  }
  std::printf("legend pixels: %zu red, %zu near white (stored colours: %zu, %zu)\n", reds[1], whites[1], reds[0],
              whites[0]);
  EXPECT_GT(reds[1], 200u);
  EXPECT_GT(whites[1], 50u);
  EXPECT_EQ(reds[0], 0u);
}

// The viewer frames the clip beside its panel and above its timeline: at the default window size,
// no pixel of the clip lies under either, on both fixture sims at three moments. The picture comes
// from a run with the panel hidden (--hide-ui: laid out, drawn transparent); the rectangles from
// what scripted runs print.
TEST(Viewer, NoParticleUnderThePanel) {
  if (test::run_cli_raw("command -v xvfb-run").exit_code != 0) GTEST_SKIP() << "xvfb-run is not installed";
  const fs::path dir = test::fresh_dir();
  for (const char* sim : {"sims/blender_sparks.abc", "sims/blender_flip_pour_small.abc"}) {
    const fs::path clip = dir / (fs::path(sim).stem().string() + ".pstream");
    ASSERT_EQ(cook_default(sim, clip), 0);
    for (const int frames : {8, 24, 44}) {
      const fs::path shot = dir / fmt::format("{}_{}.png", clip.stem().string(), frames);
      const auto r =
          test::run_cli_raw(fmt::format("xvfb-run -a -s '-screen 0 1280x720x24' {} play '{}' --hide-ui "
                                        "--frames-to-run {} --screenshot '{}'",
                                        PSTREAM_CLI, clip.string(), frames, shot.string()));
      ASSERT_EQ(r.exit_code, 0) << r.output;
      int px = 0, py = 0, pw = 0, ph = 0, tx = 0, ty = 0, tw = 0, th = 0;
      const auto at = r.output.find("panel ");
      ASSERT_NE(at, std::string::npos) << r.output;
      ASSERT_EQ(std::sscanf(r.output.c_str() + at, "panel %d %d %d %d\ntimeline %d %d %d %d", &px, &py, &pw, &ph, &tx,
                            &ty, &tw, &th),
                8)
          << r.output;
      int w = 0, h = 0;
      const auto img = read_png(shot, w, h);
      ASSERT_EQ(w, 1280);  // the default window
      ASSERT_EQ(h, 720);
      const std::uint8_t* bg = &img[0];  // the top-left corner: background
      std::size_t drawn = 0, covered = 0;
      for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) {
          const std::uint8_t* p = &img[(std::size_t(y) * w + x) * 4];
          const int d = std::max({std::abs(p[0] - bg[0]), std::abs(p[1] - bg[1]), std::abs(p[2] - bg[2])});
          if (d <= 6) continue;
          ++drawn;
          const bool in_panel = x >= px && x < px + pw && y >= py && y < py + ph;
          const bool in_timeline = x >= tx && x < tx + tw && y >= ty && y < ty + th;
          covered += in_panel || in_timeline;
        }
      }
      EXPECT_GT(drawn, 200u) << shot;
      EXPECT_EQ(covered, 0u) << shot << ": " << covered << " of " << drawn << " particle pixels under the panel (" << px
                             << "," << py << " " << pw << "x" << ph << ") or the timeline";
    }
  }
}

}  // namespace

namespace {

// `pstream demo` end to end on a small smoke simulation (the preset where sorting matters):
// every output exists, the report holds measured figures, and two frames match references.
TEST(Demo, SmallSmokeRunProducesEverythingAndMatchingFrames) {
  const fs::path dir = test::fresh_dir();
  const auto r =
      test::run_cli("demo --preset smoke --particles 3000 --seconds 1 --fps 12 --size 320x180 --headless -q --out '" +
                    dir.string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* f : {"demo.abc", "demo.pstream", "contact_sheet.png", "report.json", "report.md", "demo.mp4"}) {
    EXPECT_TRUE(fs::exists(dir / f)) << f;
  }
  const auto report = nlohmann::json::parse(test::read_text(dir / "report.json"));
  EXPECT_GT(report["simulation"]["peak_particles"].get<int>(), 300);  // 1 s of a 4-7 s lifetime
  EXPECT_GT(report["simulation"]["abc_bytes"].get<double>(), 0);
  EXPECT_GT(report["cook"]["pstream_bytes"].get<double>(), 0);
  EXPECT_GT(report["render"]["frame_ms"]["median"].get<double>(), 0);
  EXPECT_GE(report["stream"]["frame_ms"]["p99"].get<double>(), report["stream"]["frame_ms"]["median"].get<double>());
  EXPECT_EQ(report["render"]["frames"].get<int>(), 12);
  for (int frame : {4, 10}) {
    int w = 0, h = 0;
    const auto img = read_png(test::nth_frame(dir / "frames", frame), w, h);
    ASSERT_EQ(w, 320);
    const fs::path golden = test::data_path(fmt::format("demo/smoke_frame_{}.png", frame));
    if (std::getenv("PSTREAM_UPDATE_GOLDEN") != nullptr) write_png(golden, w, h, img);
    int gw = 0, gh = 0;
    const auto ref = read_png(golden, gw, gh);
    ASSERT_EQ(ref.size(), img.size());
    std::size_t off = 0, lit = 0;
    for (std::size_t i = 0; i < ref.size(); ++i) off += std::abs(int(ref[i]) - int(img[i])) > 8;
    for (std::size_t i = 0; i < img.size(); i += 4) lit += img[i] + img[i + 1] + img[i + 2] > 60;
    EXPECT_LE(off, ref.size() / 200) << "frame " << frame << " differs from its reference";
    EXPECT_GT(lit, 200u) << "frame " << frame << " is nearly blank";
  }
}

// Regression (#12): a clip that fails while playing made `play` exit 0.
TEST(Viewer, ACorruptClipFailsTheRun) {
  if (test::run_cli_raw("command -v xvfb-run").exit_code != 0) GTEST_SKIP() << "xvfb-run is not installed";
  const fs::path dir = test::fresh_dir();
  const cook::Options o = large_clip(dir);
  std::string bytes = test::read_text(o.output);
  for (std::size_t i = 100000; i < 100100; ++i) bytes[i] = static_cast<char>(bytes[i] ^ 0x3c);  // inside chunk 1
  std::ofstream(dir / "corrupt.pstream", std::ios::binary).write(bytes.data(), std::streamsize(bytes.size()));
  const auto r =
      test::run_cli_raw("xvfb-run -a -s '-screen 0 640x480x24' " + std::string(PSTREAM_CLI) + " play '" +
                        (dir / "corrupt.pstream").string() + "' --width 640 --height 480 --frames-to-run 60");
  // (xvfb-run passes pstream's exit code on, unless its own clean-up fails: then it is not 0 either.)
  EXPECT_NE(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("pstream: error:"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("checksum"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("Sanitizer"), std::string::npos) << r.output;
}

}  // namespace

namespace {

// The default speed ramp on each shared fixture sim (default cook): the particles' colours span
// the ramp, and no more than 5 % of them sit at either end of it (issue #26's measure), over
// every frame.
TEST(RenderCommand, DefaultSpeedRampsSpanTheRampOnTheFixtureSims) {
  const fs::path dir = test::fresh_dir();
  for (const char* sim : {"sims/blender_sparks.abc", "sims/blender_flip_pour_small.abc"}) {
    SCOPED_TRACE(sim);
    const fs::path clip = dir / (fs::path(sim).stem().string() + ".pstream");
    ASSERT_EQ(cook_default(sim, clip), 0);
    const fs::path files[] = {clip};
    const std::array<float, 2> range = playback::ramp_range(files);
    const format::Reader reader = format::Reader::open(clip);
    const format::Metadata& m = reader.metadata();
    const format::Attribute* v = m.find("velocity");
    ASSERT_NE(v, nullptr);
    std::vector<std::byte> records = format::frame_buffer(m, "clip");
    std::uint64_t n = 0, low = 0, high = 0, quarters[4] = {0, 0, 0, 0};
    for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
      reader.read_frame(f, records);
      for (std::uint64_t i = 0; i < m.frames[f].count; ++i) {
        float w[3];
        std::memcpy(w, records.data() + i * m.record_size + v->offset, 12);
        const double t = (std::sqrt(double(w[0]) * w[0] + double(w[1]) * w[1] + double(w[2]) * w[2]) - range[0]) /
                         double(range[1] - range[0]);  // where on the ramp, as the shader computes it
        ++n;
        low += t <= 0.0 ? 1 : 0;
        high += t >= 1.0 ? 1 : 0;
        ++quarters[std::clamp(int(t * 4), 0, 3)];
      }
    }
    ASSERT_GT(n, 100000u);
    std::printf("%s: ramp %.3g..%.3g m/s; %.2f%% at its start, %.2f%% at its end; quarters %.0f/%.0f/%.0f/%.0f%%\n",
                sim, range[0], range[1], 100.0 * double(low) / double(n), 100.0 * double(high) / double(n),
                100.0 * double(quarters[0]) / double(n), 100.0 * double(quarters[1]) / double(n),
                100.0 * double(quarters[2]) / double(n), 100.0 * double(quarters[3]) / double(n));
    EXPECT_LE(double(low), 0.05 * double(n));
    EXPECT_LE(double(high), 0.05 * double(n));
    for (const std::uint64_t q : quarters) EXPECT_GT(q, 0u);  // every part of the ramp is used
  }
}

}  // namespace

namespace {

// Images are numbered by source frame: Blender's sparks start at frame 1 (1/24 s), so a render
// of their first three frames writes frame_00001..3.png, and --frames 10:12 writes frame_00011
// and 12, removing the earlier render's frames from the folder.
TEST(RenderCommand, ImagesAreNumberedBySourceFrame) {
  const fs::path dir = test::fresh_dir();
  const fs::path clip = dir / "sparks.pstream";
  ASSERT_EQ(cook_default("sims/blender_sparks.abc", clip), 0);
  const fs::path out = dir / "frames";
  auto r =
      test::run_cli(fmt::format("render '{}' --out '{}' --frames 0:3 --size 32x32 -q", clip.string(), out.string()));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_FALSE(fs::exists(out / "frame_00000.png"));
  for (const char* name : {"frame_00001.png", "frame_00002.png", "frame_00003.png"})
    EXPECT_TRUE(fs::exists(out / name)) << name;
  r = test::run_cli(fmt::format("render '{}' --out '{}' --frames 10:12 --size 32x32 -q", clip.string(), out.string()));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(fs::exists(out / "frame_00011.png"));
  EXPECT_TRUE(fs::exists(out / "frame_00012.png"));
  EXPECT_FALSE(fs::exists(out / "frame_00001.png"));  // the folder holds exactly this render
  EXPECT_EQ(test::nth_frame(out, 2), fs::path());
}

}  // namespace

namespace {

// The automatic camera frames the frames rendered: rendering an effect's first frame that has
// particles, or its middle frame, alone frames that frame, where a render of the whole clip frames
// all of it and shows the first frames small (or not at all). The silhouette is the pixels
// brighter than the background; its span, the larger of its width and height shares of the image.
// Measured: the FLIP pour 90 % and 74 % alone (its first frame 8 % in the whole clip's render);
// the sparks 48 % (one particle: a sphere framed by its box's corners) and 60 % (0 %). Issue
// #26 asks 60 % at both frames of every render: the sparks' first frame misses it, and the whole
// clip's render frames its whole extent.
// The silhouette's span in a PNG: the larger of its width and height shares of the image (pixels
// brighter than 20 of 255; the background is (5, 6, 9)).
double span_of(const fs::path& png) {
  int w = 0, h = 0;
  const auto img = read_png(png, w, h);
  int x0 = w, x1 = -1, y0 = h, y1 = -1;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const std::size_t i = (std::size_t(y) * std::size_t(w) + std::size_t(x)) * 4;
      if (std::max({img[i], img[i + 1], img[i + 2]}) < 20) continue;
      x0 = std::min(x0, x), x1 = std::max(x1, x), y0 = std::min(y0, y), y1 = std::max(y1, y);
    }
  }
  return x1 < 0 ? 0.0 : std::max(double(x1 - x0 + 1) / w, double(y1 - y0 + 1) / h);
}

TEST(RenderCommand, TheAutomaticCameraFramesTheFramesRendered) {
  const fs::path dir = test::fresh_dir();
  constexpr int kWidth = 320, kHeight = 180;
  // Rendered with every default (the whole clip, the automatic camera's track), then with the
  // camera fixed at the track's settled framing, which shows what the track is for.
  for (const char* sim : {"sims/blender_sparks.abc", "sims/blender_flip_pour_small.abc"}) {
    SCOPED_TRACE(sim);
    const fs::path clip = dir / (fs::path(sim).stem().string() + ".pstream");
    ASSERT_EQ(cook_default(sim, clip), 0);
    const format::Metadata m = format::Reader::open(clip).metadata();
    std::uint64_t first = 0;
    while (first < m.frame_count() && m.frames[first].count == 0) ++first;
    ASSERT_LT(first, m.frame_count());
    const std::uint64_t middle = m.frame_count() / 2;
    std::array<double, 2> spans{}, fixed{};
    for (const char* camera : {"auto", "fixed"}) {
      const fs::path out = dir / fmt::format("{}_{}", fs::path(sim).stem().string(), camera);
      const auto r = test::run_cli(fmt::format("render -q '{}' --camera {} --size {}x{} --out '{}'", clip.string(),
                                               camera, kWidth, kHeight, out.string()));
      ASSERT_EQ(r.exit_code, 0) << r.output;
      auto& into = std::string_view(camera) == "auto" ? spans : fixed;
      into = {span_of(test::nth_frame(out, int(first))), span_of(test::nth_frame(out, int(middle)))};
      std::printf(
          "%s, --camera %s: the first frame with particles (%llu, %llu of them) spans %.0f%%, the middle "
          "frame (%llu) %.0f%%\n",
          sim, camera, static_cast<unsigned long long>(first), static_cast<unsigned long long>(m.frames[first].count),
          100 * into[0], static_cast<unsigned long long>(middle), 100 * into[1]);
    }
    EXPECT_GE(spans[0], 0.6) << "the first frame with particles, rendered with every default";
    EXPECT_GE(spans[1], 0.6) << "the middle frame, rendered with every default";
    EXPECT_GT(spans[0], 3 * fixed[0]) << "a fixed camera frames the grown effect: its first frame is small";
    // A render of a few frames frames those, not the clip's later extent.
    const fs::path alone = dir / (fs::path(sim).stem().string() + "_alone");
    const auto r = test::run_cli(fmt::format("render -q '{}' --frames {}:{} --size {}x{} --out '{}'", clip.string(),
                                             middle, middle + 1, kWidth, kHeight, alone.string()));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    EXPECT_GE(span_of(test::nth_frame(alone, 0)), 0.6);
  }
}

// The demo's presets, simulated at their default length (20,000 particles, 6 frames a second),
// cooked with defaults and rendered in the demo's look for each (demo_command.cpp's
// preset_render) without the ground (which the silhouette would count): each fills 60 % of the
// width or height at its first frame with particles and at its middle frame.
TEST(RenderCommand, TheAutomaticCameraFramesEveryDemoPreset) {
  const fs::path dir = test::fresh_dir();
  constexpr int kWidth = 320, kHeight = 180;
  for (const std::string& preset : demo::Simulator::presets()) {
    SCOPED_TRACE(preset);
    demo::SimulationOptions so;
    so.preset = preset;
    so.particles = 20000;
    so.fps = 6;
    demo::Simulator sim(so);
    std::vector<demo::ParticleState> states;
    cook::MemoryClip clip;
    clip.name = preset;
    clip.fps = so.fps;
    states.reserve(sim.frame_count());
    for (std::uint64_t f = 0; f < sim.frame_count(); ++f) {
      sim.step();
      states.push_back(sim.state());
    }
    for (std::size_t f = 0; f < states.size(); ++f) {
      const demo::ParticleState& s = states[f];
      clip.frames.push_back({double(f + 1) / so.fps, s.size(), s.position, s.width, s.velocity, s.id, s.color, {}});
    }
    cook::Options co;
    co.output = dir / (preset + ".pstream");
    cook::cook(co, clip);
    std::size_t first = 0;
    while (first < states.size() && states[first].size() == 0) ++first;
    ASSERT_LT(first, states.size());
    const std::size_t middle = states.size() / 2;
    const fs::path out = dir / preset;
    const std::string look = preset == "explosion" ? "--preset sparks"
                             : preset == "smoke"   ? "--preset smoke"
                                                   : "--shutter 0.0333 --size-multiplier 0.45";
    // The whole clip, two images a second (the camera's track is the whole clip's): the first
    // image is the first frame, and the middle frame lands on an image.
    const auto r = test::run_cli(fmt::format("render -q '{}' {} --backdrop none --fps 2 --size {}x{} --out '{}'",
                                             co.output.string(), look, kWidth, kHeight, out.string()));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    const auto middle_image = std::size_t(std::lround((double(middle) - double(first)) / so.fps * 2));
    ASSERT_DOUBLE_EQ(double(middle_image) / 2, (double(middle) - double(first)) / so.fps);
    const double at_first = span_of(test::nth_frame(out, 0)), at_middle = span_of(test::nth_frame(out, middle_image));
    std::printf("demo preset %s: the first frame with particles (%zu) spans %.0f%%, the middle frame (%zu) %.0f%%\n",
                preset.c_str(), first, 100 * at_first, middle, 100 * at_middle);
    EXPECT_GE(at_first, 0.6);
    EXPECT_GE(at_middle, 0.6);
  }
}

}  // namespace
