// The sky gradient and the ground grid: one full-screen triangle, each pixel's view ray either
// meets the ground plane (grid lines, fading into the horizon's haze; depth written) or shows the
// sky.
#include <fmt/format.h>

#include "gl_program.hpp"
#include "passes.hpp"

namespace pstream::render::detail {

const char* const kFullScreenVertexShader = R"(#version 450 core
void main() {
  vec2 p = vec2(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0);
  gl_Position = vec4(p, 0.0, 1.0);
}
)";

const char* const kSkyFunction = R"(
vec3 sky_color(vec3 d) {  // d: a unit world direction
  const vec3 zenith = vec3(0.13, 0.27, 0.52), horizon = vec3(0.58, 0.66, 0.75), below = vec3(0.16, 0.17, 0.19);
  if (d.y >= 0.0) return mix(horizon, zenith, pow(d.y, 0.55));
  return mix(horizon, below, pow(-d.y, 0.35));
}
)";

const char* const kGroundRayFunction = R"(
uniform mat4 u_view;
uniform mat4 u_projection;
uniform vec2 u_viewport;
bool ground_ray(float h, out vec3 dir, out float t, out vec3 hit) {
  vec2 ndc = gl_FragCoord.xy / u_viewport * 2.0 - 1.0;
  mat3 to_world = transpose(mat3(u_view));
  vec3 eye = -(to_world * u_view[3].xyz);
  dir = normalize(to_world * vec3(ndc.x / u_projection[0][0], ndc.y / u_projection[1][1], -1.0));
  t = (h - eye.y) / dir.y;
  hit = eye + t * dir;
  return dir.y < 0.0 && t > 0.0;
}
)";

namespace {

constexpr const char* kBackdropFragment = R"(
uniform bool u_ground;
uniform float u_ground_height;
uniform float u_grid;
out vec4 o_color;
void main() {
  vec3 dir, hit;
  float t;
  bool on_ground = ground_ray(u_ground_height, dir, t, hit);
  vec3 sky = sky_color(dir);
  if (!u_ground || !on_ground) {
    o_color = vec4(sky, 1.0);
    gl_FragDepth = 1.0;
    return;
  }
  vec2 g = hit.xz / u_grid;
  vec2 w = fwidth(g);
  vec2 line = abs(fract(g - 0.5) - 0.5) / max(w, vec2(1e-6));
  float on_line = 1.0 - min(min(line.x, line.y), 1.0);
  on_line *= 1.0 - smoothstep(0.15, 0.6, max(w.x, w.y));  // lines closer than a few pixels fade out
  vec3 ground = mix(vec3(0.30, 0.31, 0.33), vec3(0.48, 0.50, 0.53), on_line);
  float haze = 1.0 - exp(-t / (60.0 * u_grid));
  o_color = vec4(mix(ground, sky_color(vec3(dir.x, 0.0, dir.z)), haze), 1.0);
  vec4 clip = u_projection * u_view * vec4(hit, 1.0);
  gl_FragDepth = clamp(clip.z / clip.w * 0.5 + 0.5, 0.0, 1.0);
}
)";

// The twelve edges of a box: vertex k of 24 is a corner, its bits from a table.
constexpr const char* kBoxVertex = R"(#version 450 core
uniform mat4 u_view_projection;
uniform vec3 u_lo, u_hi;
const int kCorners[24] = int[24](0, 1, 2, 3, 4, 5, 6, 7, 0, 2, 1, 3, 4, 6, 5, 7, 0, 4, 1, 5, 2, 6, 3, 7);
void main() {
  int c = kCorners[gl_VertexID];
  vec3 p = vec3((c & 1) != 0 ? u_hi.x : u_lo.x, (c & 2) != 0 ? u_hi.y : u_lo.y, (c & 4) != 0 ? u_hi.z : u_lo.z);
  gl_Position = u_view_projection * vec4(p, 1.0);
}
)";

constexpr const char* kBoxFragment = R"(#version 450 core
uniform vec4 u_color;
out vec4 o_color;
void main() { o_color = vec4(u_color.rgb * u_color.a, u_color.a); }
)";

}  // namespace

BackdropPass::BackdropPass() {
  const std::string fragment =
      std::string("#version 450 core\n") + kSkyFunction + kGroundRayFunction + kBackdropFragment;
  program_ = link_program(kFullScreenVertexShader, fragment.c_str());
  const auto loc = [&](const char* name) { return glGetUniformLocation(program_, name); };
  u_view_ = loc("u_view");
  u_projection_ = loc("u_projection");
  u_viewport_ = loc("u_viewport");
  u_ground_ = loc("u_ground");
  u_ground_height_ = loc("u_ground_height");
  u_grid_ = loc("u_grid");
  box_program_ = link_program(kBoxVertex, kBoxFragment);
  b_view_projection_ = glGetUniformLocation(box_program_, "u_view_projection");
  b_lo_ = glGetUniformLocation(box_program_, "u_lo");
  b_hi_ = glGetUniformLocation(box_program_, "u_hi");
  b_color_ = glGetUniformLocation(box_program_, "u_color");
  glCreateVertexArrays(1, &vao_);
}

BackdropPass::~BackdropPass() {
  glDeleteVertexArrays(1, &vao_);
  glDeleteProgram(program_);
  glDeleteProgram(box_program_);
}

void BackdropPass::draw_box(const FrameContext& frame, const Vec3& lo, const Vec3& hi,
                            const std::array<float, 4>& color) {
  glUseProgram(box_program_);
  glBindVertexArray(vao_);
  const Mat4 vp = multiply(frame.projection, frame.view);
  glUniformMatrix4fv(b_view_projection_, 1, GL_FALSE, vp.data());
  glUniform3fv(b_lo_, 1, lo.data());
  glUniform3fv(b_hi_, 1, hi.data());
  glUniform4fv(b_color_, 1, color.data());
  glEnable(GL_BLEND);
  glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  glDepthMask(GL_FALSE);
  glDrawArrays(GL_LINES, 0, 24);
  glDepthMask(GL_TRUE);
}

void BackdropPass::draw(const FrameContext& frame, const Backdrop& backdrop) {
  glUseProgram(program_);
  glBindVertexArray(vao_);
  glUniformMatrix4fv(u_view_, 1, GL_FALSE, frame.view.data());
  glUniformMatrix4fv(u_projection_, 1, GL_FALSE, frame.projection.data());
  glUniform2f(u_viewport_, float(frame.width), float(frame.height));
  glUniform1i(u_ground_, backdrop.ground ? 1 : 0);
  glUniform1f(u_ground_height_, backdrop.ground_height);
  glUniform1f(u_grid_, backdrop.grid_spacing > 0 ? backdrop.grid_spacing : 1.0f);
  glDisable(GL_BLEND);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_ALWAYS);
  glDepthMask(GL_TRUE);
  glDrawArrays(GL_TRIANGLES, 0, 3);
  glDepthFunc(GL_LESS);
}

}  // namespace pstream::render::detail
