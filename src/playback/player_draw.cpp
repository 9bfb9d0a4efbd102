// Player::draw_data: the frame advance() prepared, styled and described in the frame model
// (frame.hpp) for a renderer to draw. No graphics API here.
#include <algorithm>
#include <cmath>
#include <string>

#include <fmt/format.h>

#include "particlestream/playback.hpp"
#include "playback/interpolate.hpp"

namespace pstream::playback {

const render::DrawData& Player::draw_data(const DrawStyle& style) {
  const std::span<render::ParticleBatch> batches(batches_.data(), batch_count_);
  render::SpriteStyle sprites = style.sprites;
  render::LiquidStyle liquid = style.liquid;
  // The light buffers (self-shadowing sprites', the liquid's) cover the clips' world box unless the
  // style names one.
  const auto unset = [](const std::array<float, 6>& b) {
    return std::all_of(b.begin(), b.end(), [](float v) { return v == 0; });
  };
  const bool fit_bounds = style.look == render::Look::Liquid ? unset(liquid.bounds) : unset(sprites.bounds);
  const bool need_box = fit_bounds || style.bounds_box;
  std::array<float, 6> box{INFINITY, INFINITY, INFINITY, -INFINITY, -INFINITY, -INFINITY};
  for (std::size_t i = 0; i < clip_count(); ++i) {
    const std::ptrdiff_t k = batch_of(i);
    if (k < 0) continue;
    render::ParticleBatch& b = batches[std::size_t(k)];
    b.blend = style.blend;
    b.size_multiplier = style.size_multiplier;
    if (b.texture != style.texture) b.texture = style.texture;  // set once: no allocation per frame
    const stream::ParticleStream& clip = this->clip(i);
    b.tint = i < style.clip_tints.size() ? style.clip_tints[i] : std::array<float, 4>{1, 1, 1, 1};
    b.scalar_offset = -1;
    if (!style.ramp_attribute.empty()) {
      for (const format::Attribute& a : clip.layout()) {
        if (a.name == style.ramp_attribute && a.type == format::AttributeType::Float32)
          b.scalar_offset = std::int32_t(a.offset);
      }
    }
    // The clip's bounds in world space: its box's eight corners through the transform.
    const std::array<float, 6>& m = clip.metadata().bounds;
    for (int corner = 0; corner < 8 && need_box; ++corner) {
      const float x = m[corner & 1 ? 3 : 0], y = m[corner & 2 ? 4 : 1], z = m[corner & 4 ? 5 : 2];
      const render::Mat4& w = b.world;
      const float p[3] = {w[0] * x + w[4] * y + w[8] * z + w[12], w[1] * x + w[5] * y + w[9] * z + w[13],
                          w[2] * x + w[6] * y + w[10] * z + w[14]};
      for (int i = 0; i < 3; ++i) {
        box[std::size_t(i)] = std::min(box[std::size_t(i)], p[i]);
        box[std::size_t(i + 3)] = std::max(box[std::size_t(i + 3)], p[i]);
      }
    }
  }
  const bool box_found = std::all_of(box.begin(), box.end(), [](float v) { return std::isfinite(v); });
  if (fit_bounds && box_found) (style.look == render::Look::Liquid ? liquid.bounds : sprites.bounds) = box;
  render::DrawData& d = draw_data_;
  d.batches = batches;
  d.merged_order = merged_order_;
  d.look = style.look;
  d.backdrop = style.backdrop;
  if (style.backdrop && style.backdrop->ground) {  // the ground receives the shadows
    if (!sprites.ground_height) sprites.ground_height = style.backdrop->ground_height;
    if (!liquid.ground_height) liquid.ground_height = style.backdrop->ground_height;
  }
  d.sprites = sprites;
  d.liquid = liquid;
  d.sort = path_ == PlaybackPath::Gpu ? sort_mode_ : render::SortMode::None;
  d.sort_view = sort_view_;
  d.box.reset();
  if (style.bounds_box && box_found) d.box = box;
  return d;
}

void Player::check_style(const DrawStyle& style) const {
  for (std::size_t i = 0; i < clip_count(); ++i) playback::check_style(style, clip(i).metadata(), clip(i).name());
}

}  // namespace pstream::playback
