// Compiling and linking the renderer's GLSL programs (one place for every pass).
#pragma once

#include <epoxy/gl.h>

#include <initializer_list>
#include <string>
#include <string_view>

namespace pstream::render::detail {

// Links a program from a vertex and a fragment shader; throws pstream::Error with the driver's
// log when either fails to compile or the program fails to link.
GLuint link_program(const char* vertex_source, const char* fragment_source);
// A compute program, the same way.
GLuint link_compute_program(const char* compute_source);
// GLSL 4.50 source: the version line, then `parts` in order (src/render/shaders/'s files, which
// the browser player shares and which start without one, and this side's own mains).
std::string glsl_source(std::initializer_list<std::string_view> parts);
// The full-screen passes' vertex stage: one triangle over the viewport.
const std::string& full_screen_vertex_source();
// Bilinear filtering and clamping at the edges: how the passes read each other's render targets.
void linear_clamped(GLuint texture);

}  // namespace pstream::render::detail
