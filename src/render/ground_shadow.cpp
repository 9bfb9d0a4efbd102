// The light buffer shared by the looks that cast shadows (self-shadowing sprites, the liquid) and
// the shadow it casts on the ground: one full-screen triangle whose pixels find where their view
// ray meets the ground (shaders/ground_ray.glsl) and multiply the ground by the light that is left
// there (shaders/ground_shadow.frag).
#include <algorithm>

#include "gl_program.hpp"
#include "passes.hpp"
#include "shaders.hpp"

namespace pstream::render::detail {

std::array<float, 16 * kMaxBatches> model_views(const Mat4& view, std::span<const ParticleBatch> source,
                                                std::size_t n) {
  std::array<float, 16 * kMaxBatches> out{};
  for (std::size_t k = 0; k < std::min({n, source.size(), kMaxBatches}); ++k) {
    const Mat4 m = multiply(view, source[k].world);
    std::copy(m.begin(), m.end(), out.begin() + 16 * std::ptrdiff_t(k));
  }
  return out;
}

ShadowBuffer::ShadowBuffer() {
  program_ = link_program(full_screen_vertex_source().c_str(),
                          glsl_source({kShader_ground_ray_glsl, kShader_ground_shadow_frag}).c_str());
  const auto loc = [&](const char* name) { return glGetUniformLocation(program_, name); };
  view_ = loc("u_view");
  projection_ = loc("u_projection");
  viewport_ = loc("u_viewport");
  ground_ = loc("u_ground_height");
  light_view_ = loc("u_light_view");
  light_projection_ = loc("u_light_projection");
  buffer_ = loc("u_light_buffer");
  texel_ = loc("u_light_texel");
  strength_ = loc("u_strength");
  glCreateVertexArrays(1, &vao_);
}

ShadowBuffer::~ShadowBuffer() {
  if (framebuffer_) glDeleteFramebuffers(1, &framebuffer_);
  if (texture_) glDeleteTextures(1, &texture_);
  glDeleteVertexArrays(1, &vao_);
  glDeleteProgram(program_);
}

void ShadowBuffer::clear(int size) {
  size = std::clamp(size, 64, 4096);
  if (size != size_) {
    if (framebuffer_) glDeleteFramebuffers(1, &framebuffer_);
    if (texture_) glDeleteTextures(1, &texture_);
    glCreateTextures(GL_TEXTURE_2D, 1, &texture_);
    glTextureStorage2D(texture_, 1, GL_R16F, size, size);
    linear_clamped(texture_);
    glCreateFramebuffers(1, &framebuffer_);
    glNamedFramebufferTexture(framebuffer_, GL_COLOR_ATTACHMENT0, texture_, 0);
    if (glCheckNamedFramebufferStatus(framebuffer_, GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
      throw Error("the light buffer (16-bit float) is not renderable on this GPU");
    size_ = size;
  }
  const float none[4] = {0, 0, 0, 0};
  glClearNamedFramebufferfv(framebuffer_, GL_COLOR, 0, none);
}

void ShadowBuffer::bind_for_opacity() const {
  glBindFramebuffer(GL_FRAMEBUFFER, framebuffer_);
  glViewport(0, 0, size_, size_);
  glEnable(GL_BLEND);
  glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
}

void ShadowBuffer::darken_ground(const FrameContext& frame, float ground_height, const ShadowLight& light,
                                 float strength) const {
  glUseProgram(program_);
  glBindVertexArray(vao_);
  glUniformMatrix4fv(view_, 1, GL_FALSE, frame.view.data());
  glUniformMatrix4fv(projection_, 1, GL_FALSE, frame.projection.data());
  glUniform2f(viewport_, float(frame.width), float(frame.height));
  glUniform1f(ground_, ground_height);
  glUniformMatrix4fv(light_view_, 1, GL_FALSE, light.view.data());
  glUniformMatrix4fv(light_projection_, 1, GL_FALSE, light.projection.data());
  glUniform1i(buffer_, 1);
  glUniform1f(texel_, 1.0f / float(std::max(size_, 1)));
  glUniform1f(strength_, std::clamp(strength, 0.0f, 1.0f));
  glBindTextureUnit(1, texture_);
  glDisable(GL_DEPTH_TEST);
  glEnable(GL_BLEND);
  glBlendFunc(GL_ZERO, GL_SRC_COLOR);
  glDrawArrays(GL_TRIANGLES, 0, 3);
}

}  // namespace pstream::render::detail
