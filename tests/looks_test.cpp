// How sprites look, measured on llvmpipe (what CI has) with tolerant comparisons: self-shadowing
// darkens the far side of a dense ball, shadows fall on the ground, a speed ramp gives known
// colours for known speeds, motion blur grows with velocity, a receding sub-pixel cloud keeps its
// brightness, and an additive cloud does not clip to white. PSTREAM_LOOKS_IMAGES=DIR writes the
// images the tests measure.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <random>

#include <fmt/format.h>

#include "particlestream/render.hpp"
#include "particlestream/sort.hpp"

namespace {

using namespace pstream;
using namespace pstream::render;

constexpr int kW = 320, kH = 240;

struct Particle {
  float x, y, z, scale;
  std::uint32_t rgba;  // R in the lowest byte
  float vx, vy, vz;
  float value;  // a float attribute for ramps
};

std::uint32_t rgba(float r, float g, float b, float a) {
  const auto q = [](float v) { return std::uint32_t(std::lround(std::clamp(v, 0.0f, 1.0f) * 255)); };
  return q(r) | q(g) << 8 | q(b) << 16 | q(a) << 24;
}

ParticleBatch batch_of(const std::vector<Particle>& ps) {
  ParticleBatch b;
  b.first = std::as_bytes(std::span(ps));
  b.count = ps.size();
  b.record_size = sizeof(Particle);
  b.color_offset = 16;
  b.velocity_offset = 20;
  b.scalar_offset = 32;
  return b;
}

// A ball of n particles, uniform in volume.
std::vector<Particle> ball(int n, float radius, float size, std::uint32_t color, Vec3 center = {0, 0, 0},
                           unsigned seed = 7) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<Particle> ps;
  while (int(ps.size()) < n) {
    const float x = u(rng), y = u(rng), z = u(rng);
    if (x * x + y * y + z * z > 1) continue;
    ps.push_back({center[0] + x * radius, center[1] + y * radius, center[2] + z * radius, size, color, 0, 0, 0, 0});
  }
  return ps;
}

struct Image {
  std::vector<std::uint8_t> rgba;  // top row first
  double lum(int x, int y) const {
    const std::size_t i = (std::size_t(y) * kW + std::size_t(x)) * 4;
    return (0.2126 * rgba[i] + 0.7152 * rgba[i + 1] + 0.0722 * rgba[i + 2]) / 255.0;
  }
  std::array<int, 3> at(int x, int y) const {
    const std::size_t i = (std::size_t(y) * kW + std::size_t(x)) * 4;
    return {rgba[i], rgba[i + 1], rgba[i + 2]};
  }
};

class LooksTest : public ::testing::Test {
 protected:
  HeadlessContext ctx{kW, kH};
  std::unique_ptr<Renderer> renderer;

  void SetUp() override {
    ctx.bind();
    RendererOptions o;
    o.light_direction = light;
    renderer = std::make_unique<Renderer>(o);
  }
  void use_light(const Vec3& l) {
    light = l;
    ctx.bind();
    RendererOptions o;
    o.light_direction = l;
    renderer = std::make_unique<Renderer>(o);
  }

  // Draws `ps` seen by `cam` in `style` (sorted as the style needs, as the playback layer does),
  // over an optional backdrop.
  Image draw(const Camera& cam, const std::vector<Particle>& ps, const SpriteStyle& style,
             BlendMode blend = BlendMode::Alpha, const std::optional<Backdrop>& backdrop = std::nullopt,
             const std::string& name = {}, const std::string& texture = {}) {
    ParticleBatch b = batch_of(ps);
    b.blend = blend;
    b.texture = texture;
    sort::DepthSorter sorter(ps.size());
    const HalfAngle half = half_angle(cam.view(), light);
    const bool sliced = style.shadows && blend != BlendMode::Additive;
    b.order = sorter.sort(reinterpret_cast<const std::byte*>(ps.data()), ps.size(), sizeof(Particle),
                          sliced ? half.sort_view : cam.view(),
                          sliced ? sort::SortMode::FrontToBack : sort::SortMode::BackToFront);
    ctx.bind();
    renderer->begin_frame(kW, kH, cam, {0, 0, 0, 1});
    if (backdrop) renderer->draw_backdrop(*backdrop);
    renderer->draw(b, style);
    renderer->end_frame();
    Image img{ctx.read_rgba()};
    if (const char* dir = std::getenv("PSTREAM_LOOKS_IMAGES"); dir != nullptr && !name.empty()) {
      std::filesystem::create_directories(dir);
      write_png(std::filesystem::path(dir) / (name + ".png"), kW, kH, img.rgba);
    }
    return img;
  }

