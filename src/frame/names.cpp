// The names the render options are given by (in files, on command lines, in the Python API).
#include <algorithm>
#include <initializer_list>

#include <fmt/format.h>

#include "base/names.hpp"
#include "particlestream/error.hpp"
#include "particlestream/frame.hpp"

namespace pstream::render {

BlendMode parse_blend(const std::string& name) {
  if (name == "alpha") return BlendMode::Alpha;
  if (name == "additive") return BlendMode::Additive;
  if (name == "alphatest") return BlendMode::AlphaTest;
  throw Error(fmt::format("blend mode '{}': expected alpha, additive or alphatest{}", name,
                          did_you_mean(name, {"alpha", "additive", "alphatest"})));
}

Look parse_look(const std::string& name) {
  if (name == "sprites") return Look::Sprites;
  if (name == "liquid") return Look::Liquid;
  throw Error(fmt::format("look '{}': expected sprites or liquid{}", name, did_you_mean(name, {"sprites", "liquid"})));
}

LiquidFilter parse_liquid_filter(const std::string& name) {
  if (name == "narrow-range") return LiquidFilter::NarrowRange;
  if (name == "bilateral") return LiquidFilter::Bilateral;
  if (name == "gaussian") return LiquidFilter::Gaussian;
  if (name == "none") return LiquidFilter::None;
  throw Error(fmt::format("liquid filter '{}': expected narrow-range, bilateral, gaussian or none{}", name,
                          did_you_mean(name, {"narrow-range", "bilateral", "gaussian", "none"})));
}

LiquidOutput parse_liquid_output(const std::string& name) {
  if (name == "shaded") return LiquidOutput::Shaded;
  if (name == "depth") return LiquidOutput::Depth;
  if (name == "normals") return LiquidOutput::Normals;
  if (name == "thickness") return LiquidOutput::Thickness;
  throw Error(fmt::format("liquid output '{}': expected shaded, depth, normals or thickness{}", name,
                          did_you_mean(name, {"shaded", "depth", "normals", "thickness"})));
}

ColorBy parse_color_by(const std::string& name) {
  if (name == "stored") return ColorBy::Stored;
  if (name == "speed") return ColorBy::Speed;
  if (name == "attribute") return ColorBy::Attribute;
  throw Error(fmt::format("colour source '{}': expected stored, speed or attribute{}", name,
                          did_you_mean(name, {"stored", "speed", "attribute"})));
}

ToneMap parse_tone_map(const std::string& name) {
  if (name == "filmic") return ToneMap::Filmic;
  if (name == "linear") return ToneMap::Linear;
  throw Error(
      fmt::format("tone map '{}': expected filmic or linear{}", name, did_you_mean(name, {"filmic", "linear"})));
}

Ramp Ramp::named(const std::string& name, float low, float high) {
  Ramp r;
  r.low = low;
  r.high = high;
  const auto set = [&](std::initializer_list<std::array<float, 3>> stops) {
    r.count = 0;
    for (const auto& c : stops) r.stops[std::size_t(r.count++)] = c;
  };
  if (name == "fire") {
    set({{0.02f, 0.0f, 0.0f}, {0.55f, 0.04f, 0.0f}, {1.0f, 0.35f, 0.02f}, {1.0f, 0.75f, 0.15f}, {1.0f, 0.97f, 0.85f}});
  } else if (name == "ice") {
    set({{0.02f, 0.04f, 0.12f}, {0.08f, 0.30f, 0.65f}, {0.45f, 0.75f, 0.95f}, {0.92f, 0.97f, 1.0f}});
  } else if (name == "viridis") {
    set({{0.27f, 0.00f, 0.33f},
         {0.23f, 0.32f, 0.55f},
         {0.13f, 0.57f, 0.55f},
         {0.37f, 0.79f, 0.38f},
         {0.99f, 0.91f, 0.14f}});
  } else if (name == "grey") {
    set({{0.0f, 0.0f, 0.0f}, {1.0f, 1.0f, 1.0f}});
  } else {
    throw Error(fmt::format("ramp '{}': expected fire, ice, viridis or grey", name));
  }
  return r;
}

std::array<float, 3> Ramp::at(float value) const {
  if (count <= 0) return {1, 1, 1};
  if (count == 1) return stops[0];
  const float span = high - low;
  const float t = std::clamp(span != 0 ? (value - low) / span : 0.0f, 0.0f, 1.0f);
  const float f = t * float(count - 1);
  const int i = std::min(int(f), count - 2);
  const float w = f - float(i);
  std::array<float, 3> c{};
  for (std::size_t k = 0; k < 3; ++k) c[k] = stops[std::size_t(i)][k] * (1 - w) + stops[std::size_t(i + 1)][k] * w;
  return c;
}

}  // namespace pstream::render
