// Looks as a whole: the presets a user picks by name, and the sort order a look needs.
#include <algorithm>

#include <fmt/format.h>

#include "base/names.hpp"
#include "particlestream/playback.hpp"
#include "playback/interpolate.hpp"

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

void apply_colouring(const Colouring& c, DrawStyle& style) {
  render::SpriteStyle& s = style.sprites;
  if (!c.color_by.empty()) s.color_by = render::parse_color_by(c.color_by);
  if (!c.ramp_attribute.empty()) {
    style.ramp_attribute = c.ramp_attribute;
    if (c.color_by.empty()) s.color_by = render::ColorBy::Attribute;
  }
  if (c.range && !(c.range->at(0) < c.range->at(1)))
    throw OptionError("ramp_range", fmt::format("ramp range {},{}: expected LOW,HIGH with LOW < HIGH", c.range->at(0),
                                                c.range->at(1)));
  const float low = c.range ? c.range->at(0) : s.ramp.low, high = c.range ? c.range->at(1) : s.ramp.high;
  if (!c.ramp.empty()) {
    s.ramp = render::Ramp::named(c.ramp, low, high);
  } else {
    s.ramp.low = low, s.ramp.high = high;
  }
}

bool wants_ground(const DrawStyle& style) { return style.look == render::Look::Liquid || style.sprites.shadows; }

std::optional<render::Backdrop> backdrop_for(std::string_view choice, const DrawStyle& style,
                                             const std::array<float, 6>& bounds) {
  static constexpr std::array<std::string_view, 4> kChoices{"auto", "ground", "sky", "none"};
  if (std::find(kChoices.begin(), kChoices.end(), choice) == kChoices.end())
    throw OptionError("backdrop", fmt::format("backdrop '{}': expected auto, ground, sky or none{}", choice,
                                              did_you_mean(choice, kChoices)));
  const bool ground = choice == "ground" || (choice == "auto" && wants_ground(style));
  if (!ground && choice != "sky") return std::nullopt;
  render::Backdrop backdrop =
      render::Backdrop::under({bounds[0], bounds[1], bounds[2]}, {bounds[3], bounds[4], bounds[5]});
  backdrop.ground = ground;
  return backdrop;
}

void check_style(const DrawStyle& style, const format::Metadata& clip, std::string_view name) {
  const bool sprites = style.look == render::Look::Sprites;
  if (sprites && style.sprites.color_by == render::ColorBy::Attribute && style.ramp_attribute.empty()) {
    throw OptionError("ramp_attribute",
                      "colouring by attribute needs a `ramp_attribute`: the float attribute to colour by");
  }
  // What needs velocities: colouring by speed, and motion blur (sprites stretched along their
  // velocity). Without them the speed is 0 everywhere (a black or flat picture) and nothing
  // streaks: say so, and how to get them, instead of drawing that.
  const char* needs = !sprites                                           ? nullptr
                      : style.sprites.color_by == render::ColorBy::Speed ? "colouring by speed"
                      : style.sprites.shutter > 0.0f                     ? "motion blur (a shutter)"
                                                                         : nullptr;
  if (needs != nullptr && velocity_offset(clip) < 0) {
    throw OptionError("velocity", fmt::format("{}: {} needs velocities, and the clip has none: cook it again with "
                                              "`--attributes velocity` (without `--no-velocity`; the source must "
                                              "have velocities)",
                                              name, needs));
  }
  if (style.ramp_attribute.empty()) return;
  std::string floats;
  bool found = false;
  for (const format::Attribute& a : clip.layout) {
    if (a.type != format::AttributeType::Float32 || a.components != 1) continue;
    found = found || a.name == style.ramp_attribute;
    floats += (floats.empty() ? "" : ", ") + a.name;
  }
  if (!found) {
    throw OptionError("ramp_attribute", fmt::format("{}: `ramp_attribute` '{}' is not one of its float attributes ({})",
                                                    name, style.ramp_attribute, floats));
  }
}

std::array<float, 2> ramp_range_of(std::span<float> values, bool speeds) {
  if (values.size() < 2) return {0.0f, 1.0f};
  const auto at = [&](double q) {
    const auto it = values.begin() + std::ptrdiff_t(q * double(values.size() - 1));
    std::nth_element(values.begin(), it, values.end());
    return *it;
  };
  // Speeds from rest (0) to the 99th percentile; an attribute from its 1st to 99th percentile.
  const float low = speeds ? 0.0f : at(0.01), high = at(0.99);
  return high > low ? std::array<float, 2>{low, high} : std::array<float, 2>{low, low + 1.0f};
}

}  // namespace pstream::playback