  Vec3 light{-0.4f, 0.8f, 0.45f};
};

Camera front_camera(float distance = 5) {
  Camera c;
  c.eye = {0, 0, distance};
  c.target = {0, 0, 0};
  return c;
}

// ---- Sprite images ----------------------------------------------------------------------------

// An artist's sprite (`--texture`) stands upright, as the image viewer shows it: the test image's
// ring is green along its top row and red along its bottom one (tests/data/render/sprite_ring.png),
// so the sprite's upper half is green and its lower half red.
TEST_F(LooksTest, ASpriteImageIsDrawnUpright) {
  const std::vector<Particle> ps{{0, 0, 0, 1.5f, rgba(1, 1, 1, 1), 0, 0, 0, 0}};
  SpriteStyle style;
  style.lit = false;
  style.tone_map = ToneMap::Linear;
  const Image img = draw(front_camera(), ps, style, BlendMode::Alpha, std::nullopt, "sprite_image",
                         PSTREAM_TEST_DATA "/render/sprite_ring.png");
  double green_above = 0, red_above = 0, green_below = 0, red_below = 0;
  int drawn = 0;
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      const auto [r, g, b] = img.at(x, y);
      if (r + g + b < 30) continue;
      ++drawn;
      (y < kH / 2 ? red_above : red_below) += r;
      (y < kH / 2 ? green_above : green_below) += g;
    }
  }
  std::printf("sprite image: %d pixels; above the centre green %.0f, red %.0f; below green %.0f, red %.0f\n", drawn,
              green_above, red_above, green_below, red_below);
  ASSERT_GT(drawn, 2000) << "the sprite should cover much of the image";
  EXPECT_GT(green_above, 2 * red_above) << "the image's top row is drawn at the sprite's bottom";
  EXPECT_GT(red_below, 2 * green_below);
}

// ---- Self-shadowing ---------------------------------------------------------------------------

TEST_F(LooksTest, ADenseBallIsDarkerOnTheSideAwayFromTheLight) {
  use_light({1, 0, 0});  // from the right, across the view
  const auto ps = ball(6000, 1.0f, 0.07f, rgba(0.85f, 0.85f, 0.85f, 0.6f));
  SpriteStyle style;
  style.shadows = true;
  style.bounds = {-1.1f, -1.1f, -1.1f, 1.1f, 1.1f, 1.1f};
  // Mean luminance of the ball's right (lit) and left thirds, where it covers the pixel.
  const auto sides = [&](const Image& img) {
    double left = 0, right = 0;
    int nl = 0, nr = 0;
    const int cx = kW / 2,
              r = int(1.0 / std::tan(22.5 * 3.14159265 / 180) / 5 * kH / 2);  // the ball's radius in pixels
    for (int y = kH / 2 - r / 2; y < kH / 2 + r / 2; ++y) {
      for (int x = cx - r; x < cx + r; ++x) {
        if (x < cx - r / 3) left += img.lum(x, y), ++nl;
        if (x > cx + r / 3) right += img.lum(x, y), ++nr;
      }
    }
    return std::pair{left / nl, right / nr};
  };
  const Image shadowed = draw(front_camera(), ps, style, BlendMode::Alpha, std::nullopt, "ball_shadowed");
  style.shadows = false;
  const Image plain = draw(front_camera(), ps, style, BlendMode::Alpha, std::nullopt, "ball_unshadowed");
  const auto [sl, sr] = sides(shadowed);
  const auto [pl, pr] = sides(plain);
  const double with = sr / sl, without = pr / pl;
  RecordProperty("contrast_with_shadows", fmt::format("{:.3f}", with));
  RecordProperty("contrast_without", fmt::format("{:.3f}", without));
  std::printf("lit/far side luminance: with shadows %.3f / %.3f = %.2f, without %.3f / %.3f = %.2f\n", sr, sl, with, pr,
              pl, without);
  EXPECT_GT(with, 1.8) << "the far side should be in the ball's own shadow";
  EXPECT_NEAR(without, 1.0, 0.08) << "without shadows both sides are lit alike";
  EXPECT_GT(sl, 0.03) << "the shadowed side still shows (ambient light)";
}

