// Drawing particle frames: camera-facing instanced quads pulled straight from the frame's records
// (OpenGL 4.5 core through libepoxy), in a window or headless (EGL without a display).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "particlestream/error.hpp"
#include "particlestream/frame.hpp"

namespace pstream::render {

// The frame model (math, camera, batches, styles) is GL-free, in frame.hpp.

// The buffers of the last liquid draw, read back as floats (tests and tools; allocates).
enum class LiquidBuffer { RawDepth, Depth, Normals, Thickness };  // Normals: 3 floats a pixel, view space
struct LiquidImage {
  int width = 0, height = 0, channels = 1;
  std::vector<float> values;  // bottom row first, as OpenGL stores it; depth: distance along the view axis, 0: none
};

struct RendererOptions {
  std::uint64_t max_bytes_per_frame = 64ull << 20;  // records and indices of all batches of a frame
  int buffering = 3;                                // frames in flight in the persistent buffers
  Vec3 light_direction{-0.4f, 0.8f, 0.45f};         // world space, towards the light
  bool points = false;                              // draw GL points instead of quads (benchmark)
};

// What the renderer moved from host memory to the GPU since begin_frame().
struct RendererStats {
  // By the host thread: on the CPU path every frame's records and order; on the GPU path
  // (ParticleBatch::pair) a cached frame's records and its pair table when they are needed and
  // were not staged ahead (the first frames, after a seek), else nothing.
  std::uint64_t upload_bytes = 0;
  // The GPU path: bytes of the frame ahead of the playhead (FramePair::ahead) and its table, handed
  // to the renderer's staging thread this frame to be copied once, before the playhead gets there.
  std::uint64_t staged_bytes = 0;
};

// Needs a current OpenGL 4.5 core context. Throws pstream::Error naming what is missing.
class Renderer {
 public:
  explicit Renderer(RendererOptions options = {});
  ~Renderer();
  Renderer(const Renderer&) = delete;
  Renderer& operator=(const Renderer&) = delete;

  void begin_frame(int width, int height, const Camera& camera, const std::array<float, 4>& background);
  void draw(const ParticleBatch& batch, const SpriteStyle& style = {});
  // Several streams' frames as one draw, in a merged order (frame.hpp: kMergedIndexBits, at most
  // kMaxMergedBatches batches), so overlapping streams blend in depth order. The first batch's
  // blend mode and sprite apply to all.
  static constexpr std::size_t kMaxMergedBatches = render::kMaxMergedBatches;
  void draw_merged(std::span<const ParticleBatch> batches, std::span<const std::uint32_t> order,
                   const SpriteStyle& style = {});
  // Several streams drawn as one liquid surface (Look::Liquid). Needs no draw order; the
  // surface is depth-tested against what is already drawn and writes its depth. The GPU buffers
  // are made on the first liquid draw and when the viewport's size changes.
  void draw_liquid(std::span<const ParticleBatch> batches, const LiquidStyle& style);
  LiquidImage read_liquid(LiquidBuffer which) const;
  // The sky and, optionally, the ground grid; call it first in a frame (it replaces the clear
  // colour and writes the ground's depth).
  void draw_backdrop(const Backdrop& backdrop);
  // The edges of the world box [lo, hi] as lines (context: where the clip can be), depth-tested.
  void draw_box(const Vec3& lo, const Vec3& hi, const std::array<float, 4>& color);
  // A whole frame as the playback layer describes it (frame.hpp): the backdrop, the box, then the
  // batches as sprites (merged or each in its order) or as one liquid surface. Batches with a
  // FramePair (the GPU path) are made here: each clip's cached frames and pair table go to GPU
  // buffers once, then compute shaders interpolate (GpuInterpolator) and sort (GpuSorter, every
  // batch together, as DrawData::sort says), and the draw reads the results where they are.
  void draw(const DrawData& frame);
  // What draw() does before its draw calls, alone: the frame's records (and order) made resident
  // on the GPU — the GPU path's uploads and compute passes, the CPU path's copy into the mapped
  // buffer. For measuring the playback cost apart from the drawing (`pstream bench playback`).
  void prepare(const DrawData& frame);
  const RendererStats& stats() const;
  void end_frame();                     // fences this frame's buffer region
  const Vec3& light_direction() const;  // RendererOptions::light_direction
  static std::string gl_renderer();

