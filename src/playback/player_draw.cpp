// Player::draw, apart from the rest of the player: the only part that needs OpenGL, so that
// what links the player without drawing (the C API's shared library) does not pull in the
// renderer.
#include "particlestream/playback.hpp"

namespace pstream::playback {

void Player::draw(render::Renderer& renderer, const DrawStyle& style) {
  const std::span<render::ParticleBatch> batches(batches_.data(), batch_count_);
  for (auto& b : batches) {
    b.blend = style.blend;
    b.size_multiplier = style.size_multiplier;
    if (b.texture != style.texture) b.texture = style.texture;  // set once: no allocation per frame
  }
  if (style.backdrop) renderer.draw_backdrop(*style.backdrop);
  if (style.look == render::Look::Liquid) {  // one surface from every clip; needs no order
    renderer.draw_liquid(batches, style.liquid);
    return;
  }
  if (!merged_order_.empty()) {
    renderer.draw_merged(batches, merged_order_);
    return;
  }
  for (const auto& b : batches) renderer.draw(b);
}

}  // namespace pstream::playback