// Half-angle slicing must not band: a dense column lit along its length (the light from the side
// of the view) darkens smoothly along it. The luminance profile along the column, its slow trend
// removed, has no peak at the slices' period above 2 % of the mean, with 32 and with 128 slices,
// and the two give the same mean luminance within 5 %.
TEST_F(LooksTest, SlicedShadowsDoNotBand) {
  use_light({1, 0, 0});  // along the column, across the view
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<Particle> ps;
  while (ps.size() < 12000) {  // a column along x: length 3, radius 0.25
    const float x = u(rng) * 1.5f, y = u(rng) * 0.25f, z = u(rng) * 0.25f;
    if (y * y + z * z > 0.0625f) continue;
    ps.push_back({x, y, z, 0.05f, rgba(0.85f, 0.85f, 0.85f, 0.5f), 0, 0, 0, 0});
  }
  SpriteStyle style;
  style.shadows = true;
  style.shadow_density = 0.012f;  // light reaches along the whole column, fading: a gradient bands would show in
  style.bounds = {-1.6f, -0.3f, -0.3f, 1.6f, 0.3f, 0.3f};
  const Camera cam = front_camera();
  const double px_per_unit = kH / 2.0 / (std::tan(22.5 * 3.14159265358979 / 180) * 5);
  // The slices' period along the column in pixels: slices hold equal counts along the half-angle
  // axis, so for a uniform column they are equally spaced along it.
  const sort::DepthAxis axis = sort::depth_axis(half_angle(cam.view(), light).sort_view);
  float lo = INFINITY, hi = -INFINITY;
  for (const Particle& p : ps) {
    const float d = axis.x * p.x + axis.y * p.y + axis.z * p.z;
    lo = std::min(lo, d), hi = std::max(hi, d);
  }
  const double norm = std::sqrt(double(axis.x) * axis.x + double(axis.y) * axis.y + double(axis.z) * axis.z);
  const double along_x = std::abs(axis.x) / norm;
  double means[2]{}, lit_end = 0, far_end = 1;
  int k = 0;
  for (const int slices : {32, 128}) {
    style.slices = slices;
    const Image img = draw(cam, ps, style, BlendMode::Alpha, std::nullopt, fmt::format("column_{}_slices", slices));
    // The profile along the column's middle third of rows, over its inner 80 % (away from its ends).
    const int half_len = int(1.5 * px_per_unit * 0.8), half_h = int(0.25 * px_per_unit / 3);
    std::vector<double> profile;
    for (int x = kW / 2 - half_len; x < kW / 2 + half_len; ++x) {
      double sum = 0;
      for (int y = kH / 2 - half_h; y <= kH / 2 + half_h; ++y) sum += img.lum(x, y);
      profile.push_back(sum / (2 * half_h + 1));
    }
    double mean = 0;
    for (const double v : profile) mean += v;
    mean /= double(profile.size());
    means[k++] = mean;
    lit_end = profile.back(), far_end = profile.front();
    const double period = (hi - lo) / norm / slices / along_x * px_per_unit;
    // The slow trend (the shadow deepening along the light) out: a moving average of twice the period.
    const int w = std::max(2, int(std::lround(period)));
    std::vector<double> detail(profile.size(), 0.0);
    for (std::size_t i = 0; i < profile.size(); ++i) {
      double s = 0;
      int n = 0;
      for (int j = -w; j <= w; ++j) {
        const auto at = std::ptrdiff_t(i) + j;
        if (at >= 0 && at < std::ptrdiff_t(profile.size())) s += profile[std::size_t(at)], ++n;
      }
      detail[i] = profile[i] - s / n;
    }
    // The largest Fourier amplitude at periods within 25 % of the slices'.
    double peak = 0;
    for (double p = period * 0.75; p <= period * 1.25; p += period * 0.05) {
      double re = 0, im = 0;
      for (std::size_t i = 0; i < detail.size(); ++i) {
        re += detail[i] * std::cos(2 * 3.14159265358979 * double(i) / p);
        im += detail[i] * std::sin(2 * 3.14159265358979 * double(i) / p);
      }
      peak = std::max(peak, 2 * std::sqrt(re * re + im * im) / double(detail.size()));
    }
    std::printf(
        "%d slices: period %.2f px, luminance %.4f (lit end) .. %.4f (far end), mean %.4f, peak at the slice "
        "period %.5f (%.2f %% of the mean)\n",
        slices, period, profile.back(), profile.front(), mean, peak, 100 * peak / mean);
    if (period >= 2.0) {  // shorter than 2 pixels, a band cannot show
      EXPECT_LT(peak, 0.02 * mean) << slices << " slices band at their period (" << period << " px)";
    }
  }
  EXPECT_NEAR(means[0] / means[1], 1.0, 0.05) << "32 and 128 slices should light the column alike";
  EXPECT_GT(lit_end / far_end, 1.15) << "the column should darken along the light (else the test sees no gradient)";
}

