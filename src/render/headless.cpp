// An OpenGL 4.5 core context without a display: EGL's device platform where a GPU driver offers
// it, else Mesa's surfaceless platform (llvmpipe on CI), rendering into a framebuffer object.
#include <epoxy/egl.h>
#include <epoxy/gl.h>

#include <algorithm>
#include <cstring>

#include <fmt/format.h>

#include "particlestream/render.hpp"

namespace pstream::render {

struct HeadlessContext::Impl {
  EGLDisplay display = EGL_NO_DISPLAY;
  EGLContext context = EGL_NO_CONTEXT;
  GLuint framebuffer = 0, color = 0, depth = 0;
};

namespace {

EGLDisplay open_display() {
  // A real GPU first (NVIDIA's EGL device platform), then Mesa without any window system.
  if (epoxy_has_egl_extension(EGL_NO_DISPLAY, "EGL_EXT_device_enumeration")) {
    EGLDeviceEXT devices[8];
    EGLint count = 0;
    if (eglQueryDevicesEXT(8, devices, &count) && count > 0) {
      for (EGLint i = 0; i < count; ++i) {
        EGLDisplay d = eglGetPlatformDisplayEXT(EGL_PLATFORM_DEVICE_EXT, devices[i], nullptr);
        EGLint major = 0, minor = 0;
        if (d != EGL_NO_DISPLAY && eglInitialize(d, &major, &minor)) {
          const char* vendor = eglQueryString(d, EGL_VENDOR);
          if (vendor != nullptr && std::strstr(vendor, "Mesa") == nullptr) return d;  // prefer a vendor driver
          eglTerminate(d);
        }
      }
    }
  }
  EGLDisplay d = eglGetPlatformDisplayEXT(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
  EGLint major = 0, minor = 0;
  if (d == EGL_NO_DISPLAY || !eglInitialize(d, &major, &minor)) {
    throw Error(
        "no headless OpenGL: neither an EGL device nor Mesa's surfaceless platform could be initialised "
        "(install libegl-mesa0 and libgl1-mesa-dri, or a GPU driver with EGL)");
  }
  return d;
}

}  // namespace

HeadlessContext::HeadlessContext(int width, int height)
    : width_(width), height_(height), impl_(std::make_unique<Impl>()) {
  if (width <= 0 || height <= 0 || width > 16384 || height > 16384) {
    throw Error(fmt::format("image size {}x{} is out of range (1..16384)", width, height));
  }
  impl_->display = open_display();
  if (!eglBindAPI(EGL_OPENGL_API)) throw Error("EGL: the OpenGL API is not available");
  const EGLint attributes[] = {
      EGL_CONTEXT_MAJOR_VERSION,           4,       EGL_CONTEXT_MINOR_VERSION, 5, EGL_CONTEXT_OPENGL_PROFILE_MASK,
      EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
  impl_->context = eglCreateContext(impl_->display, EGL_NO_CONFIG_KHR, EGL_NO_CONTEXT, attributes);
  if (impl_->context == EGL_NO_CONTEXT) {
    throw Error(
        fmt::format("EGL: no OpenGL 4.5 core context (error 0x{:x}); ParticleStream needs OpenGL 4.5", eglGetError()));
  }
  bind();
  glGenFramebuffers(1, &impl_->framebuffer);
  glGenRenderbuffers(1, &impl_->color);
  glGenRenderbuffers(1, &impl_->depth);
  glBindRenderbuffer(GL_RENDERBUFFER, impl_->color);
  glRenderbufferStorage(GL_RENDERBUFFER, GL_RGBA8, width, height);
  glBindRenderbuffer(GL_RENDERBUFFER, impl_->depth);
  glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, width, height);
  glBindFramebuffer(GL_FRAMEBUFFER, impl_->framebuffer);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, impl_->color);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, impl_->depth);
  if (glCheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
    throw Error("offscreen framebuffer incomplete");
}

HeadlessContext::~HeadlessContext() {
  if (impl_->context != EGL_NO_CONTEXT) {
    eglMakeCurrent(impl_->display, EGL_NO_SURFACE, EGL_NO_SURFACE, impl_->context);
    glDeleteFramebuffers(1, &impl_->framebuffer);
    glDeleteRenderbuffers(1, &impl_->color);
    glDeleteRenderbuffers(1, &impl_->depth);
    eglMakeCurrent(impl_->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    eglDestroyContext(impl_->display, impl_->context);
  }
  if (impl_->display != EGL_NO_DISPLAY) eglTerminate(impl_->display);
}

void HeadlessContext::bind() {
  if (!eglMakeCurrent(impl_->display, EGL_NO_SURFACE, EGL_NO_SURFACE, impl_->context)) {
    throw Error(fmt::format("EGL: cannot make the context current (error 0x{:x})", eglGetError()));
  }
  if (impl_->framebuffer) glBindFramebuffer(GL_FRAMEBUFFER, impl_->framebuffer);
}

std::vector<std::uint8_t> HeadlessContext::read_rgba() {
  std::vector<std::uint8_t> pixels(std::size_t(width_) * height_ * 4);
  glFinish();
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glReadPixels(0, 0, width_, height_, GL_RGBA, GL_UNSIGNED_BYTE, pixels.data());
  const std::size_t row = std::size_t(width_) * 4;  // OpenGL's first row is the bottom one
  for (int y = 0; y < height_ / 2; ++y) {
    std::swap_ranges(pixels.begin() + y * row, pixels.begin() + (y + 1) * row,
                     pixels.begin() + (height_ - 1 - y) * row);
  }
  return pixels;
}

}  // namespace pstream::render
