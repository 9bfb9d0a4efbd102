// The renderer: each frame's records are copied once into a persistently mapped, multi-buffered
// buffer guarded by fences, where every pass's shaders pull them from (shader storage), in the
// sort module's order. The passes: sprites (sprites.cpp), liquid (liquid.cpp), backdrop
// (backdrop.cpp).
#include <epoxy/gl.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>

#include <fmt/format.h>

#include "gl_program.hpp"
#include "particlestream/render.hpp"
#include "passes.hpp"

namespace pstream::render {
namespace {

std::uint64_t align_up(std::uint64_t v, std::uint64_t a) { return (v + a - 1) / a * a; }

}  // namespace

void detail::stage_batch(StagedBatches& s, std::size_t k, const ParticleBatch& b, std::uint64_t base_word,
                         const Mat4& view) {
  s.count[k] = b.count;
  s.base[k] = GLuint(base_word);
  s.stride[k] = b.record_size / 4;
  s.color_word[k] = b.color_offset >= 0 ? b.color_offset / 4 : -1;
  s.velocity_word[k] = b.velocity_offset >= 0 ? b.velocity_offset / 4 : -1;
  s.scalar_word[k] = b.scalar_offset >= 0 ? b.scalar_offset / 4 : -1;
  s.size[k] = b.size_multiplier;
  std::copy(b.color.begin(), b.color.end(), s.color.begin() + 4 * std::ptrdiff_t(k));
  std::copy(b.tint.begin(), b.tint.end(), s.tint.begin() + 4 * std::ptrdiff_t(k));
  const Mat4 mv = multiply(view, b.world);
  std::copy(mv.begin(), mv.end(), s.model_view.begin() + 16 * std::ptrdiff_t(k));
}

struct Renderer::Impl {
  RendererOptions options;
  detail::FrameContext frame;
  detail::StagedBatches staged;
  std::unique_ptr<detail::LiquidPass> liquid;      // made on the first liquid draw
  std::unique_ptr<detail::BackdropPass> backdrop;  // made on the first backdrop
  std::unique_ptr<detail::SpritePass> sprites;
  std::unique_ptr<detail::GpuFrames> gpu;  // the GPU playback path, made on its first frame
  RendererStats stats;
  // Copies the batches' records (and the order) into this frame's region of the mapped buffers,
  // binds them, and fills `staged`; false when there is nothing to draw.
  bool stage(std::span<const ParticleBatch> batches, std::span<const std::uint32_t> order);
  // The GPU path's staging (GpuFrames): the order's length, and whether it is merged.
  std::uint64_t stage_gpu(const DrawData& frame, bool& merged);
  void draw_staged(std::span<const ParticleBatch> batches, std::uint64_t order_count, bool merged,
                   const SpriteStyle& style);
  GLuint records = 0, order = 0, sprite = 0;
  std::string sprite_path;
  std::byte* records_map = nullptr;
  std::uint32_t* order_map = nullptr;
  std::uint64_t region_bytes = 0, order_region = 0;  // per frame in flight
  std::vector<GLsync> fences;
  int region = 0;
  std::uint64_t records_used = 0, order_used = 0;
  GLint ssbo_alignment = 256;
};

std::string Renderer::gl_renderer() {
  const auto* r = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  return r ? r : "unknown";
}

Renderer::Renderer(RendererOptions options) : impl_(std::make_unique<Impl>()) {
  Impl& d = *impl_;
  d.options = options;
  if (epoxy_gl_version() < 45 || !epoxy_is_desktop_gl()) {
    throw Error(
        fmt::format("OpenGL 4.5 core is required; this context offers {} {}.{} ({}). Use `pstream render` for "
                    "headless rendering, or update the graphics driver",
                    epoxy_is_desktop_gl() ? "OpenGL" : "OpenGL ES", epoxy_gl_version() / 10, epoxy_gl_version() % 10,
                    gl_renderer()));
  }
  d.sprites = std::make_unique<detail::SpritePass>();
  glGetIntegerv(GL_SHADER_STORAGE_BUFFER_OFFSET_ALIGNMENT, &d.ssbo_alignment);

  // Persistent, coherent mappings: one region per frame in flight, written by the CPU while the
  // GPU reads the others.
  const int n = std::max(1, options.buffering);
  d.region_bytes = align_up(options.max_bytes_per_frame, 4096);
  d.order_region = align_up(options.max_bytes_per_frame / 4, 4096);
  const GLbitfield flags = GL_MAP_WRITE_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
  glCreateBuffers(1, &d.records);
  glNamedBufferStorage(d.records, GLsizeiptr(d.region_bytes * n), nullptr, flags);
  d.records_map = static_cast<std::byte*>(glMapNamedBufferRange(d.records, 0, GLsizeiptr(d.region_bytes * n), flags));
  glCreateBuffers(1, &d.order);
  glNamedBufferStorage(d.order, GLsizeiptr(d.order_region * n), nullptr, flags);
  d.order_map = static_cast<std::uint32_t*>(glMapNamedBufferRange(d.order, 0, GLsizeiptr(d.order_region * n), flags));
  if (d.records_map == nullptr || d.order_map == nullptr) throw Error("cannot map the particle buffers persistently");
  d.fences.assign(std::size_t(n), nullptr);
}

Renderer::~Renderer() {
  Impl& d = *impl_;
  d.liquid.reset();
  d.backdrop.reset();
  d.sprites.reset();
  for (GLsync f : d.fences) {
    if (f) glDeleteSync(f);
  }
  glUnmapNamedBuffer(d.records);
  glUnmapNamedBuffer(d.order);
  glDeleteBuffers(1, &d.records);
  glDeleteBuffers(1, &d.order);
  if (d.sprite) glDeleteTextures(1, &d.sprite);
}

void Renderer::begin_frame(int width, int height, const Camera& camera, const std::array<float, 4>& background) {
  Impl& d = *impl_;
  d.region = (d.region + 1) % int(d.fences.size());
  if (GLsync f = d.fences[std::size_t(d.region)]) {  // the GPU may still read this region
    glClientWaitSync(f, GL_SYNC_FLUSH_COMMANDS_BIT, GLuint64(5'000'000'000));
    glDeleteSync(f);
    d.fences[std::size_t(d.region)] = nullptr;
  }
  d.records_used = d.order_used = 0;
  d.stats = {};
  d.frame.view = camera.view();
  d.frame.projection = camera.projection(float(width) / float(std::max(height, 1)));
  d.frame.width = std::max(width, 1);
  d.frame.height = std::max(height, 1);
  const Vec3& l = d.options.light_direction;
  d.frame.light_view = view_direction(d.frame.view, l);
  const float lw = std::sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]);
  d.frame.light_world = lw > 0 ? Vec3{l[0] / lw, l[1] / lw, l[2] / lw} : Vec3{0, 1, 0};
  glViewport(0, 0, width, height);
  glClearColor(background[0], background[1], background[2], background[3]);
  glDepthMask(GL_TRUE);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
}

void Renderer::draw(const ParticleBatch& b, const SpriteStyle& style) {
  const bool ordered = !b.order.empty() && b.blend != BlendMode::Additive;
  impl_draw({&b, 1}, ordered ? b.order : std::span<const std::uint32_t>{}, false, style);
}

const Vec3& Renderer::light_direction() const { return impl_->options.light_direction; }
const RendererStats& Renderer::stats() const { return impl_->stats; }

void Renderer::prepare(const DrawData& frame) {
  Impl& d = *impl_;
  if (frame.batches.empty()) return;
  if (frame.batches.front().pair != nullptr) {
    bool merged = false;
    d.stage_gpu(frame, merged);
  } else {
    d.stage(frame.batches, frame.merged_order.empty() ? frame.batches.front().order : frame.merged_order);
  }
}

void Renderer::draw(const DrawData& frame) {
  if (frame.backdrop) draw_backdrop(*frame.backdrop);
  if (frame.box) {
    const std::array<float, 6>& b = *frame.box;
    draw_box({b[0], b[1], b[2]}, {b[3], b[4], b[5]}, {0.9f, 0.75f, 0.3f, 0.6f});
  }
  const bool gpu =
      std::any_of(frame.batches.begin(), frame.batches.end(), [](const ParticleBatch& b) { return b.pair != nullptr; });
  if (gpu) {  // the GPU path: the records are made (and ordered) here, in compute shaders
    Impl& d = *impl_;
    if (!std::all_of(frame.batches.begin(), frame.batches.end(),
                     [](const ParticleBatch& b) { return b.pair != nullptr; }))
      throw Error("a frame's batches are all on the GPU path or all on the CPU path");
    if (frame.batches.empty()) return;
    bool merged = false;
    const std::uint64_t order = d.stage_gpu(frame, merged);
    if (frame.look == Look::Liquid) {
      if (!d.liquid) d.liquid = std::make_unique<detail::LiquidPass>();
      d.liquid->draw(d.frame, d.staged, frame.batches, frame.liquid);
      return;
    }
    d.draw_staged(frame.batches, order, merged, frame.sprites);
    return;
  }
  if (frame.look == Look::Liquid) {  // one surface from every clip; needs no order
    draw_liquid(frame.batches, frame.liquid);
    return;
  }
  if (!frame.merged_order.empty()) {
    draw_merged(frame.batches, frame.merged_order, frame.sprites);
    return;
  }
  for (const ParticleBatch& b : frame.batches) draw(b, frame.sprites);
}

void Renderer::draw_merged(std::span<const ParticleBatch> batches, std::span<const std::uint32_t> order,
                           const SpriteStyle& style) {
  if (batches.size() > kMaxMergedBatches) {
    throw Error(
        fmt::format("{} streams drawn together; the renderer merges at most {}", batches.size(), kMaxMergedBatches));
  }
  impl_draw(batches, order, true, style);
}

bool Renderer::Impl::stage(std::span<const ParticleBatch> batches, std::span<const std::uint32_t> order) {
  Impl& d = *this;
  std::uint64_t total = 0, bytes = 0;
  for (const ParticleBatch& b : batches) {
    const std::uint64_t n = b.first.size() + b.second.size();
    if (n != b.count * b.record_size || b.record_size % 4 != 0) {
      throw Error(fmt::format("particle batch: {} bytes for {} records of {} bytes", n, b.count, b.record_size));
    }
    total += b.count;
    bytes += n;
  }
  if (total == 0) return false;
  const std::uint64_t at = align_up(d.records_used, std::uint64_t(d.ssbo_alignment));
  const std::uint64_t order_at = align_up(d.order_used, std::uint64_t(d.ssbo_alignment));
  if (at + bytes > d.region_bytes || order_at + order.size_bytes() > d.order_region) {
    throw Error(fmt::format("a frame of {:.1f} MiB exceeds the renderer's {:.1f} MiB per frame (RendererOptions)",
                            (at + bytes) / 1048576.0, d.region_bytes / 1048576.0));
  }
  // Each frame's records move once: from the stream's cache into the mapped GPU buffer, batch
  // after batch; the shader finds a batch's records at its base word.
  std::byte* dst = d.records_map + std::uint64_t(d.region) * d.region_bytes + at;
  detail::StagedBatches& s = d.staged;
  s.n = batches.size();
  std::uint64_t offset = 0;
  for (std::size_t k = 0; k < batches.size(); ++k) {
    const ParticleBatch& b = batches[k];
    std::memcpy(dst + offset, b.first.data(), b.first.size());
    if (!b.second.empty()) std::memcpy(dst + offset + b.first.size(), b.second.data(), b.second.size());
    detail::stage_batch(s, k, b, offset / 4, d.frame.view);
    offset += b.first.size() + b.second.size();
  }
  glBindBufferRange(GL_SHADER_STORAGE_BUFFER, 0, d.records, GLintptr(std::uint64_t(d.region) * d.region_bytes + at),
                    GLsizeiptr(bytes));
  if (!order.empty()) {
    std::memcpy(reinterpret_cast<std::byte*>(d.order_map) + std::uint64_t(d.region) * d.order_region + order_at,
                order.data(), order.size_bytes());
    glBindBufferRange(GL_SHADER_STORAGE_BUFFER, 1, d.order,
                      GLintptr(std::uint64_t(d.region) * d.order_region + order_at), GLsizeiptr(order.size_bytes()));
    d.order_used = order_at + order.size_bytes();
  } else {
    glBindBufferRange(GL_SHADER_STORAGE_BUFFER, 1, d.order, 0, 4);
  }
  d.records_used = at + bytes;
  d.stats.upload_bytes += bytes + order.size_bytes();
  return true;
}

std::uint64_t Renderer::Impl::stage_gpu(const DrawData& f, bool& merged) {
  Impl& d = *this;
  if (!d.gpu) d.gpu = std::make_unique<detail::GpuFrames>(d.options.max_bytes_per_frame, d.ssbo_alignment);
  d.gpu->uploaded_bytes = 0;
  d.gpu->staged_bytes = 0;
  const std::uint64_t order = d.gpu->stage(f.batches, f.sort, f.sort_view, d.frame.view, d.staged, merged);
  d.stats.upload_bytes += d.gpu->uploaded_bytes;
  d.stats.staged_bytes += d.gpu->staged_bytes;
  return order;
}

void Renderer::impl_draw(std::span<const ParticleBatch> batches, std::span<const std::uint32_t> order, bool merged,
                         const SpriteStyle& style) {
  Impl& d = *impl_;
  if (!d.stage(batches, order)) return;
  d.draw_staged(batches, order.size(), merged, style);
}

void Renderer::Impl::draw_staged(std::span<const ParticleBatch> batches, std::uint64_t order_count, bool merged,
                                 const SpriteStyle& style) {
  Impl& d = *this;
  const detail::StagedBatches& s = d.staged;
  const ParticleBatch& first = batches.front();                    // blend mode and sprite of the draw
  if (!first.texture.empty() && first.texture != d.sprite_path) {  // an artist's sprite, loaded once
    int w = 0, h = 0;
    const auto pixels = read_png(first.texture, w, h);
    if (d.sprite) glDeleteTextures(1, &d.sprite);
    glCreateTextures(GL_TEXTURE_2D, 1, &d.sprite);
    glTextureStorage2D(d.sprite, 1, GL_RGBA8, w, h);
    glTextureSubImage2D(d.sprite, 0, 0, 0, w, h, GL_RGBA, GL_UNSIGNED_BYTE, pixels.data());
    glTextureParameteri(d.sprite, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    d.sprite_path = first.texture;
  }
  detail::SpriteDraw what;
  for (std::size_t k = 0; k < s.n; ++k) what.instances += s.count[k];
  what.order_count = order_count;
  what.merged = merged;
  what.points = d.options.points;
  what.blend = first.blend;
  what.sprite = first.texture.empty() ? 0 : d.sprite;
  d.sprites->draw(d.frame, s, batches, what, style);
}

void Renderer::draw_liquid(std::span<const ParticleBatch> batches, const LiquidStyle& style) {
  Impl& d = *impl_;
  if (batches.size() > kMaxMergedBatches) {
    throw Error(fmt::format("{} streams drawn as one liquid; the renderer merges at most {}", batches.size(),
                            kMaxMergedBatches));
  }
  if (!d.stage(batches, {})) return;
  if (!d.liquid) d.liquid = std::make_unique<detail::LiquidPass>();
  d.liquid->draw(d.frame, d.staged, batches, style);
}

LiquidImage Renderer::read_liquid(LiquidBuffer which) const {
  if (!impl_->liquid) throw Error("read_liquid: nothing was drawn as a liquid yet");
  return impl_->liquid->read(which);
}

void Renderer::draw_backdrop(const Backdrop& backdrop) {
  Impl& d = *impl_;
  if (!d.backdrop) d.backdrop = std::make_unique<detail::BackdropPass>();
  d.backdrop->draw(d.frame, backdrop);
}

void Renderer::draw_box(const Vec3& lo, const Vec3& hi, const std::array<float, 4>& color) {
  Impl& d = *impl_;
  if (!d.backdrop) d.backdrop = std::make_unique<detail::BackdropPass>();
  d.backdrop->draw_box(d.frame, lo, hi, color);
}

void Renderer::end_frame() {
  Impl& d = *impl_;
  d.fences[std::size_t(d.region)] = glFenceSync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0);
}

}  // namespace pstream::render