// Where the cloud thins out along the half-angle (the top of a smoke plume), slices of equal
// counts are thick in depth and their particles do not shadow each other: bands at the slices'
// borders (docs/rendering.md, "Where the slices are cut"). A column along the half-angle, a dense
// core of 9,000 particles over its first 0.8 and a sparse tail of 2,000 over the next 3.2, drawn
// with the smoke preset's 48 slices and with 256: over the tail's pixels the two differ by under
// 3 % of the tail's mean luminance on average and under 10 % in any 8x8 block (1.6 % and 5.6 %).
// With slices of equal counts (before 2026-11-30) the same measures gave 6.4 % and 16.3 %.
TEST_F(LooksTest, SlicesStayThinWhereTheCloudThins) {
  use_light({1, 0, 0});  // from the side: the half-angle 45 degrees into the view, the column seen along its length
  const Camera cam = front_camera(6);
  const HalfAngle half = half_angle(cam.view(), light);
  const Vec3 s{-half.sort_view[2], -half.sort_view[6], -half.sort_view[10]};  // front to back, away from the light
  const auto cross = [](const Vec3& p, const Vec3& q) {
    return Vec3{p[1] * q[2] - p[2] * q[1], p[2] * q[0] - p[0] * q[2], p[0] * q[1] - p[1] * q[0]};
  };
  Vec3 a = cross(s, {0, 0, 1});  // across the column
  const float len = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
  a = {a[0] / len, a[1] / len, a[2] / len};
  const Vec3 b = cross(s, a);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<Particle> ps;
  const auto add = [&](float along) {
    float x, y;
    do x = u(rng), y = u(rng);
    while (x * x + y * y > 1);
    x *= 0.35f, y *= 0.35f;
    const float t = along - 2.0f;  // the column's middle at the origin
    ps.push_back({s[0] * t + a[0] * x + b[0] * y, s[1] * t + a[1] * x + b[1] * y, s[2] * t + a[2] * x + b[2] * y, 0.09f,
                  rgba(0.8f, 0.8f, 0.8f, 0.55f), 0, 0, 0, 0});
  };
  for (int i = 0; i < 9000; ++i) add(0.4f * (u(rng) + 1));
  for (int i = 0; i < 2000; ++i) add(0.8f + 1.6f * (u(rng) + 1));
  SpriteStyle style;
  style.shadows = true;
  style.shadow_density = 0.25f;
  style.bounds = {-2.5f, -2.5f, -2.5f, 2.5f, 2.5f, 2.5f};
  style.slices = 48;
  const Image few = draw(cam, ps, style, BlendMode::Alpha, std::nullopt, "thin_tail_48_slices");
  style.slices = 256;
  const Image many = draw(cam, ps, style, BlendMode::Alpha, std::nullopt, "thin_tail_256_slices");
  // The tail's pixels: the screen box of its particles' centres, where the 256-slice image is not
  // background, compared in 8x8 blocks (blocks mostly background left out).
  const Mat4 vp = multiply(cam.projection(float(kW) / kH), cam.view());
  int x0 = kW, x1 = 0, y0 = kH, y1 = 0;
  for (std::size_t i = 9000; i < ps.size(); ++i) {
    const float* m = vp.data();
    const float p[3] = {ps[i].x, ps[i].y, ps[i].z};
    const float cx = m[0] * p[0] + m[4] * p[1] + m[8] * p[2] + m[12],
                cy = m[1] * p[0] + m[5] * p[1] + m[9] * p[2] + m[13];
    const float cw = m[3] * p[0] + m[7] * p[1] + m[11] * p[2] + m[15];
    const int px = int((cx / cw * 0.5f + 0.5f) * kW), py = int((0.5f - cy / cw * 0.5f) * kH);
    x0 = std::min(x0, px), x1 = std::max(x1, px), y0 = std::min(y0, py), y1 = std::max(y1, py);
  }
  double diff = 0, mean = 0;
  int n = 0;
  double worst = 0;
  for (int by = std::max(0, y0); by + 8 <= std::min(kH, y1); by += 8) {
    for (int bx = std::max(0, x0); bx + 8 <= std::min(kW, x1); bx += 8) {
      double d = 0, l = 0;
      int lit = 0;
      for (int y = by; y < by + 8; ++y) {
        for (int x = bx; x < bx + 8; ++x) {
          if (many.lum(x, y) < 0.02) continue;  // background
          d += std::abs(few.lum(x, y) - many.lum(x, y));
          l += many.lum(x, y);
          ++lit;
        }
      }
      if (lit < 48) continue;  // mostly background
      diff += d, mean += l, n += lit;
      worst = std::max(worst, d / l);
    }
  }
  ASSERT_GT(n, 2000) << "the tail should cover the image";
  std::printf(
      "tail: %d pixels, 48 against 256 slices: %.2f %% of the luminance on average, %.2f %% in the worst block\n", n,
      100 * diff / mean, 100 * worst);
  EXPECT_LT(diff / mean, 0.03) << "48 slices light the thin tail unlike 256";
  EXPECT_LT(worst, 0.10) << "a band: one block of the tail lit unlike 256 slices light it";
}

