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

namespace {

constexpr const char* kBackdropFragment = R"(
uniform mat4 u_view;
uniform mat4 u_projection;
uniform vec2 u_viewport;
uniform bool u_ground;
uniform float u_ground_height;
uniform float u_grid;
out vec4 o_color;
void main() {
  vec2 ndc = gl_FragCoord.xy / u_viewport * 2.0 - 1.0;
  mat3 to_world = transpose(mat3(u_view));
  vec3 eye = -(to_world * u_view[3].xyz);
  vec3 dir = normalize(to_world * vec3(ndc.x / u_projection[0][0], ndc.y / u_projection[1][1], -1.0));
  vec3 sky = sky_color(dir);
  float t = (u_ground_height - eye.y) / dir.y;
  if (!u_ground || dir.y >= 0.0 || t <= 0.0) {
    o_color = vec4(sky, 1.0);
    gl_FragDepth = 1.0;
    return;
  }
  vec3 hit = eye + t * dir;
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

}  // namespace

BackdropPass::BackdropPass() {
  const std::string fragment = std::string("#version 450 core\n") + kSkyFunction + kBackdropFragment;
  program_ = link_program(kFullScreenVertexShader, fragment.c_str());
  glCreateVertexArrays(1, &vao_);
}

BackdropPass::~BackdropPass() {
  glDeleteVertexArrays(1, &vao_);
  glDeleteProgram(program_);
}

void BackdropPass::draw(const FrameContext& frame, const Backdrop& backdrop) {
  glUseProgram(program_);
  glBindVertexArray(vao_);
  const auto loc = [&](const char* name) { return glGetUniformLocation(program_, name); };
  glUniformMatrix4fv(loc("u_view"), 1, GL_FALSE, frame.view.data());
  glUniformMatrix4fv(loc("u_projection"), 1, GL_FALSE, frame.projection.data());
  glUniform2f(loc("u_viewport"), float(frame.width), float(frame.height));
  glUniform1i(loc("u_ground"), backdrop.ground ? 1 : 0);
  glUniform1f(loc("u_ground_height"), backdrop.ground_height);
  glUniform1f(loc("u_grid"), backdrop.grid_spacing > 0 ? backdrop.grid_spacing : 1.0f);
  glDisable(GL_BLEND);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_ALWAYS);
  glDepthMask(GL_TRUE);
  glDrawArrays(GL_TRIANGLES, 0, 3);
  glDepthFunc(GL_LESS);
}

}  // namespace pstream::render::detail
