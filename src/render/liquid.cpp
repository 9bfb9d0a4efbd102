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

namespace pstream::render::detail {
namespace {

// Splats, one instanced quad per particle of one batch. Pass 0: the sphere's front depth
// (distance along the view axis) with depth testing; 1: its thickness (chord length) added up;
// 2: spray, for particles where the liquid is thin (isolated) or that move fast.
// After its prelude (splat_vertex_source()): kScaleWord.
constexpr const char* kSplatVertex = R"(
layout(std430, binding = 0) readonly buffer Records { uint words[]; };
uniform mat4 u_model_view;
uniform mat4 u_projection;
uniform uint u_base;
uniform uint u_stride;
uniform float u_size;
uniform int u_velocity_word;
uniform float u_fixed_radius;    // > 0: every particle's radius (object units)
uniform int u_pass;
uniform sampler2D u_thickness;
uniform float u_foam_speed;      // view units per second; 0: off
uniform float u_foam_thickness;  // view units; 0: off
out vec2 v_corner;
out vec3 v_center;
out float v_radius;
out float v_foam;
float word(uint w) { return uintBitsToFloat(words[w]); }
void main() {
  uint w = u_base + uint(gl_InstanceID) * u_stride;
  float world_scale = length(u_model_view[0].xyz);
  float r = (u_fixed_radius > 0.0 ? u_fixed_radius : word(w + kScaleWord) * u_size) * world_scale;
  vec4 view = u_model_view * vec4(word(w), word(w + 1u), word(w + 2u), 1.0);
  v_corner = vec2(float(gl_VertexID & 1) * 2.0 - 1.0, float(gl_VertexID >> 1) * 2.0 - 1.0);
  v_center = view.xyz;
  v_radius = r;
  v_foam = 0.0;
  if (u_pass == 2) {
    vec4 c = u_projection * view;
    vec2 uv = c.xy / c.w * 0.5 + 0.5;
    float foam = 0.0;
    if (u_foam_thickness > 0.0 && c.w > 0.0 && all(greaterThan(uv, vec2(0.0))) && all(lessThan(uv, vec2(1.0)))) {
      float t = texture(u_thickness, uv).r;
      foam = 1.0 - smoothstep(0.5 * u_foam_thickness, u_foam_thickness, t);
    }
    if (u_foam_speed > 0.0 && u_velocity_word >= 0) {
      uint vw = w + uint(u_velocity_word);
      float speed = length(vec3(word(vw), word(vw + 1u), word(vw + 2u))) * world_scale;
      foam = max(foam, smoothstep(u_foam_speed, 1.5 * u_foam_speed, speed));
    }
    v_foam = foam;
    if (foam < 0.02) {  // not spray: outside the clip volume, so nothing is rasterised
      gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
      return;
    }
    view.z += r;  // on the surface of the liquid the particle is in, not inside it
    r *= 0.8;
  }
  view.xy += v_corner * r;
  gl_Position = u_projection * view;
}
)";

std::string splat_vertex_source() {
  return fmt::format("#version 450 core\nconst uint kScaleWord = {}u;\n", kScaleOffset / 4) + kSplatVertex;
}

constexpr const char* kSplatFragment = R"(#version 450 core
in vec2 v_corner;
in vec3 v_center;
in float v_radius;
in float v_foam;
uniform mat4 u_projection;
uniform int u_pass;
layout(location = 0) out vec4 o_out;
void main() {
  float r2 = dot(v_corner, v_corner);
  if (r2 > 1.0) discard;
  float h = sqrt(1.0 - r2);
  if (u_pass == 0) {
    vec3 p = v_center + vec3(v_corner * v_radius, h * v_radius);
    vec4 c = u_projection * vec4(p, 1.0);
    gl_FragDepth = c.z / c.w * 0.5 + 0.5;
    o_out = vec4(-p.z, 1.0, 0.0, 0.0);  // depth x coverage, coverage (the filter reads both)
    return;
  }
  gl_FragDepth = gl_FragCoord.z;
  if (u_pass == 1) {
    o_out = vec4(2.0 * h * v_radius, 0.0, 0.0, 0.0);
    return;
  }
  float a = v_foam * 0.85 * (1.0 - smoothstep(0.2, 1.0, sqrt(r2)));
  o_out = vec4(vec3(0.93, 0.96, 1.0) * a, a);
}
)";