TEST_F(LooksTest, ShadowsFallOnTheGround) {
  use_light({0.25f, 1.0f, 0.1f});  // from above
  const auto ps = ball(3000, 0.6f, 0.06f, rgba(0.8f, 0.8f, 0.8f, 0.7f), {0, 0.4f, 0});
  Camera cam;
  cam.eye = {0, 2.5f, 5.0f};
  cam.target = {0, -0.2f, 0};
  Backdrop ground;
  ground.ground_height = -1.0f;
  ground.grid_spacing = 0.5f;
  SpriteStyle style;
  style.shadows = true;
  style.bounds = {-0.7f, -0.3f, -0.7f, 0.7f, 1.1f, 0.7f};
  style.ground_height = ground.ground_height;
  const Image with = draw(cam, ps, style, BlendMode::Alpha, ground, "ground_shadowed");
  style.shadows = false;
  const Image without = draw(cam, ps, style, BlendMode::Alpha, ground, "ground_unshadowed");
  const Image empty = draw(cam, {}, style, BlendMode::Alpha, ground);
  // Ground pixels the particles do not cover (the picture without shadows equals the empty
  // scene there) that the shadow darkens by more than a quarter.
  int ground_pixels = 0, darkened = 0;
  double sum_ratio = 0, shadow_y = 0, ball_y = 0, ball_n = 0;
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      const double e = empty.lum(x, y), p = without.lum(x, y), s = with.lum(x, y);
      if (std::abs(p - e) > 2.0 / 255) {
        ball_y += y, ++ball_n;
        continue;
      }
      ++ground_pixels;
      if (s < 0.75 * p) {
        ++darkened;
        sum_ratio += s / p;
        shadow_y += y;
      }
    }
  }
  std::printf(
      "ground shadow: %d pixels darkened (mean to %.2f of their light), centroid row %.1f; particles' row %.1f\n",
      darkened, darkened ? sum_ratio / darkened : 0.0, darkened ? shadow_y / darkened : 0.0,
      ball_n ? ball_y / ball_n : 0.0);
  EXPECT_GT(darkened, 400) << "a shadow on the ground";
  EXPECT_LT(sum_ratio / std::max(darkened, 1), 0.6);
  EXPECT_GT(shadow_y / std::max(darkened, 1), ball_y / std::max(ball_n, 1.0)) << "the shadow lies below the ball";
  // Without shadows the ground is untouched.
  int changed = 0;
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) changed += std::abs(without.lum(x, y) - empty.lum(x, y)) > 2.0 / 255;
  EXPECT_LT(changed, 0.12 * kW * kH);  // only the ball itself
}

// ---- Colour -------------------------------------------------------------------------------------

