// Sprites: instanced camera-facing quads (or streaks along their screen-space velocity) pulled
// straight from the staged records, accumulated in a half-float buffer and tone-mapped over what
// is already drawn. With shadows, half-angle slicing (Green 2008), the slices cut by count and
// depth (slice_starts()): they alternate between the eye buffer, which reads how much light the
// slices before let through, and the light buffer, which adds the slice's opacity; the ground
// then takes the light buffer's final shadow.
#include <algorithm>
#include <cmath>
#include <string>

#include <fmt/format.h>

#include "gl_program.hpp"
#include "passes.hpp"
#include "shaders.hpp"

namespace pstream::render::detail {
namespace {

// What the sprite shader shares with the C++ side, written once (frame.hpp).
std::string sprite_vertex_source();

// After the prelude (sprite_vertex_source()): kBatches, kMergedIndexBits, kScaleWord, and the
// corner placing shared with the browser (shaders/sprite_corner.glsl: u_projection,
// u_light_projection, u_shutter, u_min_pixels, u_viewport_height, v_local, v_half, v_axis).
constexpr const char* kVertexShader = R"(
layout(std430, binding = 0) readonly buffer Records { uint words[]; };
layout(std430, binding = 1) readonly buffer Order { uint order[]; };
uniform mat4 u_model_view[kBatches];
uniform mat4 u_light_model_view[kBatches];  // object -> the light's view
uniform uint u_stride_words[kBatches];
uniform uint u_base_words[kBatches];     // where each batch's records start in the buffer
uniform int u_color_word[kBatches];
uniform int u_velocity_word[kBatches];
uniform int u_scalar_word[kBatches];
uniform vec4 u_color[kBatches];
uniform vec4 u_batch_tint[kBatches];
uniform float u_size[kBatches];
uniform bool u_use_order;
uniform bool u_merged;                   // order entries are (batch << kMergedIndexBits) | index
uniform uint u_first;                    // the slice's first entry
uniform bool u_points;
uniform int u_pass;                      // 0: the eye, 1: the light buffer
uniform int u_color_by;                  // 0 stored, 1 speed, 2 attribute
uniform vec3 u_ramp[8];
uniform int u_ramp_count;
uniform vec2 u_ramp_range;
uniform vec4 u_tint;
uniform float u_opacity;
uniform bool u_cull_below;
uniform vec4 u_ground_view;              // the ground plane in view space: under it, dot(n, p) + d < 0
out vec4 v_color;
out vec2 v_light_uv;

float word(uint w) { return uintBitsToFloat(words[w]); }

vec3 ramp(float x) {
  float t = clamp((x - u_ramp_range.x) / (u_ramp_range.y - u_ramp_range.x), 0.0, 1.0);
  if (u_ramp_count <= 1) return u_ramp[0];
  float f = t * float(u_ramp_count - 1);
  int i = min(int(f), u_ramp_count - 2);
  return mix(u_ramp[i], u_ramp[i + 1], f - float(i));
}

void main() {
  uint slot = uint(gl_InstanceID) + u_first;
  uint entry = u_use_order ? order[slot] : slot;
  uint b = u_merged ? entry >> kMergedIndexBits : 0u;
  uint index = u_merged ? entry & ((1u << kMergedIndexBits) - 1u) : entry;
  uint w = u_base_words[b] + index * u_stride_words[b];
  vec3 p = vec3(word(w), word(w + 1u), word(w + 2u));
  float radius = word(w + kScaleWord) * u_size[b] * length(u_model_view[b][0].xyz);
  vec4 color = u_color_word[b] >= 0 ? unpackUnorm4x8(words[w + uint(u_color_word[b])]) : u_color[b];
  vec3 velocity = vec3(0.0);
  if (u_velocity_word[b] >= 0) {
    uint vw = w + uint(u_velocity_word[b]);
    velocity = mat3(u_model_view[b]) * vec3(word(vw), word(vw + 1u), word(vw + 2u));  // view space, world units
  }
  if (u_color_by == 1) color.rgb = ramp(length(velocity));
  if (u_color_by == 2 && u_scalar_word[b] >= 0) color.rgb = ramp(word(w + uint(u_scalar_word[b])));
  color *= u_tint * u_batch_tint[b];
  color.a *= u_opacity;
  // Corners of a triangle strip: (-1,-1) (1,-1) (-1,1) (1,1).
  vec2 corner = vec2(float(gl_VertexID & 1) * 2.0 - 1.0, float(gl_VertexID >> 1) * 2.0 - 1.0);
  v_half = 0.0;
  v_axis = vec2(1.0, 0.0);
  v_color = color;
  v_light_uv = vec2(-1.0);
  if (u_pass == 1) {  // the light buffer: a disc facing the light
    gl_Position = light_corner(u_light_model_view[b] * vec4(p, 1.0), radius, corner);
    return;
  }
  vec4 view = u_model_view[b] * vec4(p, 1.0);
  if (u_cull_below && dot(u_ground_view.xyz, view.xyz) + u_ground_view.w < 0.0) {
    gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // under the ground: outside the view
    return;
  }
  vec4 light_clip = u_light_projection * (u_light_model_view[b] * vec4(p, 1.0));
  v_light_uv = light_clip.xy * 0.5 + 0.5;
  float pixels = sprite_pixels(radius, view.z);
  floor_size(pixels, radius, v_color.a);
  if (u_points) {
    gl_Position = u_projection * view;
    gl_PointSize = max(1.0, 2.0 * pixels);
    v_local = vec2(0.0);
    return;
  }
  gl_Position = sprite_corner(view, velocity, radius, corner, v_color.a);
}
)";

std::string sprite_vertex_source() {
  return glsl_source({fmt::format("const int kBatches = {};\nconst uint kMergedIndexBits = {}u;\n"
                                  "const uint kScaleWord = {}u;\n",
                                  kMaxMergedBatches, kMergedIndexBits, kScaleOffset / 4),
                      kShader_sprite_corner_glsl, kVertexShader});
}

struct Uniforms {
  GLint model_view, light_model_view, projection, light_projection, stride, base, color_word, velocity_word,
      scalar_word, color, batch_tint, size, use_order, merged, first, points, pass, viewport_height, color_by, ramp,
      ramp_count, ramp_range, tint, opacity, shutter, min_pixels, cull_below, ground_view, mode, textured, sprite,
      light_buffer, shadows, shadow_blur, light_texel, shadow_density, lit, key, fill;
};

}  // namespace