// The depth filter, in two dimensions at once, one compute pass; the radius in pixels is a world
// length projected at the centre pixel's depth. Depth 0 is "no liquid" and stays so: silhouettes
// do not move.
//
// Why two dimensions: a separable filter treats each line on its own. Where the narrow range
// leaves samples out (a silhouette, a drop in front of the pool), one line takes samples that the
// next leaves out, and the lines differ: at 1080p, lines and crosses a filter radius long at every
// edge and behind every drop.
//
// Its cost does not grow with the radius: kPairs pairs of taps on a sunflower spiral over the disc
// (Vogel's: each tap stands for the same area, and no two rows line up, so the taps alias into
// faint noise, not into a lattice as a square grid of sparse taps did). Every buffer it reads holds
// (depth x coverage, coverage), coverage 1 where there is liquid, and taps read it bilinearly: a
// tap's position and what it reads change continuously with the radius, so that neighbouring
// pixels at slightly different depths do not take different sets of pixels. A compute pass, not a
// full-screen triangle: data-centre GPUs shade fragments on a small part of the chip (on an
// H200 at 1080p, the whole liquid of 100,000 particles took 23.5 ms with these passes as
// fragments, 6.3 ms as compute).
// (After "#version" and kPairs, which the C++ side sets: kFilterPairs.)
constexpr const char* kFilterCompute = R"(
uniform sampler2D u_depth;    // depth x coverage, coverage
uniform ivec2 u_size;
uniform float u_radius_at_1;  // filter radius in pixels at distance 1
uniform float u_range;        // the narrow range, view units
uniform int u_mode;           // 0 narrow range, 1 bilateral, 2 gaussian
uniform float u_scale;        // this pass's radius, a fraction of the filter's
const float kMaxRadius = 48.0;
// The spiral's taps for this pass (turned from the last pass's): each one's offset at radius 1
// (one of a pair; the other is its negative) and its Gaussian weight (sigma half the radius).
uniform vec3 u_taps[kPairs];
layout(local_size_x = 8, local_size_y = 8) in;
layout(rg32f, binding = 0) uniform writeonly image2D u_out;
// The depth at p + o and how much of the tap has liquid (0..1).
vec2 tap(ivec2 p, vec2 o) {
  vec2 v = textureLod(u_depth, (vec2(p) + 0.5 + o) / vec2(u_size), 0.0).rg;
  return vec2(v.y > 1e-4 ? v.x / v.y : 0.0, v.y);
}
void main() {
  ivec2 p = ivec2(gl_GlobalInvocationID.xy);
  if (any(greaterThanEqual(p, u_size))) return;
  float z0 = texelFetch(u_depth, p, 0).r;
  float radius = u_scale * min(u_radius_at_1 / max(z0, 1e-6), kMaxRadius);
  if (z0 <= 0.0 || radius < 0.5) {
    imageStore(u_out, p, vec4(z0, z0 > 0.0 ? 1.0 : 0.0, 0.0, 0.0));
    return;
  }
  float sum = 0.0, weights = 0.0;
  float half_range = 0.5 * u_range;
  for (int i = 0; i < kPairs; ++i) {
    vec2 o = radius * u_taps[i].xy;
    vec2 a = tap(p, o), b = tap(p, -o);
    float g = u_taps[i].z;
    if (u_mode == 0) {
      // The narrow range (after Truong and Yuksel 2018) as point-symmetric pairs: the taps at
      // +o and -o count together, so that the kernel stays symmetric and a pixel beside an edge
      // is not pulled towards either side. A pair counts as much as both have liquid, and as
      // much as their mean lies within half the range of the centre: on a plane, however steep
      // (water seen at a grazing angle), the mean of a symmetric pair is the centre's depth,
      // while a pair with one tap on another layer (a drop in front, the floor behind a sheet) is
      // off by half the gap. The weight falls as (1 - off / half range)^2, so that no pair
      // switches on or off from one pixel to the next.
      float off = abs(0.5 * (a.x + b.x) - z0);
      float fade = max(1.0 - off / half_range, 0.0);
      float w = g * min(a.y, b.y) * fade * fade;
      sum += w * (a.x + b.x);
      weights += 2.0 * w;
    } else {
      float wa = g * a.y, wb = g * b.y;  // nothing there: the silhouette stays put
      if (u_mode == 1) {
        wa *= exp(-((a.x - z0) * (a.x - z0)) / (2.0 * u_range * u_range));
        wb *= exp(-((b.x - z0) * (b.x - z0)) / (2.0 * u_range * u_range));
      }
      sum += wa * a.x + wb * b.x;
      weights += wa + wb;
    }
  }
  // The centre stands for its own share of the disc, weighted as the innermost taps are.
  float w0 = exp(-0.5 / float(kPairs));
  imageStore(u_out, p, vec4((sum + w0 * z0) / (weights + w0), 1.0, 0.0, 0.0));
}
)";