TEST_F(LooksTest, ASpeedRampMapsKnownSpeedsToKnownColours) {
  std::vector<Particle> ps;
  const float speeds[] = {0.0f, 1.0f, 2.5f, 4.0f, 6.0f};
  for (int i = 0; i < 5; ++i) {
    const float v = speeds[i];
    ps.push_back({-1.6f + 0.8f * float(i), 0, 0, 0.3f, rgba(1, 1, 1, 1), v * 0.6f, 0, v * 0.8f, 0});
  }
  SpriteStyle style;
  style.color_by = ColorBy::Speed;
  style.ramp = Ramp::named("viridis", 0.0f, 5.0f);  // 6 is past the end: the last colour
  style.lit = false;
  style.tone_map = ToneMap::Linear;
  const Image img = draw(front_camera(), ps, style, BlendMode::Alpha, std::nullopt, "speed_ramp");
  const double px_per_unit = 1.0 / std::tan(22.5 * 3.14159265 / 180) / 5 * kH / 2;
  for (int i = 0; i < 5; ++i) {
    const int x = int(std::lround(kW / 2 + (-1.6 + 0.8 * i) * px_per_unit)), y = kH / 2;
    const auto want = style.ramp.at(speeds[i]);
    const auto got = img.at(x, y);
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(got[std::size_t(c)], want[std::size_t(c)] * 255, 4) << "speed " << speeds[i] << ", channel " << c;
    }
  }
  // A float attribute through the same ramp.
  for (int i = 0; i < 5; ++i) ps[std::size_t(i)].value = speeds[i], ps[std::size_t(i)].vx = ps[std::size_t(i)].vz = 0;
  style.color_by = ColorBy::Attribute;
  const Image by_value = draw(front_camera(), ps, style);
  for (std::size_t k = 0; k < img.rgba.size(); ++k) ASSERT_NEAR(by_value.rgba[k], img.rgba[k], 1);
}

TEST_F(LooksTest, AnAdditiveCloudDoesNotClipToWhite) {
  // 3,000 orange sparks in a small ball: dozens overlap in every pixel of the core.
  const auto ps = ball(3000, 0.5f, 0.05f, rgba(1.0f, 0.45f, 0.1f, 1.0f));
  SpriteStyle style;  // defaults: filmic tone map, exposure 1
  style.lit = false;
  const Image hdr = draw(front_camera(), ps, style, BlendMode::Additive, std::nullopt, "additive_filmic");
  style.tone_map = ToneMap::Linear;
  const Image clipped = draw(front_camera(), ps, style, BlendMode::Additive, std::nullopt, "additive_linear");
  int white_hdr = 0, white_linear = 0, bright = 0;
  std::array<int, 3> brightest{};
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      const auto a = hdr.at(x, y), b = clipped.at(x, y);
      white_hdr += std::min({a[0], a[1], a[2]}) >= 250;
      white_linear += std::min({b[0], b[1], b[2]}) >= 250;
      bright += a[0] >= 200;
      if (a[0] + a[1] + a[2] > brightest[0] + brightest[1] + brightest[2]) brightest = a;
    }
  }
  std::printf(
      "additive core: %d white pixels tone-mapped, %d linear; brightest (%d, %d, %d); %d pixels with R >= 200\n",
      white_hdr, white_linear, brightest[0], brightest[1], brightest[2], bright);
  EXPECT_EQ(white_hdr, 0);
  EXPECT_GT(white_linear, 300) << "the linear control does clip";
  EXPECT_GE(brightest[0], 230) << "the core glows";
  EXPECT_LT(brightest[2], brightest[0] / 2) << "and keeps its hue";
  EXPECT_GT(bright, 300);
}

// Bloom spreads an additive cloud's light beyond the sprites' footprint and keeps its total: the
// linear tone map, exposed so that nothing clips, lets the 8-bit image be summed as light.
TEST_F(LooksTest, BloomSpreadsLightBeyondTheSpritesAndKeepsItsTotal) {
  const auto ps = ball(800, 0.8f, 0.03f, rgba(1.0f, 0.5f, 0.15f, 1.0f));
  SpriteStyle style;
  style.lit = false;
  style.tone_map = ToneMap::Linear;
  style.exposure = 0.12f;
  const Image plain = draw(front_camera(), ps, style, BlendMode::Additive, std::nullopt, "bloom_off");
  style.bloom = 0.5f;
  style.bloom_radius = 0.02f;
  const Image glow = draw(front_camera(), ps, style, BlendMode::Additive, std::nullopt, "bloom_on");
  // The footprint: every pixel the plain render lights, grown by one pixel.
  std::vector<std::uint8_t> footprint(std::size_t(kW) * kH, 0);
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      const auto c = plain.at(x, y);
      if (c[0] + c[1] + c[2] == 0) continue;
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          const int u = std::clamp(x + dx, 0, kW - 1), v = std::clamp(y + dy, 0, kH - 1);
          footprint[std::size_t(v) * kW + std::size_t(u)] = 1;
        }
      }
    }
  }
  double total_plain = 0, total_glow = 0, outside_plain = 0, outside_glow = 0;
  int brightest = 0;
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      const auto a = plain.at(x, y), b = glow.at(x, y);
      const double la = a[0] + a[1] + a[2], lb = b[0] + b[1] + b[2];
      brightest = std::max({brightest, a[0], a[1], a[2]});
      total_plain += la;
      total_glow += lb;
      if (!footprint[std::size_t(y) * kW + std::size_t(x)]) {
        outside_plain += la;
        outside_glow += lb;
      }
    }
  }
  std::printf("bloom: total %.0f -> %.0f (%.3fx); outside the sprites %.2f%% -> %.2f%% of it; brightest %d\n",
              total_plain, total_glow, total_glow / total_plain, 100 * outside_plain / total_plain,
              100 * outside_glow / total_glow, brightest);
  ASSERT_LT(brightest, 250) << "the control must not clip, or the totals are not light";
  ASSERT_GT(total_plain, 0.0);
  EXPECT_NEAR(total_glow / total_plain, 1.0, 0.05) << "bloom moves light, it does not add any";
  EXPECT_EQ(outside_plain, 0.0);
  // Half the light blurred with sigma 4.8 px, over a cloud about 45 px across: about 0.8 sigma / R
  // of the blurred half lands outside, some 4 %.
  EXPECT_GT(outside_glow / total_glow, 0.02) << "the glow reaches past the sprites";
}

