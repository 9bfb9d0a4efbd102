// Looks as a whole: the presets a user picks by name, and the sort order a look needs.
#include <fmt/format.h>

#include "base/names.hpp"
#include "particlestream/playback.hpp"

namespace pstream::playback {

SortPlan sort_plan(const DrawStyle& style, const render::Mat4& camera_view, const render::Vec3& light_direction,
                   sort::SortMode requested) {
  // Only alpha-blended sprites depend on the order: additive light and alpha-tested cut-outs do
  // not, nor does the liquid's surface.
  if (style.look != render::Look::Sprites || style.blend != render::BlendMode::Alpha) {
    return {camera_view, sort::SortMode::None};
  }
  if (!style.sprites.shadows || requested == sort::SortMode::None) return {camera_view, requested};
  return {render::half_angle(camera_view, light_direction).sort_view, sort::SortMode::FrontToBack};
}

std::array<std::array<float, 4>, 8> DrawStyle::white_tints() {
  std::array<std::array<float, 4>, 8> t{};
  for (auto& c : t) c = {1, 1, 1, 1};
  return t;
}

std::array<std::array<float, 4>, 8> DrawStyle::distinct_tints() {
  return {{{1, 1, 1, 1},
           {1.0f, 0.55f, 0.35f, 1},
           {0.45f, 1.0f, 0.5f, 1},
           {1.0f, 0.9f, 0.35f, 1},
           {0.85f, 0.5f, 1.0f, 1},
           {0.4f, 0.95f, 1.0f, 1},
           {1.0f, 0.5f, 0.75f, 1},
           {0.7f, 0.7f, 0.7f, 1}}};
}

DrawStyle look_preset(std::string_view name) {
  DrawStyle s;
  render::SpriteStyle& p = s.sprites;
  if (name == "sprites") return s;
  if (name == "smoke") {  // soft, self-shadowed puffs
    p.shadows = true;
    p.slices = 48;
    p.opacity = 0.55f;
    p.shadow_density = 1.0f;
    return s;
  }
  if (name == "sparks") {  // additive, glowing, streaked along their motion over half a 24 fps frame
    s.blend = render::BlendMode::Additive;
    p.lit = false;
    p.shutter = 1.0f / 48;
    // Sparks are light: exposed to burn bright at their core, with a third of it spread into a
    // glow of about 1 % of the image around them (the tone map keeps hot light in its hue).
    p.exposure = 3.0f;
    p.bloom = 0.35f;
    p.bloom_radius = 0.012f;
    return s;
  }
  if (name == "liquid-sprites") {  // water as lit droplets, coloured by speed
    p.color_by = render::ColorBy::Speed;
    p.ramp = render::Ramp::named("ice", 0.0f, 3.0f);
    return s;
  }
  if (name == "debug") {  // stored colours, flat, untouched by tone or size floors
    p.lit = false;
    p.tone_map = render::ToneMap::Linear;
    p.min_pixels = 0.0f;
    return s;
  }
  if (name == "liquid") {
    s.look = render::Look::Liquid;
    return s;
  }
  throw Error(fmt::format("look preset '{}': expected sprites, smoke, sparks, liquid-sprites, liquid or debug{}", name,
                          did_you_mean(name, {"sprites", "smoke", "sparks", "liquid-sprites", "liquid", "debug"})));
}

}  // namespace pstream::playback