// Shared by the normal and composite passes: a pixel's view-space position from its depth.
constexpr const char* kViewPosition = R"(
vec3 view_position(vec2 uv, float d, mat4 projection) {
  vec2 ndc = uv * 2.0 - 1.0;
  return vec3(ndc.x * d / projection[0][0], ndc.y * d / projection[1][1], -d);
}
)";

// Normals: a plane fitted to the smoothed depth of the 7x7 pixels around each pixel (weighted
// least squares, Gaussian in distance), leaving out pixels with no liquid or more than the narrow
// range away in depth (another surface). A fit in two dimensions at once: one-sided differences
// turned small differences from one row to the next into streaks along the rows; the fit averages
// across rows as much as along them.
constexpr const char* kNormalFragment = R"(
uniform sampler2D u_depth;
uniform ivec2 u_size;
uniform mat4 u_projection;
uniform float u_range;  // view units: farther in depth is another surface
layout(location = 0) out vec4 o_normal;
vec3 at(vec2 q, float d) { return view_position((q + 0.5) / vec2(u_size), d, u_projection); }
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  float d = texelFetch(u_depth, p, 0).r;
  if (d <= 0.0) {
    o_normal = vec4(0.0);
    return;
  }
  float w0 = 0.0, sx = 0.0, sy = 0.0, sz = 0.0, sxx = 0.0, syy = 0.0, sxy = 0.0, sxz = 0.0, syz = 0.0;
  for (int j = -3; j <= 3; ++j) {
    for (int i = -3; i <= 3; ++i) {
      ivec2 q = p + ivec2(i, j);
      if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, u_size))) continue;
      float z = texelFetch(u_depth, q, 0).r;
      if (z <= 0.0 || abs(z - d) > u_range) continue;
      float w = exp(-0.125 * float(i * i + j * j));
      float x = float(i), y = float(j);
      z -= d;
      w0 += w;
      sx += w * x;
      sy += w * y;
      sz += w * z;
      sxx += w * x * x;
      syy += w * y * y;
      sxy += w * x * y;
      sxz += w * x * z;
      syz += w * y * z;
    }
  }
  // Centred sums; then depth = d + a * dx + b * dy around the pixel.
  float cxx = sxx - sx * sx / w0, cyy = syy - sy * sy / w0, cxy = sxy - sx * sy / w0;
  float cxz = sxz - sx * sz / w0, cyz = syz - sy * sz / w0;
  float det = cxx * cyy - cxy * cxy;
  float a = 0.0, b = 0.0;
  if (det > 1e-6) {
    a = (cxz * cyy - cyz * cxy) / det;
    b = (cyz * cxx - cxz * cxy) / det;
  } else if (cxx > 1e-6) {
    a = cxz / cxx;
  } else if (cyy > 1e-6) {
    b = cyz / cyy;
  }
  vec2 q = vec2(p);
  vec3 c = at(q, d);
  vec3 n = normalize(cross(at(q + vec2(1.0, 0.0), d + a) - c, at(q + vec2(0.0, 1.0), d + b) - c));
  o_normal = vec4(n, 1.0);
}
)";
constexpr const char* kCompositeFragment = R"(
uniform sampler2D u_depth;
uniform sampler2D u_normal;
uniform sampler2D u_thickness;
uniform sampler2D u_scene;
uniform vec2 u_viewport;
uniform vec2 u_liquid_size;
uniform mat4 u_projection;
uniform mat4 u_view;
uniform vec3 u_light;       // view space, towards the key light
uniform vec3 u_color;
uniform vec3 u_absorb;      // per view unit of thickness
uniform float u_color_depth;
uniform float u_refraction;
uniform float u_opacity_depth;  // view units of thickness that hide 63 % of what is behind; 0: clear
uniform int u_output;       // 0 shaded, 1 depth, 2 normals, 3 thickness
uniform float u_radius_at_1;  // a particle's radius in liquid pixels at distance 1
layout(location = 0) out vec4 o_color;
void main() {
  vec2 uv = gl_FragCoord.xy / u_viewport;
  ivec2 q = min(ivec2(uv * u_liquid_size), ivec2(u_liquid_size) - 1);
  float d = texelFetch(u_depth, q, 0).r;
  if (d <= 0.0) discard;
  vec3 p = view_position(uv, d, u_projection);
  vec4 clip = u_projection * vec4(p, 1.0);
  gl_FragDepth = clip.z / clip.w * 0.5 + 0.5;
  vec3 n = texelFetch(u_normal, q, 0).xyz;
  float thickness = texelFetch(u_thickness, q, 0).r;
  if (u_output == 1) {
    float near = u_projection[3][2] / (u_projection[2][2] - 1.0), far = u_projection[3][2] / (u_projection[2][2] + 1.0);
    o_color = vec4(vec3(1.0 - clamp((d - near) / (far - near), 0.0, 1.0)), 1.0);
    return;
  }
  if (u_output == 2) {
    o_color = vec4(n * 0.5 + 0.5, 1.0);
    return;
  }
  if (u_output == 3) {
    o_color = vec4(vec3(1.0 - exp(-thickness / u_color_depth)), 1.0);
    return;
  }
  vec3 v = normalize(-p);
  float fresnel = 0.02 + 0.98 * pow(1.0 - max(dot(n, v), 0.0), 5.0);
  vec3 reflected = sky_color(normalize(transpose(mat3(u_view)) * reflect(-v, n)));
  vec3 transmitted = exp(-u_absorb * thickness);
  vec2 bend = n.xy * u_refraction * 0.04 * (1.0 - exp(-thickness / u_color_depth));
  // A body of water scatters what crosses it: the scene behind is seen blurred, more so through
  // more liquid (up to 6 px, on a ring of 8 taps), and then hidden by the body's own light by
  // 1 - exp(-thickness / opacity_depth). A sheet a few particles thick reads as water, not glass.
  float opacity = u_opacity_depth > 0.0 ? 1.0 - exp(-thickness / u_opacity_depth) : 0.0;
  vec2 at = clamp(uv - bend, vec2(0.0), vec2(1.0));
  vec3 behind = texture(u_scene, at).rgb;
  if (opacity > 0.0) {
    float spread = 6.0 * opacity / u_viewport.y;
    for (int k = 0; k < 8; ++k) {
      float a = 0.785398 * float(k);
      behind += texture(u_scene, clamp(at + spread * vec2(cos(a) * u_viewport.y / u_viewport.x, sin(a)), vec2(0.0), vec2(1.0))).rgb;
    }
    behind /= 9.0;
  }
  vec3 scattered = 0.5 * u_color * (1.0 - transmitted);  // light the liquid scatters back, tinted
  // The body's own light: the liquid's colour, lit from the key light, darker and more saturated
  // the deeper it is (the light it scatters back crossed some of it).
  vec3 body = u_color * sqrt(transmitted) * (0.45 + 0.55 * max(dot(n, u_light), 0.0));
  vec3 under = mix(behind * transmitted + scattered, body, opacity);
  // The key light's highlight, its sharpness from how much the normals vary around the pixel
  // (Toksvig 2005): the mean of the unit normals over 3x3 taps a particle's radius apart (2 to 8
  // pixels, so the same part of the surface at any image size) is shorter where they disagree,
  // and a sharp highlight there would alias into glints that the foreshortening of a surface seen
  // at a grazing angle draws out into bright lines along the rows. Flat water keeps the sharp one.
  vec3 mean_n = vec3(0.0);
  float taps = 0.0;
  int spacing = clamp(int(round(u_radius_at_1 / d)), 2, 8);
  for (int j = -1; j <= 1; ++j) {
    for (int i = -1; i <= 1; ++i) {
      ivec2 t = clamp(q + ivec2(i, j) * spacing, ivec2(0), ivec2(u_liquid_size) - 1);
      if (texelFetch(u_depth, t, 0).r <= 0.0) continue;
      mean_n += texelFetch(u_normal, t, 0).xyz;
      taps += 1.0;
    }
  }
  float agree = clamp(length(mean_n) / max(taps, 1.0), 0.0, 1.0);
  const float kShininess = 180.0;
  float shininess = kShininess * agree / (agree + kShininess * (1.0 - agree));
  vec3 h = normalize(u_light + v);
  // Scaled by (1 + shininess) / (1 + kShininess): a broader highlight spreads the same light.
  float highlight = dot(n, u_light) > 0.0
      ? 1.6 * (1.0 + shininess) / (1.0 + kShininess) * pow(max(dot(n, h), 0.0), shininess) : 0.0;
  o_color = vec4(mix(under, reflected, fresnel) + vec3(highlight), 1.0);
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

// The median radius (view units) of up to 255 records spread over the batches.
float median_radius(std::span<const ParticleBatch> batches) {
  std::uint64_t total = 0;
  // A batch on the GPU path samples its earlier cached frame (its records are made on the GPU).
  const auto count_of = [](const ParticleBatch& b) { return b.pair ? b.pair->a_count : b.count; };
  for (const ParticleBatch& b : batches) total += count_of(b);
  std::array<float, 255> sample{};
  std::size_t n = 0;
  const std::uint64_t want = std::min<std::uint64_t>(total, sample.size());
  for (std::uint64_t k = 0; k < want; ++k) {
    std::uint64_t i = total <= want ? k : k * total / want;
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
      if (std::isfinite(radius) && radius > 0) sample[n++] = radius * b.size_multiplier * scale_of(b.world);
      break;
    }
  }
  if (n == 0) return 0.01f;
  std::nth_element(sample.begin(), sample.begin() + std::ptrdiff_t(n / 2), sample.begin() + std::ptrdiff_t(n));
  return sample[n / 2];
}

