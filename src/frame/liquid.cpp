// The liquid's passes as numbers: what a renderer derives from a LiquidStyle for one image
// (frame.hpp: liquid_passes), shared by the native passes and the browser player.
#include <algorithm>
#include <cmath>

#include "particlestream/frame.hpp"

namespace pstream::render {

LiquidPasses liquid_passes(const LiquidStyle& style, float world_scale, float image_radius, const Mat4& projection,
                           int width, int height) {
  LiquidPasses p;
  // Lengths in view units: the style's are in particle radii.
  const float radius = style.particle_radius > 0 ? style.particle_radius * world_scale : image_radius;
  const float resolution = std::clamp(style.resolution, 0.25f, 1.0f);
  p.width = std::max(1, int(std::lround(float(width) * resolution)));
  p.height = std::max(1, int(std::lround(float(height) * resolution)));
  p.radius = radius;
  p.fixed_radius = style.particle_radius > 0 ? style.particle_radius : 0.0f;
  // A world length through the projection's focal length: the filter's radius is `smoothing` of
  // these, the highlight's taps one apart.
  p.radius_px_at_1 = radius * projection[5] * 0.5f * float(p.height);
  const int iterations = style.filter == LiquidFilter::None ? 0 : std::clamp(style.iterations, 0, kLiquidMaxIterations);
  p.filter_passes = iterations > 0 ? kLiquidRampPasses + iterations : 0;
  p.filter_mode = style.filter == LiquidFilter::NarrowRange ? 0 : style.filter == LiquidFilter::Bilateral ? 1 : 2;
  p.filter_radius_at_1 = style.smoothing * p.radius_px_at_1;
  p.range = std::max(style.depth_range, 0.01f) * radius;
  p.color_depth = std::max(style.color_depth, 0.01f) * radius;
  for (std::size_t c = 0; c < 3; ++c) p.absorb[c] = -std::log(std::clamp(style.color[c], 1e-3f, 1.0f)) / p.color_depth;
  p.refraction = std::clamp(style.refraction, 0.0f, 4.0f);
  p.opacity_depth = std::max(style.opacity_depth, 0.0f) * radius;
  p.foam_speed = style.foam_speed;
  p.foam_thickness = style.foam_isolation * radius;
  p.spray = style.output == LiquidOutput::Shaded && (style.foam_isolation > 0 || style.foam_speed > 0);
  // A shadow needs a ground to fall on, and a surface: the inspection views show the buffers alone.
  const bool shadow = style.ground_height && style.output == LiquidOutput::Shaded && style.shadow_depth > 0 &&
                      style.shadow_strength > 0;
  p.shadow_depth = shadow ? style.shadow_depth * radius : 0.0f;
  p.shadow_strength = std::clamp(style.shadow_strength, 0.0f, 1.0f);
  p.shadow_resolution = std::clamp(style.shadow_resolution, 64, 4096);
  return p;
}

std::array<float, 3 * kLiquidFilterPairs> liquid_filter_taps(int pass) {
  constexpr double kGoldenAngle = 2.39996322972865332;
  const double turn = double(1.1f * float(pass));
  std::array<float, 3 * kLiquidFilterPairs> taps{};
  for (int i = 0; i < kLiquidFilterPairs; ++i) {
    const double r2 = (i + 0.5) / kLiquidFilterPairs, t = i * kGoldenAngle + turn, r = std::sqrt(r2);
    taps[std::size_t(3 * i)] = float(r * std::cos(t));
    taps[std::size_t(3 * i + 1)] = float(r * std::sin(t));
    taps[std::size_t(3 * i + 2)] = float(std::exp(-2.0 * r2));
  }
  return taps;
}

float liquid_filter_scale(int pass) {
  return pass < kLiquidRampPasses ? std::ldexp(1.0f, pass - kLiquidRampPasses) : 1.0f;
}

}  // namespace pstream::render
