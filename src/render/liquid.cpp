// The screen-space liquid: sphere splats to a depth buffer and (additively) to a thickness
// buffer, a two-dimensional depth filter (narrow-range by default), normals from the smoothed depth,
// and a full-screen composite that reflects the sky, refracts and absorbs the scene behind, adds
// the key light's highlight and writes the surface's depth; spray is drawn over it.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <string>

#include <fmt/format.h>

#include "gl_program.hpp"
#include "passes.hpp"
#include "shaders.hpp"

namespace pstream::render::detail {
namespace {

// The shaders are src/render/shaders/'s files, shared with the browser player: the splats
// (liquid_splat.glsl, liquid_splat.frag), the depth filter (liquid_filter.glsl), the normals
// (liquid_normal.frag) and the composite (liquid_composite.frag). Here: their mains and preludes.

// A splat's vertex stage: the particle's centre, radius and speed from the records buffer.
// After its prelude (splat_vertex_source()): kScaleWord.
constexpr const char* kSplatVertex = R"(
layout(std430, binding = 0) readonly buffer Records { uint words[]; };
uniform mat4 u_model_view;
uniform uint u_base;
uniform uint u_stride;
uniform float u_size;
uniform int u_velocity_word;
uniform float u_fixed_radius;    // > 0: every particle's radius (object units)
float word(uint w) { return uintBitsToFloat(words[w]); }
void main() {
  uint w = u_base + uint(gl_InstanceID) * u_stride;
  float world_scale = length(u_model_view[0].xyz);
  float r = (u_fixed_radius > 0.0 ? u_fixed_radius : word(w + kScaleWord) * u_size) * world_scale;
  vec4 view = u_model_view * vec4(word(w), word(w + 1u), word(w + 2u), 1.0);
  float speed = -1.0;
  if (u_pass == 2 && u_velocity_word >= 0) {
    uint vw = w + uint(u_velocity_word);
    speed = length(vec3(word(vw), word(vw + 1u), word(vw + 2u))) * world_scale;
  }
  gl_Position = liquid_splat_corner(view, r, speed);
}
)";

std::string splat_vertex_source() {
  return glsl_source(
      {fmt::format("const uint kScaleWord = {}u;\n", kScaleOffset / 4), kShader_liquid_splat_glsl, kSplatVertex});
}

// The depth filter as a compute pass, not a full-screen triangle: data-centre GPUs shade fragments
// on a small part of the chip (on an H200 at 1080p, the whole liquid of 100,000 particles took
// 23.5 ms with these passes as fragments, 6.3 ms as compute).
constexpr const char* kFilterCompute = R"(
layout(local_size_x = 8, local_size_y = 8) in;
layout(rg32f, binding = 0) uniform writeonly image2D u_out;
void main() {
  ivec2 p = ivec2(gl_GlobalInvocationID.xy);
  if (any(greaterThanEqual(p, u_size))) return;
  imageStore(u_out, p, vec4(liquid_filter(p), 0.0, 0.0));
}
)";

struct Target {
  GLuint texture = 0, framebuffer = 0;
};