struct Uniforms {
  GLint model_view, projection, base, stride, size, velocity_word, fixed_radius, pass, thickness, foam_speed,
      foam_thickness;
};
struct FilterUniforms {
  GLint radius_at_1, range, mode, size, depth, scale, taps;
};
// The filter's taps: kFilterPairs pairs on a sunflower (Vogel) spiral over the unit disc, the
// i-th at radius sqrt((i + 0.5) / n) and i golden angles, the whole turned by `turn` radians;
// each with its Gaussian weight for a sigma of half the radius, exp(-2 r^2).
constexpr int kFilterPairs = 64;
std::array<float, 3 * kFilterPairs> filter_taps(float turn) {
  constexpr double kGoldenAngle = 2.39996322972865332;
  std::array<float, 3 * kFilterPairs> taps{};
  for (int i = 0; i < kFilterPairs; ++i) {
    const double r2 = (i + 0.5) / kFilterPairs, t = i * kGoldenAngle + turn, r = std::sqrt(r2);
    taps[std::size_t(3 * i)] = float(r * std::cos(t));
    taps[std::size_t(3 * i + 1)] = float(r * std::sin(t));
    taps[std::size_t(3 * i + 2)] = float(std::exp(-2.0 * r2));
  }
  return taps;
}
// Before the filter's passes at its radius: passes at 1/8, 1/4 and 1/2 of it. Each smooths the
// depth at the scale of the next pass's tap spacing, so that the sparse taps of a large radius
// read a surface with nothing finer left to alias (LiquidTest's grazing view measured 1.31
// down/along with three, 1.45 with two, 1.55 with one).
constexpr int kRampPasses = 3;
constexpr int kMaxIterations = 8;
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
  // Each filter pass's taps (filter_taps), turned by 1.1 radians from the pass before.
  std::array<std::array<float, 3 * kFilterPairs>, kRampPasses + kMaxIterations> filter_pass_taps{};
  NormalUniforms nu{};
  CompositeUniforms cu{};
  Target raw, smooth[2], thickness, normal, scene;
  const Target* smoothed = &raw;  // the last filter output
  int width = 0, height = 0, liquid_width = 0, liquid_height = 0;

  void resize(int w, int h, float resolution);
  void release();
  void splat_batches(const FrameContext& frame, const StagedBatches& s, int pass, float fixed_radius,
                     const LiquidStyle& style, float radius);
};