TEST_F(LooksTest, EachStreamTakesItsTint) {
  // Two white streams side by side, drawn as one merged order; the second tinted orange.
  const std::vector<Particle> a = {{-0.8f, 0, 0, 0.4f, rgba(1, 1, 1, 1), 0, 0, 0, 0}};
  const std::vector<Particle> b = {{0.8f, 0, 0, 0.4f, rgba(1, 1, 1, 1), 0, 0, 0, 0}};
  std::array<ParticleBatch, 2> batches{batch_of(a), batch_of(b)};
  batches[1].tint = {1.0f, 0.55f, 0.2f, 1.0f};
  const std::vector<std::uint32_t> order = {0u, 1u << 28};
  SpriteStyle style;
  style.lit = false;
  style.tone_map = ToneMap::Linear;
  ctx.bind();
  renderer->begin_frame(kW, kH, front_camera(), {0, 0, 0, 1});
  renderer->draw_merged(batches, order, style);
  renderer->end_frame();
  const Image img{ctx.read_rgba()};
  const double px_per_unit = 1.0 / std::tan(22.5 * 3.14159265 / 180) / 5 * kH / 2;
  const auto left = img.at(int(kW / 2 - 0.8 * px_per_unit), kH / 2),
             right = img.at(int(kW / 2 + 0.8 * px_per_unit), kH / 2);
  EXPECT_NEAR(left[0], 255, 3);
  EXPECT_NEAR(left[2], 255, 3);
  EXPECT_NEAR(right[0], 255, 3);
  EXPECT_NEAR(right[1], 0.55 * 255, 4);
  EXPECT_NEAR(right[2], 0.2 * 255, 4);
}

// ---- Motion and size ---------------------------------------------------------------------------

TEST_F(LooksTest, MotionBlurLengthIsProportionalToVelocity) {
  // Three sparks in a column: still, moving right at v and at 2v.
  const float v = 4.0f;
  std::vector<Particle> ps = {{0, 0.8f, 0, 0.06f, rgba(1, 1, 1, 1), 0, 0, 0, 0},
                              {0, 0, 0, 0.06f, rgba(1, 1, 1, 1), v, 0, 0, 0},
                              {0, -0.8f, 0, 0.06f, rgba(1, 1, 1, 1), 2 * v, 0, 0, 0}};
  SpriteStyle style;
  style.shutter = 1.0f / 48;  // half of a 24 fps frame
  style.lit = false;
  style.tone_map = ToneMap::Linear;
  const Image img = draw(front_camera(), ps, style, BlendMode::Alpha, std::nullopt, "motion_blur");
  const double px_per_unit = 1.0 / std::tan(22.5 * 3.14159265 / 180) / 5 * kH / 2;
  // Each spark's total brightness (its row band), and its width at half its own peak along the
  // row through it: a streak is flat along its straight part, so that width grows by exactly the
  // straight part's length, whatever the disc's soft edge.
  const auto measure = [&](float world_y) {
    const int y = int(std::lround(kH / 2 - world_y * px_per_unit));
    double sum = 0, peak = 0;
    for (int yy = y - 12; yy <= y + 12; ++yy)
      for (int x = 0; x < kW; ++x) sum += img.lum(x, yy);
    for (int x = 0; x < kW; ++x) peak = std::max(peak, img.lum(x, y));
    const double half = peak / 2;
    double left = 0, right = 0;
    for (int x = 1; x < kW; ++x) {  // crossings of half the peak, interpolated between pixels
      const double a = img.lum(x - 1, y), b = img.lum(x, y);
      if (a < half && b >= half && left == 0) left = x - 1 + (half - a) / (b - a);
      if (a >= half && b < half) right = x - 1 + (a - half) / (a - b);
    }
    return std::pair{right - left, sum};
  };
  const auto [w0, e0] = measure(0.8f);
  const auto [w1, e1] = measure(0.0f);
  const auto [w2, e2] = measure(-0.8f);
  const double one = w1 - w0, two = w2 - w0;
  const double expected = v * style.shutter * px_per_unit;  // the streak's length at v, pixels
  std::printf("streak lengths: %.2f px at v, %.2f px at 2v (expected %.2f, %.2f); total brightness %.1f %.1f %.1f\n",
              one, two, expected, 2 * expected, e0, e1, e2);
  EXPECT_NEAR(one, expected, 0.8);
  EXPECT_NEAR(two, 2 * expected, 0.8);
  EXPECT_NEAR(two / one, 2.0, 0.2);
  EXPECT_NEAR(e1 / e0, 1.0, 0.08) << "a streak is as bright in total as the still spark";
  EXPECT_NEAR(e2 / e0, 1.0, 0.08);
}

