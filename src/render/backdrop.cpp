// The sky gradient and the ground grid: one full-screen triangle, each pixel's view ray either
// meets the ground plane (grid lines, fading into the horizon's haze; depth written) or shows the
// sky.
#include <fmt/format.h>

#include "gl_program.hpp"
#include "passes.hpp"
#include "shaders.hpp"

namespace pstream::render::detail {

namespace {

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
  // src/render/shaders/backdrop.frag and its functions, shared with the browser player.
  const std::string fragment = glsl_source({kShader_sky_glsl, kShader_ground_ray_glsl, kShader_backdrop_frag});
  program_ = link_program(full_screen_vertex_source().c_str(), fragment.c_str());
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