 private:
  void impl_draw(std::span<const ParticleBatch> batches, std::span<const std::uint32_t> order, bool merged,
                 const SpriteStyle& style);
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// A stable LSD radix sort of (key, value) pairs in compute shaders (OpenGL 4.3; no subgroup
// operations, so it runs on Mesa's llvmpipe as on GPUs): 4-bit digits, 8 passes for 32-bit keys
// or 4 for 16-bit ones. Pairs with equal keys keep their order, so values 0..n-1 sorted by
// (key, index) give exactly the CPU radix sort's order (sort::DepthSorter). Its buffers for
// `capacity` pairs are made once; sort() allocates nothing. Needs a current context.
class GpuSorter {
 public:
  explicit GpuSorter(std::uint32_t capacity);
  ~GpuSorter();
  GpuSorter(const GpuSorter&) = delete;
  GpuSorter& operator=(const GpuSorter&) = delete;
  std::uint32_t capacity() const;
  // The GL buffers (names) holding the pairs: fill the first `count` keys and values, sort(), and
  // read the sorted pairs from the same buffers.
  std::uint32_t keys_buffer() const;
  std::uint32_t values_buffer() const;
  // Sorts the first `count` pairs ascending by key (`key_bits` 16: keys below 65536).
  void sort(std::uint32_t count, int key_bits = 32);
  // Fills the pairs with depth keys for the camera: for record i of the GL buffer `records`
  // (from byte `offset`, `stride` bytes apart), depth = dot(position, axis.xyz) + axis.w with the
  // CPU's operations (sort::depth_axis gives the axis of a view x world matrix), its
  // order-preserving key (flipped when `back_to_front`), and i. Then sort(count) gives exactly
  // sort::DepthSorter's order. Several batches sorted together: each writes its pairs from
  // `first` on, its values or-ed with `tag` ((batch << kMergedIndexBits), as
  // sort::DepthSorter::sort_merged makes them).
  void depth_keys(std::uint32_t records, std::uint64_t offset, std::uint32_t count, std::uint32_t stride,
                  const std::array<float, 4>& axis, bool back_to_front, std::uint32_t first = 0, std::uint32_t tag = 0);
  // For tests: the depth order of host records (uploaded to a temporary buffer). Allocates.
  std::vector<std::uint32_t> order_by_depth(std::span<const std::byte> records, std::uint32_t stride,
                                            const std::array<float, 4>& axis, bool back_to_front);
  // For tests and benchmarks: uploads `keys` with values 0..n-1, sorts, returns the values (the
  // order). Allocates.
  std::vector<std::uint32_t> sort_indices(std::span<const std::uint32_t> keys, int key_bits = 32);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Interpolation between two cached frames in a compute shader: the playback layer's rules
// (playback/interpolate.hpp: FrameBlender::blend), word by word as `lanes` says (frame.hpp),
// for the particles of a pair table (frame.hpp: ParticlePair; playback::pair_table makes it).
// Within 2 ulps of the CPU path (the CPU kernel may fuse multiply-adds where the GPU does not);
// ids, colours' other words and integers copied bit for bit. Needs a current context.
class GpuInterpolator {
 public:
  GpuInterpolator(std::span<const RecordLane> lanes, std::int32_t velocity_offset, std::int32_t color_offset);
  ~GpuInterpolator();
  GpuInterpolator(const GpuInterpolator&) = delete;
  GpuInterpolator& operator=(const GpuInterpolator&) = delete;
  // Records of frames a and b (GL buffers), the pair table (`count` entries), out: count records
  // from byte `out_offset` (a multiple of GL_SHADER_STORAGE_BUFFER_OFFSET_ALIGNMENT) on.
  // `hermite`: along the curve (when the records have velocities); `nearer`: the pair table is
  // the nearer frame alone (no matching), moved along its velocities without shrinking.
  void run(std::uint32_t a, std::uint32_t b, std::uint32_t pairs, std::uint32_t count, double t, double dt,
           bool hermite, bool nearer, std::uint32_t out, std::uint64_t out_offset = 0);
  // For tests: host records in, host records out (temporary buffers). Allocates.
  std::vector<std::byte> run_host(std::span<const std::byte> a, std::span<const std::byte> b,
                                  std::span<const ParticlePair> pairs, double t, double dt, bool hermite, bool nearer);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// An offscreen OpenGL 4.5 context and framebuffer: EGL's device platform (GPU machines) or
// Mesa's surfaceless platform, no display needed.
class HeadlessContext {
 public:
  HeadlessContext(int width, int height);
  ~HeadlessContext();
  HeadlessContext(const HeadlessContext&) = delete;
  HeadlessContext& operator=(const HeadlessContext&) = delete;
  int width() const { return width_; }
  int height() const { return height_; }
  void bind();                            // makes the context current and binds the framebuffer
  std::vector<std::uint8_t> read_rgba();  // top row first
 private:
  int width_, height_;
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

void write_png(const std::filesystem::path& path, int width, int height, std::span<const std::uint8_t> rgba);
std::vector<std::uint8_t> read_png(const std::filesystem::path& path, int& width, int& height);

}  // namespace pstream::render