TEST_F(LooksTest, ASubPixelCloudKeepsItsBrightnessAsItRecedes) {
  // A 12 x 12 sheet of tiny additive particles, facing the camera, at growing distances: each
  // particle's image shrinks with the square of the distance, so brightness x distance^2 stays
  // constant while they are larger than a pixel, and must stay so below a pixel.
  std::vector<Particle> ps;
  for (int j = 0; j < 12; ++j)
    for (int i = 0; i < 12; ++i)
      ps.push_back({-0.165f + 0.03f * float(i) + 0.0037f * float(j % 3),
                    -0.165f + 0.03f * float(j) + 0.0041f * float(i % 4), 0, 0.006f, rgba(1, 1, 1, 1), 0, 0, 0, 0});
  const auto total = [&](const std::vector<Particle>& cloud, float distance, const SpriteStyle& style,
                         const std::string& name = {}) {
    const Image img = draw(front_camera(distance), cloud, style, BlendMode::Additive, std::nullopt, name);
    double sum = 0;
    for (std::size_t k = 0; k < img.rgba.size(); k += 4) sum += img.rgba[k];
    return sum * distance * distance;
  };
  const auto radius_px = [](float d) { return 0.006 / std::tan(22.5 * 3.14159265 / 180) * kH / 2 / d; };
  SpriteStyle style;
  style.lit = false;
  style.tone_map = ToneMap::Linear;
  const double reference = total(ps, 1.2f, style, "subpixel_1.2");  // radius 1.45 px
  for (float d : {2.4f, 4.8f, 9.6f}) {                              // 0.72, 0.36, 0.18 px
    const double kept = total(ps, d, style, fmt::format("subpixel_{:.1f}", d)) / reference;
    std::printf("distance %.1f (radius %.2f px): brightness x d^2 %.3f of the near cloud\n", d, radius_px(d), kept);
    EXPECT_NEAR(kept, 1.0, 0.12) << "distance " << d;
  }
  // One particle of 0.18 px radius moved across a pixel in eighths: with the floor it shows at
  // every position with about the same brightness; without it, it vanishes between pixel centres.
  SpriteStyle raw = style;
  raw.min_pixels = 0;
  double kept_min = 1e30, kept_max = 0;
  int raw_gone = 0;
  for (int k = 0; k < 8; ++k) {
    const float shift = float(k) / 8 * 9.6f / float(1.0 / std::tan(22.5 * 3.14159265 / 180) * kH / 2);  // k/8 pixel
    const std::vector<Particle> one = {{shift, 0.3f * shift, 0, 0.006f, rgba(1, 1, 1, 1), 0, 0, 0, 0}};
    const double a = total(one, 9.6f, style), b = total(one, 9.6f, raw);
    kept_min = std::min(kept_min, a), kept_max = std::max(kept_max, a);
    raw_gone += b == 0;
  }
  std::printf(
      "one 0.18 px particle at 8 sub-pixel positions: brightness %.0f..%.0f with the floor; without it, "
      "invisible at %d of 8\n",
      kept_min, kept_max, raw_gone);
  EXPECT_GT(kept_min, 0.55 * kept_max) << "always visible, about as bright";
  EXPECT_GE(raw_gone, 4) << "without the floor it vanishes between pixel centres";
}

}  // namespace
