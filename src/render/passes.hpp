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
  Vec3 light_view{0, 0, 1};   // towards the key light, view space, unit length
  Vec3 light_world{0, 1, 0};  // the same in world space
};

// The batches of one draw, where the shaders find them: per batch the first word of its records,
// the words per record, the colour and velocity words (or -1), the size multiplier, the colour
// when there is none, and object -> view.
struct StagedBatches {
  std::size_t n = 0;
  std::array<std::uint64_t, kMaxBatches> count{};
  std::array<GLuint, kMaxBatches> base{}, stride{};
  std::array<GLint, kMaxBatches> color_word{}, velocity_word{}, scalar_word{};
  std::array<float, kMaxBatches> size{};
  std::array<float, 4 * kMaxBatches> color{}, tint{};
  std::array<float, 16 * kMaxBatches> model_view{};
};

// Batch k's entries of `staged`: its records start at word `base_word` of the bound buffer.
void stage_batch(StagedBatches& staged, std::size_t k, const ParticleBatch& batch, std::uint64_t base_word,
                 const Mat4& view);

// Each of the first `n` batches' object -> `view` matrix, 16 floats a batch (as
// StagedBatches::model_view holds the camera's): for a light buffer, the light's view.
std::array<float, 16 * kMaxBatches> model_views(const Mat4& view, std::span<const ParticleBatch> source, std::size_t n);

// A light buffer (R16F, square: an orthographic view along the light, shadow_light()) that a
// look's particles add their opacities to, and the shadow it casts on the ground plane: the
// self-shadowing sprites' and the liquid's (shaders/ground_shadow.frag).
class ShadowBuffer {
 public:
  ShadowBuffer();
  ~ShadowBuffer();
  ShadowBuffer(const ShadowBuffer&) = delete;
  ShadowBuffer& operator=(const ShadowBuffer&) = delete;
  // Makes the buffer `size` square (64..4096) unless it is already, and clears it to no opacity.
  void clear(int size);
  // Binds it as the framebuffer with its viewport, blending each fragment's opacity "over" what
  // is there (premultiplied: ONE, ONE_MINUS_SRC_ALPHA).
  void bind_for_opacity() const;
  GLuint texture() const { return texture_; }
  int size() const { return size_; }
  // Multiplies the shadow over the ground y = `ground_height` into the framebuffer bound when
  // called, with the viewport of `frame`: each pixel whose view ray meets the ground there is
  // darkened by `strength` (0..1) times the opacity above it (a 3x3 blur of the buffer). Leaves
  // blending on.
  void darken_ground(const FrameContext& frame, float ground_height, const ShadowLight& light, float strength) const;

 private:
  GLuint texture_ = 0, framebuffer_ = 0, program_ = 0, vao_ = 0;
  int size_ = 0;
  GLint view_ = -1, projection_ = -1, viewport_ = -1, ground_ = -1, light_view_ = -1, light_projection_ = -1,
        buffer_ = -1, texel_ = -1, strength_ = -1;
};

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

// What one sprite draw covers: instances (the order's length, or every record), whether the order
// holds (batch << 28) | index entries, the blend mode and sprite texture of the draw.
struct SpriteDraw {
  std::uint64_t instances = 0;
  std::uint64_t order_count = 0;  // 0: stored order
  bool merged = false;
  bool points = false;  // GL points instead of quads (a benchmark's baseline)
  BlendMode blend = BlendMode::Alpha;
  GLuint sprite = 0;  // an artist's sprite texture, or 0
};

class SpritePass {
 public:
  SpritePass();
  ~SpritePass();
  SpritePass(const SpritePass&) = delete;
  SpritePass& operator=(const SpritePass&) = delete;
  // Draws into the framebuffer bound when called (and leaves it bound).
  void draw(const FrameContext& frame, const StagedBatches& batches, std::span<const ParticleBatch> source,
            const SpriteDraw& what, const SpriteStyle& style);

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
  void draw_box(const FrameContext& frame, const Vec3& lo, const Vec3& hi, const std::array<float, 4>& color);

 private:
  GLuint program_ = 0, box_program_ = 0, vao_ = 0;
  GLint u_view_ = -1, u_projection_ = -1, u_viewport_ = -1, u_ground_ = -1, u_ground_height_ = -1, u_grid_ = -1;
  GLint b_view_projection_ = -1, b_lo_ = -1, b_hi_ = -1, b_color_ = -1;
};

// The GPU path's frames (ParticleBatch::pair): per clip, the cached frames' records and the pair
// table in GPU buffers, each uploaded once (a frame when it first appears, the table when its
// version changes); per host frame, compute passes interpolate every batch into one records
// buffer and, when asked, sort them all together by depth. stage() then leaves the records bound
// at shader storage binding 0 and the order at 1, as the CPU path's staging does, so every pass
// (sprites, shadow slices, motion blur, liquid) draws them the same way.
class GpuFrames {
 public:
  GpuFrames(std::uint64_t max_bytes_per_frame, GLint ssbo_alignment);
  ~GpuFrames();
  GpuFrames(const GpuFrames&) = delete;
  GpuFrames& operator=(const GpuFrames&) = delete;
  // Fills `staged` for `batches` (all with a pair) and returns the order's length (0: stored
  // order); `merged` tells whether its entries carry the batch.
  std::uint64_t stage(std::span<const ParticleBatch> batches, SortMode sort, const Mat4& sort_view, const Mat4& view,
                      StagedBatches& staged, bool& merged);
  std::uint64_t uploaded_bytes = 0;  // by the host thread, since the last reset by the renderer
  std::uint64_t staged_bytes = 0;    // queued for the staging thread, likewise

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace pstream::render::detail
