// What the renderer's passes share: the frame's camera, and the batches as staged in the
// persistently mapped records buffer (bound at shader storage binding 0).
#pragma once

#include <epoxy/gl.h>

#include <array>
#include <cstdint>
#include <span>

#include "particlestream/render.hpp"

namespace pstream::render::detail {

constexpr std::size_t kMaxBatches = Renderer::kMaxMergedBatches;

struct FrameContext {
  Mat4 view = identity(), projection = identity();
  int width = 1, height = 1;
  Vec3 light_view{0, 0, 1};  // towards the key light, view space, unit length
};

// The batches of one draw, where the shaders find them: per batch the first word of its records,
// the words per record, the colour and velocity words (or -1), the size multiplier, the colour
// when there is none, and object -> view.
struct StagedBatches {
  std::size_t n = 0;
  std::array<std::uint64_t, kMaxBatches> count{};
  std::array<GLuint, kMaxBatches> base{}, stride{};
  std::array<GLint, kMaxBatches> color_word{}, velocity_word{};
  std::array<float, kMaxBatches> size{};
  std::array<float, 4 * kMaxBatches> color{};
  std::array<float, 16 * kMaxBatches> model_view{};
};

// A triangle that covers the viewport (no vertex buffer: positions from gl_VertexID).
extern const char* const kFullScreenVertexShader;

// The sky seen along a world-space direction, shared by the backdrop and the liquid's reflection.
extern const char* const kSkyFunction;

class LiquidPass {
 public:
  LiquidPass();
  ~LiquidPass();
  LiquidPass(const LiquidPass&) = delete;
  LiquidPass& operator=(const LiquidPass&) = delete;
  // Draws into the framebuffer bound when called (and leaves it bound).
  void draw(const FrameContext& frame, const StagedBatches& batches, std::span<const ParticleBatch> source,
            const LiquidStyle& style);
  LiquidImage read(LiquidBuffer which) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

class BackdropPass {
 public:
  BackdropPass();
  ~BackdropPass();
  BackdropPass(const BackdropPass&) = delete;
  BackdropPass& operator=(const BackdropPass&) = delete;
  void draw(const FrameContext& frame, const Backdrop& backdrop);

 private:
  GLuint program_ = 0, vao_ = 0;
};

}  // namespace pstream::render::detail