void LiquidPass::Impl::release() {
  for (Target& t : smooth) destroy(t);
  for (Target* t : {&raw, &thickness, &normal, &scene}) destroy(*t);
  if (depth_buffer) glDeleteRenderbuffers(1, &depth_buffer);
  depth_buffer = 0;
  width = height = liquid_width = liquid_height = 0;
}

void LiquidPass::Impl::resize(int w, int h, float resolution) {
  const int lw = std::max(1, int(std::lround(float(w) * resolution)));
  const int lh = std::max(1, int(std::lround(float(h) * resolution)));
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
  d.splat = link_program(splat_vertex_source().c_str(), kSplatFragment);
  const std::string header = std::string("#version 450 core\n") + kViewPosition;
  d.filter = link_compute_program(
      fmt::format("#version 450 core\nconst int kPairs = {};\n{}", kFilterPairs, kFilterCompute).c_str());
  d.normals = link_program(kFullScreenVertexShader, (header + kNormalFragment).c_str());
  d.composite = link_program(kFullScreenVertexShader, (header + kSkyFunction + kCompositeFragment).c_str());
  glCreateVertexArrays(1, &d.vao);
  const auto loc = [&](const char* name) { return glGetUniformLocation(d.splat, name); };
  d.su = {loc("u_model_view"), loc("u_projection"),    loc("u_base"),          loc("u_stride"),
          loc("u_size"),       loc("u_velocity_word"), loc("u_fixed_radius"),  loc("u_pass"),
          loc("u_thickness"),  loc("u_foam_speed"),    loc("u_foam_thickness")};
  const auto in = [](GLuint program, const char* name) { return glGetUniformLocation(program, name); };
  d.fu = {in(d.filter, "u_radius_at_1"), in(d.filter, "u_range"), in(d.filter, "u_mode"), in(d.filter, "u_size"),
          in(d.filter, "u_depth"),       in(d.filter, "u_scale"), in(d.filter, "u_taps")};
  for (std::size_t i = 0; i < d.filter_pass_taps.size(); ++i) d.filter_pass_taps[i] = filter_taps(1.1f * float(i));
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

void LiquidPass::Impl::splat_batches(const FrameContext& frame, const StagedBatches& s, int pass, float fixed_radius,
                                     const LiquidStyle& style, float radius) {
  glUseProgram(splat);
  glUniformMatrix4fv(su.projection, 1, GL_FALSE, frame.projection.data());
  glUniform1i(su.pass, pass);
  glUniform1f(su.fixed_radius, fixed_radius);
  glUniform1i(su.thickness, 0);
  glUniform1f(su.foam_speed, style.foam_speed);
  glUniform1f(su.foam_thickness, style.foam_isolation * radius);
  for (std::size_t k = 0; k < s.n; ++k) {
    if (s.count[k] == 0) continue;
    glUniformMatrix4fv(su.model_view, 1, GL_FALSE, s.model_view.data() + 16 * k);
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
  d.resize(frame.width, frame.height, std::clamp(style.resolution, 0.25f, 1.0f));
  const int lw = d.liquid_width, lh = d.liquid_height;
  // Lengths in view units: the style's are in particle radii.
  const float world = source.empty() ? 1.0f : scale_of(source[0].world);
  const float radius = style.particle_radius > 0 ? style.particle_radius * world : median_radius(source);
  const float fixed_radius = style.particle_radius > 0 ? style.particle_radius : 0.0f;
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
  d.splat_batches(frame, s, 0, fixed_radius, style, radius);

  // 2. Thickness, every sphere's chord added.
  glBindFramebuffer(GL_FRAMEBUFFER, d.thickness.framebuffer);
  glClearNamedFramebufferfv(d.thickness.framebuffer, GL_COLOR, 0, zero);
  glDisable(GL_DEPTH_TEST);
  glEnable(GL_BLEND);
  glBlendFunc(GL_ONE, GL_ONE);
  d.splat_batches(frame, s, 1, fixed_radius, style, radius);
  glDisable(GL_BLEND);

  // A particle's radius in liquid pixels at distance 1: a world length through the projection's
  // focal length. The filter's radius is `smoothing` of these; the highlight's taps are one apart.
  const float radius_px_at_1 = radius * frame.projection[5] * 0.5f * float(lh);

  // 3. The depth filter (two-dimensional, compute): three smaller passes, then `iterations` at its
  // radius.
  d.smoothed = &d.raw;
  const int iterations = style.filter == LiquidFilter::None ? 0 : std::clamp(style.iterations, 0, kMaxIterations);
  if (iterations > 0) {
    glUseProgram(d.filter);
    glUniform1f(d.fu.radius_at_1, style.smoothing * radius_px_at_1);
    glUniform1f(d.fu.range, std::max(style.depth_range, 0.01f) * radius);
    glUniform1i(d.fu.mode, style.filter == LiquidFilter::NarrowRange ? 0
                           : style.filter == LiquidFilter::Bilateral ? 1
                                                                     : 2);
    glUniform2i(d.fu.size, lw, lh);
    glUniform1i(d.fu.depth, 0);
    for (int i = 0; i < kRampPasses + iterations; ++i) {
      const Target& out = d.smooth[i % 2];
      glUniform1f(d.fu.scale, i < kRampPasses ? std::ldexp(1.0f, i - kRampPasses) : 1.0f);
      glUniform3fv(d.fu.taps, kFilterPairs, d.filter_pass_taps[std::size_t(i)].data());
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
  glUniform1f(d.nu.range, std::max(style.depth_range, 0.01f) * radius);
  glBindTextureUnit(0, d.smoothed->texture);
  glDrawArrays(GL_TRIANGLES, 0, 3);

  // 5. What is behind the liquid, copied for refraction; then the surface over it.
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
  const float color_depth = std::max(style.color_depth, 0.01f) * radius;
  std::array<float, 3> absorb{};
  for (int c = 0; c < 3; ++c)
    absorb[std::size_t(c)] = -std::log(std::clamp(style.color[std::size_t(c)], 1e-3f, 1.0f)) / color_depth;
  glUniform3fv(d.cu.color, 1, style.color.data());
  glUniform3fv(d.cu.absorb, 1, absorb.data());
  glUniform1f(d.cu.color_depth, color_depth);
  glUniform1f(d.cu.refraction, std::clamp(style.refraction, 0.0f, 4.0f));
  glUniform1f(d.cu.opacity_depth, std::max(style.opacity_depth, 0.0f) * radius);
  glUniform1i(d.cu.output, int(style.output));
  glUniform1f(d.cu.radius_at_1, radius_px_at_1);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  glDepthMask(GL_TRUE);
  glDrawArrays(GL_TRIANGLES, 0, 3);

  // 6. Spray over the surface.
  if (style.output == LiquidOutput::Shaded && (style.foam_isolation > 0 || style.foam_speed > 0)) {
    glBindTextureUnit(0, d.thickness.texture);
    glEnable(GL_BLEND);
    glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
    glDepthMask(GL_FALSE);
    d.splat_batches(frame, s, 2, fixed_radius, style, radius);
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
