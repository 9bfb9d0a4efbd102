#include "gl_program.hpp"

#include <array>
#include <initializer_list>

#include <fmt/format.h>

#include "particlestream/error.hpp"
#include "shaders.hpp"

namespace pstream::render::detail {
namespace {

GLuint compile(GLenum type, const char* source) {
  const GLuint s = glCreateShader(type);
  glShaderSource(s, 1, &source, nullptr);
  glCompileShader(s);
  GLint ok = 0;
  glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    std::array<char, 2048> log{};
    glGetShaderInfoLog(s, GLsizei(log.size()), nullptr, log.data());
    glDeleteShader(s);
    throw Error(fmt::format("{} shader compilation failed: {}",
                            type == GL_VERTEX_SHADER    ? "vertex"
                            : type == GL_COMPUTE_SHADER ? "compute"
                                                        : "fragment",
                            log.data()));
  }
  return s;
}

// Links the compiled shaders (and deletes them), or throws with the driver's log.
GLuint link(std::initializer_list<GLuint> shaders) {
  const GLuint program = glCreateProgram();
  for (const GLuint s : shaders) glAttachShader(program, s);
  glLinkProgram(program);
  for (const GLuint s : shaders) glDeleteShader(s);
  GLint ok = 0;
  glGetProgramiv(program, GL_LINK_STATUS, &ok);
  if (!ok) {
    std::array<char, 2048> log{};
    glGetProgramInfoLog(program, GLsizei(log.size()), nullptr, log.data());
    glDeleteProgram(program);
    throw Error(fmt::format("shader link failed: {}", log.data()));
  }
  return program;
}

}  // namespace

GLuint link_program(const char* vertex_source, const char* fragment_source) {
  const GLuint vs = compile(GL_VERTEX_SHADER, vertex_source);
  GLuint fs = 0;
  try {
    fs = compile(GL_FRAGMENT_SHADER, fragment_source);
  } catch (...) {
    glDeleteShader(vs);
    throw;
  }
  return link({vs, fs});
}

GLuint link_compute_program(const char* compute_source) { return link({compile(GL_COMPUTE_SHADER, compute_source)}); }

void linear_clamped(GLuint texture) {
  glTextureParameteri(texture, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
  glTextureParameteri(texture, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
  glTextureParameteri(texture, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
  glTextureParameteri(texture, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
}

std::string glsl_source(std::initializer_list<std::string_view> parts) {
  std::string source = "#version 450 core\n";
  for (const std::string_view part : parts) source += part;
  return source;
}

const std::string& full_screen_vertex_source() {
  static const std::string source = glsl_source({kShader_full_screen_vert});
  return source;
}

}  // namespace pstream::render::detail