struct SpritePass::Impl {
  GLuint program = 0, composite = 0, vao = 0;
  Uniforms u{};
  GLint c_hdr = -1, c_bloom = -1, c_bloom_strength = -1, c_exposure = -1, c_tone_map = -1;
  GLuint bloom = 0;  // the blur program
  GLint b_source = -1, b_step = -1, b_sigma = -1, b_taps = -1, b_size = -1;
  std::array<GLuint, 2> bloom_texture{}, bloom_framebuffer{};  // half resolution: across, then down
  int bloom_width = 0, bloom_height = 0;
  GLuint hdr_texture = 0, hdr_depth = 0, hdr_framebuffer = 0;  // depth: alpha-tested sprites only
  int hdr_width = 0, hdr_height = 0;
  ShadowBuffer light;  // the light buffer: what the slices before let through, and the ground's shadow

  void ensure_hdr(int width, int height) {
    if (hdr_width == width && hdr_height == height) return;
    if (hdr_framebuffer) glDeleteFramebuffers(1, &hdr_framebuffer);
    if (hdr_texture) glDeleteTextures(1, &hdr_texture);
    if (hdr_depth) glDeleteRenderbuffers(1, &hdr_depth);
    delete_bloom();
    glCreateTextures(GL_TEXTURE_2D, 1, &hdr_texture);
    glTextureStorage2D(hdr_texture, 1, GL_RGBA16F, width, height);
    linear_clamped(hdr_texture);  // the bloom reads it filtered (the composite by texel)
    glCreateRenderbuffers(1, &hdr_depth);
    glNamedRenderbufferStorage(hdr_depth, GL_DEPTH_COMPONENT24, width, height);
    glCreateFramebuffers(1, &hdr_framebuffer);
    glNamedFramebufferTexture(hdr_framebuffer, GL_COLOR_ATTACHMENT0, hdr_texture, 0);
    glNamedFramebufferRenderbuffer(hdr_framebuffer, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, hdr_depth);
    if (glCheckNamedFramebufferStatus(hdr_framebuffer, GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
      throw Error("the sprites' half-float buffer is not renderable on this GPU");
    hdr_width = width;
    hdr_height = height;
  }

  // The bloom's two half-resolution buffers, made the first time a style asks for bloom.
  void ensure_bloom() {
    if (bloom_texture[0] != 0) return;
    bloom_width = std::max(1, (hdr_width + 1) / 2);
    bloom_height = std::max(1, (hdr_height + 1) / 2);
    for (std::size_t i = 0; i < 2; ++i) {
      glCreateTextures(GL_TEXTURE_2D, 1, &bloom_texture[i]);
      glTextureStorage2D(bloom_texture[i], 1, GL_RGBA16F, bloom_width, bloom_height);
      linear_clamped(bloom_texture[i]);
      glCreateFramebuffers(1, &bloom_framebuffer[i]);
      glNamedFramebufferTexture(bloom_framebuffer[i], GL_COLOR_ATTACHMENT0, bloom_texture[i], 0);
      if (glCheckNamedFramebufferStatus(bloom_framebuffer[i], GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
        throw Error("the sprites' bloom buffer is not renderable on this GPU");
    }
  }

  void delete_bloom() {
    for (std::size_t i = 0; i < 2; ++i) {
      if (bloom_framebuffer[i]) glDeleteFramebuffers(1, &bloom_framebuffer[i]);
      if (bloom_texture[i]) glDeleteTextures(1, &bloom_texture[i]);
      bloom_framebuffer[i] = bloom_texture[i] = 0;
    }
  }

  // Blurs the HDR buffer into bloom_texture[1]: a Gaussian of `radius` image heights, across
  // into [0] (halving the resolution), then down into [1].
  void blur(float radius) {
    ensure_bloom();
    const int w = bloom_width, h = bloom_height;
    const float sigma = std::max(0.5f, radius * float(h));
    const int taps = std::clamp(int(std::ceil(3.0f * sigma)), 1, 96);
    glUseProgram(bloom);
    glUniform1i(b_source, 3);
    glUniform1f(b_sigma, sigma);
    glUniform1i(b_taps, taps);
    glUniform2f(b_size, float(w), float(h));
    glViewport(0, 0, w, h);
    glDisable(GL_BLEND);
    glBindFramebuffer(GL_FRAMEBUFFER, bloom_framebuffer[0]);
    glBindTextureUnit(3, hdr_texture);
    glUniform2f(b_step, 1.0f / float(w), 0.0f);
    glDrawArrays(GL_TRIANGLES, 0, 3);
    glBindFramebuffer(GL_FRAMEBUFFER, bloom_framebuffer[1]);
    glBindTextureUnit(3, bloom_texture[0]);
    glUniform2f(b_step, 0.0f, 1.0f / float(h));
    glDrawArrays(GL_TRIANGLES, 0, 3);
  }
};

SpritePass::SpritePass() : impl_(std::make_unique<Impl>()) {
  Impl& d = *impl_;
  d.program = link_program(sprite_vertex_source().c_str(), glsl_source({kShader_sprite_frag}).c_str());
  const auto loc = [&](const char* name) { return glGetUniformLocation(d.program, name); };
  d.u = Uniforms{loc("u_model_view"),   loc("u_light_model_view"),
                 loc("u_projection"),   loc("u_light_projection"),
                 loc("u_stride_words"), loc("u_base_words"),
                 loc("u_color_word"),   loc("u_velocity_word"),
                 loc("u_scalar_word"),  loc("u_color"),
                 loc("u_batch_tint"),   loc("u_size"),
                 loc("u_use_order"),    loc("u_merged"),
                 loc("u_first"),        loc("u_points"),
                 loc("u_pass"),         loc("u_viewport_height"),
                 loc("u_color_by"),     loc("u_ramp"),
                 loc("u_ramp_count"),   loc("u_ramp_range"),
                 loc("u_tint"),         loc("u_opacity"),
                 loc("u_shutter"),      loc("u_min_pixels"),
                 loc("u_cull_below"),   loc("u_ground_view"),
                 loc("u_mode"),         loc("u_textured"),
                 loc("u_sprite"),       loc("u_light_buffer"),
                 loc("u_shadows"),      loc("u_shadow_blur"),
                 loc("u_light_texel"),  loc("u_shadow_density"),
                 loc("u_lit"),          loc("u_key"),
                 loc("u_fill")};
  d.composite = link_program(full_screen_vertex_source().c_str(), glsl_source({kShader_composite_frag}).c_str());
  d.c_hdr = glGetUniformLocation(d.composite, "u_hdr");
  d.c_exposure = glGetUniformLocation(d.composite, "u_exposure");
  d.c_tone_map = glGetUniformLocation(d.composite, "u_tone_map");
  d.c_bloom = glGetUniformLocation(d.composite, "u_bloom");
  d.c_bloom_strength = glGetUniformLocation(d.composite, "u_bloom_strength");
  d.bloom = link_program(full_screen_vertex_source().c_str(), glsl_source({kShader_bloom_frag}).c_str());
  d.b_source = glGetUniformLocation(d.bloom, "u_source");
  d.b_step = glGetUniformLocation(d.bloom, "u_step");
  d.b_sigma = glGetUniformLocation(d.bloom, "u_sigma");
  d.b_taps = glGetUniformLocation(d.bloom, "u_taps");
  d.b_size = glGetUniformLocation(d.bloom, "u_size");
  glCreateVertexArrays(1, &d.vao);
}

SpritePass::~SpritePass() {
  Impl& d = *impl_;
  if (d.hdr_framebuffer) glDeleteFramebuffers(1, &d.hdr_framebuffer);
  if (d.hdr_texture) glDeleteTextures(1, &d.hdr_texture);
  if (d.hdr_depth) glDeleteRenderbuffers(1, &d.hdr_depth);
  d.delete_bloom();
  glDeleteProgram(d.bloom);
  glDeleteVertexArrays(1, &d.vao);
  glDeleteProgram(d.program);
  glDeleteProgram(d.composite);
}

void SpritePass::draw(const FrameContext& frame, const StagedBatches& s, std::span<const ParticleBatch> source,
                      const SpriteDraw& what, const SpriteStyle& style) {
  Impl& d = *impl_;
  const Uniforms& u = d.u;
  GLint target = 0;
  glGetIntegerv(GL_DRAW_FRAMEBUFFER_BINDING, &target);
  d.ensure_hdr(frame.width, frame.height);
  const bool shadows = style.shadows && what.blend != BlendMode::Additive && !what.points;
  if (shadows) d.light.clear(style.shadow_resolution);
  const int light_size = d.light.size();

  const ShadowLight light = shadow_light(style.bounds, frame.view, frame.light_world);
  const Mat4& light_view = light.view;
  const Mat4& light_projection = light.projection;
  const std::array<float, 16 * kMaxBatches> light_model_view = model_views(light_view, source, s.n);

  const auto n = GLsizei(s.n);
  glUseProgram(d.program);
  glBindVertexArray(d.vao);
  glUniformMatrix4fv(u.model_view, n, GL_FALSE, s.model_view.data());
  glUniformMatrix4fv(u.light_model_view, n, GL_FALSE, light_model_view.data());
  glUniformMatrix4fv(u.projection, 1, GL_FALSE, frame.projection.data());
  glUniformMatrix4fv(u.light_projection, 1, GL_FALSE, light_projection.data());
  glUniform1uiv(u.stride, n, s.stride.data());
  glUniform1uiv(u.base, n, s.base.data());
  glUniform1iv(u.color_word, n, s.color_word.data());
  glUniform1iv(u.velocity_word, n, s.velocity_word.data());
  glUniform1iv(u.scalar_word, n, s.scalar_word.data());
  glUniform4fv(u.color, n, s.color.data());
  glUniform4fv(u.batch_tint, n, s.tint.data());
  glUniform1fv(u.size, n, s.size.data());
  glUniform1i(u.use_order, what.order_count > 0 ? 1 : 0);
  glUniform1i(u.merged, what.merged ? 1 : 0);
  glUniform1i(u.points, what.points ? 1 : 0);
  glUniform1f(u.viewport_height, float(frame.height));
  glUniform1i(u.color_by, static_cast<int>(style.color_by));
  glUniform3fv(u.ramp, 8, style.ramp.stops[0].data());
  glUniform1i(u.ramp_count, std::clamp(style.ramp.count, 1, 8));
  glUniform2f(u.ramp_range, style.ramp.low, style.ramp.high != style.ramp.low ? style.ramp.high : style.ramp.low + 1);
  glUniform4fv(u.tint, 1, style.tint.data());
  glUniform1f(u.opacity, style.opacity);
  glUniform1f(u.shutter, std::max(style.shutter, 0.0f));
  glUniform1f(u.min_pixels, std::max(style.min_pixels, 0.0f));
  glUniform1i(u.mode, static_cast<int>(what.blend));
  glUniform1i(u.textured, what.sprite != 0 ? 1 : 0);
  glUniform1i(u.sprite, 0);
  glUniform1i(u.light_buffer, 1);
  glUniform1i(u.shadows, shadows ? 1 : 0);
  glUniform1i(u.shadow_blur, style.shadow_blur ? 1 : 0);
  glUniform1f(u.light_texel, 1.0f / float(std::max(light_size, 1)));
  glUniform1f(u.shadow_density, std::max(style.shadow_density, 0.0f));
  glUniform1i(u.lit, style.lit ? 1 : 0);
  const SpriteLights lights = sprite_lights(frame.view, frame.light_world);
  glUniform3fv(u.key, 1, lights.key.data());
  glUniform3fv(u.fill, 1, lights.fill.data());
  // The ground plane y = h in view space: n = the view's y axis, d = -n . (0, h, 0) transformed.
  const bool cull = style.ground_height.has_value();
  glUniform1i(u.cull_below, cull ? 1 : 0);
  if (cull) {
    const Mat4& v = frame.view;
    const float h = *style.ground_height;
    const float nx = v[4], ny = v[5], nz = v[6];                                      // view * (0, 1, 0, 0)
    const float px = v[4] * h + v[12], py = v[5] * h + v[13], pz = v[6] * h + v[14];  // view * (0, h, 0, 1)
    glUniform4f(u.ground_view, nx, ny, nz, -(nx * px + ny * py + nz * pz));
  }
  if (what.sprite != 0) glBindTextureUnit(0, what.sprite);
  if (shadows) glBindTextureUnit(1, d.light.texture());

  const float clear[4] = {0, 0, 0, 0};
  glClearNamedFramebufferfv(d.hdr_framebuffer, GL_COLOR, 0, clear);
  // Blended sprites need no depth (drawn in order; the ground hides what is under it in the
  // vertex shader); alpha-tested ones are opaque cut-outs with a depth test of their own.
  const bool depth = what.blend == BlendMode::AlphaTest;
  if (depth) {
    const float far_depth = 1.0f;
    glClearNamedFramebufferfv(d.hdr_framebuffer, GL_DEPTH, 0, &far_depth);
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    glDepthMask(GL_TRUE);
  } else {
    glDisable(GL_DEPTH_TEST);
    glDepthMask(GL_FALSE);
  }
  glEnable(GL_BLEND);
  if (what.points) glEnable(GL_PROGRAM_POINT_SIZE);

  const HalfAngle half = half_angle(frame.view, frame.light_world);
  const auto eye_blend = [&] {
    if (what.blend == BlendMode::Additive) {
      glBlendFunc(GL_ONE, GL_ONE);
    } else if (what.blend == BlendMode::AlphaTest) {
      glDisable(GL_BLEND);
    } else if (shadows && half.eye_front_to_back) {
      glBlendFunc(GL_ONE_MINUS_DST_ALPHA, GL_ONE);  // "under": each slice goes behind the ones before
    } else {
      glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);  // premultiplied "over", back to front
    }
  };
  const std::uint64_t total = what.instances;
  const SliceStarts cut = slice_starts(source, half.sort_view, shadows ? style.slices : 1, total);
  const int slices = cut.slices;
  for (int k = 0; k < slices; ++k) {
    const std::uint64_t first = cut.starts[std::size_t(k)], end = cut.starts[std::size_t(k) + 1];
    if (end == first) continue;
    glUniform1ui(u.first, GLuint(first));
    glBindFramebuffer(GL_FRAMEBUFFER, d.hdr_framebuffer);
    glViewport(0, 0, frame.width, frame.height);
    glEnable(GL_BLEND);
    eye_blend();
    glUniform1i(u.pass, 0);
    if (what.points) {
      glDrawArraysInstanced(GL_POINTS, 0, 1, GLsizei(end - first));
    } else {
      glDrawArraysInstanced(GL_TRIANGLE_STRIP, 0, 4, GLsizei(end - first));
    }
    // The last slice shadows no slice after it, only the ground (when there is one).
    if (!shadows || (k + 1 == slices && !style.ground_height)) continue;
    d.light.bind_for_opacity();
    glUniform1i(u.pass, 1);
    glDrawArraysInstanced(GL_TRIANGLE_STRIP, 0, 4, GLsizei(end - first));
  }
  glDisable(GL_DEPTH_TEST);
  glDepthMask(GL_FALSE);

  glBindFramebuffer(GL_FRAMEBUFFER, GLuint(target));
  glViewport(0, 0, frame.width, frame.height);
  glBindVertexArray(d.vao);
  if (shadows && style.ground_height) {  // the ground's shadow under every slice
    d.light.darken_ground(frame, *style.ground_height, light, style.ground_shadow);
  }

  const bool bloom = style.bloom > 0.0f && style.bloom_radius > 0.0f;
  if (bloom) {
    d.blur(style.bloom_radius);
    glBindFramebuffer(GL_FRAMEBUFFER, GLuint(target));
    glViewport(0, 0, frame.width, frame.height);
    glBindVertexArray(d.vao);
  }
  glUseProgram(d.composite);
  glUniform1i(d.c_hdr, 2);
  glUniform1i(d.c_bloom, 3);
  glUniform1f(d.c_bloom_strength, bloom ? std::min(style.bloom, 1.0f) : 0.0f);
  if (bloom) glBindTextureUnit(3, d.bloom_texture[1]);
  glUniform1f(d.c_exposure, std::max(style.exposure, 0.0f));
  glUniform1i(d.c_tone_map, static_cast<int>(style.tone_map));
  glBindTextureUnit(2, d.hdr_texture);
  glEnable(GL_BLEND);
  glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
  glDrawArrays(GL_TRIANGLES, 0, 3);
  glEnable(GL_DEPTH_TEST);
  glDepthMask(GL_TRUE);
}

}  // namespace pstream::render::detail