Target make_target(GLenum format, int w, int h, GLuint depth_renderbuffer = 0) {
  Target t;
  glCreateTextures(GL_TEXTURE_2D, 1, &t.texture);
  glTextureStorage2D(t.texture, 1, format, w, h);
  linear_clamped(t.texture);
  glCreateFramebuffers(1, &t.framebuffer);
  glNamedFramebufferTexture(t.framebuffer, GL_COLOR_ATTACHMENT0, t.texture, 0);
  if (depth_renderbuffer)
    glNamedFramebufferRenderbuffer(t.framebuffer, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, depth_renderbuffer);
  if (glCheckNamedFramebufferStatus(t.framebuffer, GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
    throw Error(fmt::format("liquid: a {}x{} render target is not supported by {}", w, h, Renderer::gl_renderer()));
  return t;
}

void destroy(Target& t) {
  if (t.framebuffer) glDeleteFramebuffers(1, &t.framebuffer);
  if (t.texture) glDeleteTextures(1, &t.texture);
  t = {};
}

// How much a world transform scales lengths (its first column's length, as the shaders take it).
float scale_of(const Mat4& world) { return std::sqrt(world[0] * world[0] + world[1] * world[1] + world[2] * world[2]); }

// The median radius (view units) of the batches' records (frame.hpp: median_radius).
float median_radius(std::span<const ParticleBatch> batches) {
  std::uint64_t total = 0;
  // A batch on the GPU path samples its earlier cached frame (its records are made on the GPU).
  const auto count_of = [](const ParticleBatch& b) { return b.pair ? b.pair->a_count : b.count; };
  for (const ParticleBatch& b : batches) total += count_of(b);
  return render::median_radius(total, [&](std::uint64_t i) {
    for (const ParticleBatch& b : batches) {
      if (i >= count_of(b)) {
        i -= count_of(b);
        continue;
      }
      const std::uint64_t at = i * b.record_size + kScaleOffset;  // scale: the radius
      const std::span<const std::byte> first = b.pair ? b.pair->a : b.first;
      const std::span<const std::byte> part = at < first.size() ? first : b.second;
      const std::uint64_t in = at < first.size() ? at : at - first.size();
      float radius = 0;
      std::memcpy(&radius, part.data() + in, sizeof radius);
      return radius * b.size_multiplier * scale_of(b.world);
    }
    return 0.0f;
  });
}

struct Uniforms {
  GLint model_view, projection, base, stride, size, velocity_word, fixed_radius, pass, thickness, foam_speed,
      foam_thickness, shadow_depth;
};
struct FilterUniforms {
  GLint radius_at_1, range, mode, size, depth, scale, taps;
};
struct NormalUniforms {
  GLint depth, size, projection, range;
};
struct CompositeUniforms {
  GLint depth, normal, thickness, scene, viewport, liquid_size, projection, view, light, color, absorb, color_depth,
      refraction, opacity_depth, output, radius_at_1;
};

}  // namespace

struct LiquidPass::Impl {
  GLuint splat = 0, filter = 0, normals = 0, composite = 0, vao = 0, depth_buffer = 0;
  Uniforms su{};
  FilterUniforms fu{};
  // Each filter pass's taps (frame.hpp: liquid_filter_taps).
  std::array<std::array<float, 3 * kLiquidFilterPairs>, kLiquidRampPasses + kLiquidMaxIterations> filter_pass_taps{};
  NormalUniforms nu{};
  CompositeUniforms cu{};
  Target raw, smooth[2], thickness, normal, scene;
  std::unique_ptr<ShadowBuffer> light;  // made on the first image with a shadow on the ground
  const Target* smoothed = &raw;        // the last filter output
  int width = 0, height = 0, liquid_width = 0, liquid_height = 0;

  void resize(int w, int h, int lw, int lh);
  void release();
  // Draws every batch's splats for `pass` (liquid_splat.frag) through `projection`, batch k
  // through model_views[16 k ...] (object -> the pass's view).
  void splat_batches(const Mat4& projection, const float* model_views, const StagedBatches& s, int pass,
                     const LiquidPasses& p);
};

void LiquidPass::Impl::release() {
  for (Target& t : smooth) destroy(t);
  for (Target* t : {&raw, &thickness, &normal, &scene}) destroy(*t);
  if (depth_buffer) glDeleteRenderbuffers(1, &depth_buffer);
  depth_buffer = 0;
  width = height = liquid_width = liquid_height = 0;
}

void LiquidPass::Impl::resize(int w, int h, int lw, int lh) {
  if (w == width && h == height && lw == liquid_width && lh == liquid_height) return;
  release();
  glCreateRenderbuffers(1, &depth_buffer);
  glNamedRenderbufferStorage(depth_buffer, GL_DEPTH_COMPONENT32F, lw, lh);
  raw = make_target(GL_RG32F, lw, lh, depth_buffer);           // depth x coverage, coverage
  for (Target& t : smooth) t = make_target(GL_RG32F, lw, lh);  // depth x coverage, coverage
  thickness = make_target(GL_R32F, lw, lh);
  normal = make_target(GL_RGBA16F, lw, lh);
  scene = make_target(GL_RGBA8, w, h);
  width = w, height = h, liquid_width = lw, liquid_height = lh;
}

LiquidPass::LiquidPass() : impl_(std::make_unique<Impl>()) {
  Impl& d = *impl_;
  d.splat = link_program(splat_vertex_source().c_str(), glsl_source({kShader_liquid_splat_frag}).c_str());
  d.filter = link_compute_program(glsl_source({fmt::format("const int kPairs = {};\n", kLiquidFilterPairs),
                                               kShader_liquid_filter_glsl, kFilterCompute})
                                      .c_str());
  d.normals = link_program(full_screen_vertex_source().c_str(),
                           glsl_source({kShader_view_position_glsl, kShader_liquid_normal_frag}).c_str());
  d.composite =
      link_program(full_screen_vertex_source().c_str(),
                   glsl_source({kShader_view_position_glsl, kShader_sky_glsl, kShader_liquid_composite_frag}).c_str());
  glCreateVertexArrays(1, &d.vao);
  const auto loc = [&](const char* name) { return glGetUniformLocation(d.splat, name); };
  d.su = {loc("u_model_view"), loc("u_projection"),    loc("u_base"),           loc("u_stride"),
          loc("u_size"),       loc("u_velocity_word"), loc("u_fixed_radius"),   loc("u_pass"),
          loc("u_thickness"),  loc("u_foam_speed"),    loc("u_foam_thickness"), loc("u_shadow_depth")};
  const auto in = [](GLuint program, const char* name) { return glGetUniformLocation(program, name); };
  d.fu = {in(d.filter, "u_radius_at_1"), in(d.filter, "u_range"), in(d.filter, "u_mode"), in(d.filter, "u_size"),
          in(d.filter, "u_depth"),       in(d.filter, "u_scale"), in(d.filter, "u_taps")};
  for (std::size_t i = 0; i < d.filter_pass_taps.size(); ++i) d.filter_pass_taps[i] = liquid_filter_taps(int(i));
  d.nu = {in(d.normals, "u_depth"), in(d.normals, "u_size"), in(d.normals, "u_projection"), in(d.normals, "u_range")};
  d.cu = {in(d.composite, "u_depth"),      in(d.composite, "u_normal"),        in(d.composite, "u_thickness"),
          in(d.composite, "u_scene"),      in(d.composite, "u_viewport"),      in(d.composite, "u_liquid_size"),
          in(d.composite, "u_projection"), in(d.composite, "u_view"),          in(d.composite, "u_light"),
          in(d.composite, "u_color"),      in(d.composite, "u_absorb"),        in(d.composite, "u_color_depth"),
          in(d.composite, "u_refraction"), in(d.composite, "u_opacity_depth"), in(d.composite, "u_output"),
          in(d.composite, "u_radius_at_1")};
}

LiquidPass::~LiquidPass() {
  Impl& d = *impl_;
  d.release();
  for (GLuint p : {d.splat, d.filter, d.normals, d.composite}) glDeleteProgram(p);
  glDeleteVertexArrays(1, &d.vao);
}

void LiquidPass::Impl::splat_batches(const Mat4& projection, const float* model_views, const StagedBatches& s, int pass,
                                     const LiquidPasses& p) {
  glUseProgram(splat);
  glUniformMatrix4fv(su.projection, 1, GL_FALSE, projection.data());
  glUniform1i(su.pass, pass);
  glUniform1f(su.fixed_radius, p.fixed_radius);
  glUniform1i(su.thickness, 0);
  glUniform1f(su.foam_speed, p.foam_speed);
  glUniform1f(su.foam_thickness, p.foam_thickness);
  glUniform1f(su.shadow_depth, std::max(p.shadow_depth, 1e-6f));
  for (std::size_t k = 0; k < s.n; ++k) {
    if (s.count[k] == 0) continue;
    glUniformMatrix4fv(su.model_view, 1, GL_FALSE, model_views + 16 * k);
    glUniform1ui(su.base, s.base[k]);
    glUniform1ui(su.stride, s.stride[k]);
    glUniform1f(su.size, s.size[k]);
    glUniform1i(su.velocity_word, s.velocity_word[k]);
    glDrawArraysInstanced(GL_TRIANGLE_STRIP, 0, 4, GLsizei(s.count[k]));
  }
}

void LiquidPass::draw(const FrameContext& frame, const StagedBatches& s, std::span<const ParticleBatch> source,
                      const LiquidStyle& style) {
  Impl& d = *impl_;
  GLint target = 0;  // the application's framebuffer (a window's is 0)
  glGetIntegerv(GL_DRAW_FRAMEBUFFER_BINDING, &target);
  const float world = source.empty() ? 1.0f : scale_of(source[0].world);
  const LiquidPasses p =
      liquid_passes(style, world, median_radius(source), frame.projection, frame.width, frame.height);
  d.resize(frame.width, frame.height, p.width, p.height);
  const int lw = d.liquid_width, lh = d.liquid_height;
  glBindVertexArray(d.vao);
  glDisable(GL_BLEND);

  // 1. Sphere depth, nearest wins.
  glBindFramebuffer(GL_FRAMEBUFFER, d.raw.framebuffer);
  glViewport(0, 0, lw, lh);
  const float zero[4] = {0, 0, 0, 0};
  const float far_depth = 1.0f;
  glClearNamedFramebufferfv(d.raw.framebuffer, GL_COLOR, 0, zero);
  glClearNamedFramebufferfv(d.raw.framebuffer, GL_DEPTH, 0, &far_depth);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  glDepthMask(GL_TRUE);
  d.splat_batches(frame.projection, s.model_view.data(), s, 0, p);

  // 2. Thickness, every sphere's chord added.
  glBindFramebuffer(GL_FRAMEBUFFER, d.thickness.framebuffer);
  glClearNamedFramebufferfv(d.thickness.framebuffer, GL_COLOR, 0, zero);
  glDisable(GL_DEPTH_TEST);
  glEnable(GL_BLEND);
  glBlendFunc(GL_ONE, GL_ONE);
  d.splat_batches(frame.projection, s.model_view.data(), s, 1, p);
  glDisable(GL_BLEND);

  // 3. The depth filter (two-dimensional, compute): three smaller passes, then the style's
  // iterations at its radius.
  d.smoothed = &d.raw;
  if (p.filter_passes > 0) {
    glUseProgram(d.filter);
    glUniform1f(d.fu.radius_at_1, p.filter_radius_at_1);
    glUniform1f(d.fu.range, p.range);
    glUniform1i(d.fu.mode, p.filter_mode);
    glUniform2i(d.fu.size, lw, lh);
    glUniform1i(d.fu.depth, 0);
    for (int i = 0; i < p.filter_passes; ++i) {
      const Target& out = d.smooth[i % 2];
      glUniform1f(d.fu.scale, liquid_filter_scale(i));
      glUniform3fv(d.fu.taps, kLiquidFilterPairs, d.filter_pass_taps[std::size_t(i)].data());
      glBindTextureUnit(0, d.smoothed->texture);
      glBindImageTexture(0, out.texture, 0, GL_FALSE, 0, GL_WRITE_ONLY, GL_RG32F);
      glDispatchCompute(GLuint(lw + 7) / 8, GLuint(lh + 7) / 8, 1);
      // The next pass samples what this one stored; so do the normals, and read() copies it.
      glMemoryBarrier(GL_TEXTURE_FETCH_BARRIER_BIT | GL_TEXTURE_UPDATE_BARRIER_BIT);
      d.smoothed = &out;
    }
  }

  // 4. Normals from the smoothed depth.
  glBindFramebuffer(GL_FRAMEBUFFER, d.normal.framebuffer);
  glUseProgram(d.normals);
  glUniform1i(d.nu.depth, 0);
  glUniform2i(d.nu.size, lw, lh);
  glUniformMatrix4fv(d.nu.projection, 1, GL_FALSE, frame.projection.data());
  glUniform1f(d.nu.range, p.range);
  glBindTextureUnit(0, d.smoothed->texture);
  glDrawArrays(GL_TRIANGLES, 0, 3);

  // 5. The liquid's shadow on the ground: its sphere chords along the light, as opacities in a
  // light buffer over the clips' bounds (frame.hpp: shadow_light), darken the ground already drawn.
  if (p.shadow_depth > 0 && style.ground_height) {
    const ShadowLight light = shadow_light(style.bounds, frame.view, frame.light_world);
    const std::array<float, 16 * kMaxBatches> light_model_view = model_views(light.view, source, s.n);
    if (!d.light) d.light = std::make_unique<ShadowBuffer>();
    d.light->clear(p.shadow_resolution);
    d.light->bind_for_opacity();
    glBindVertexArray(d.vao);
    d.splat_batches(light.projection, light_model_view.data(), s, 3, p);
    glBindFramebuffer(GL_FRAMEBUFFER, GLuint(target));
    glViewport(0, 0, frame.width, frame.height);
    d.light->darken_ground(frame, *style.ground_height, light, p.shadow_strength);
    glDisable(GL_BLEND);
    glBindVertexArray(d.vao);
  }

  // 6. What is behind the liquid (with the shadow), copied for refraction; then the surface over it.
  glBlitNamedFramebuffer(GLuint(target), d.scene.framebuffer, 0, 0, frame.width, frame.height, 0, 0, frame.width,
                         frame.height, GL_COLOR_BUFFER_BIT, GL_NEAREST);
  glBindFramebuffer(GL_FRAMEBUFFER, GLuint(target));
  glViewport(0, 0, frame.width, frame.height);
  glUseProgram(d.composite);
  glUniform1i(d.cu.depth, 0);
  glUniform1i(d.cu.normal, 1);
  glUniform1i(d.cu.thickness, 2);
  glUniform1i(d.cu.scene, 3);
  glBindTextureUnit(0, d.smoothed->texture);
  glBindTextureUnit(1, d.normal.texture);
  glBindTextureUnit(2, d.thickness.texture);
  glBindTextureUnit(3, d.scene.texture);
  glUniform2f(d.cu.viewport, float(frame.width), float(frame.height));
  glUniform2f(d.cu.liquid_size, float(lw), float(lh));
  glUniformMatrix4fv(d.cu.projection, 1, GL_FALSE, frame.projection.data());
  glUniformMatrix4fv(d.cu.view, 1, GL_FALSE, frame.view.data());
  glUniform3fv(d.cu.light, 1, frame.light_view.data());
  glUniform3fv(d.cu.color, 1, style.color.data());
  glUniform3fv(d.cu.absorb, 1, p.absorb.data());
  glUniform1f(d.cu.color_depth, p.color_depth);
  glUniform1f(d.cu.refraction, p.refraction);
  glUniform1f(d.cu.opacity_depth, p.opacity_depth);
  glUniform1i(d.cu.output, int(style.output));
  glUniform1f(d.cu.radius_at_1, p.radius_px_at_1);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  glDepthMask(GL_TRUE);
  glDrawArrays(GL_TRIANGLES, 0, 3);

  // 7. Spray over the surface.
  if (p.spray) {
    glBindTextureUnit(0, d.thickness.texture);
    glEnable(GL_BLEND);
    glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
    glDepthMask(GL_FALSE);
    d.splat_batches(frame.projection, s.model_view.data(), s, 2, p);
    glDepthMask(GL_TRUE);
    glDisable(GL_BLEND);
  }
}

LiquidImage LiquidPass::read(LiquidBuffer which) const {
  const Impl& d = *impl_;
  LiquidImage image;
  image.width = d.liquid_width;
  image.height = d.liquid_height;
  const Target* t = which == LiquidBuffer::RawDepth    ? &d.raw
                    : which == LiquidBuffer::Depth     ? d.smoothed
                    : which == LiquidBuffer::Thickness ? &d.thickness
                                                       : &d.normal;
  image.channels = which == LiquidBuffer::Normals ? 3 : 1;
  image.values.resize(std::size_t(image.width) * std::size_t(image.height) * std::size_t(image.channels));
  glPixelStorei(GL_PACK_ALIGNMENT, 4);
  glGetTextureImage(t->texture, 0, image.channels == 3 ? GL_RGB : GL_RED, GL_FLOAT,
                    GLsizei(image.values.size() * sizeof(float)), image.values.data());
  return image;
}

}  // namespace pstream::render::detail
