// The GPU playback path's per-frame work (passes.hpp: GpuFrames): cached frames uploaded once,
// interpolation and the depth sort in compute shaders, the result bound where the draw passes
// read records and order.
#include <algorithm>
#include <array>
#include <cstring>

#include <epoxy/gl.h>
#include <fmt/format.h>

#include "particlestream/render.hpp"
#include "particlestream/sort.hpp"
#include "passes.hpp"

namespace pstream::render::detail {
namespace {

constexpr std::uint64_t kNoFrame = ~0ull;
std::uint64_t align_up(std::uint64_t v, std::uint64_t a) { return (v + a - 1) / a * a; }

// One clip's buffers: its two most recent cached frames and its pair table.
struct Source {
  std::uint64_t id = 0, last_used = 0;
  std::uint64_t max_count = 0;
  std::uint32_t record_size = 0;
  std::array<GLuint, 2> frames{0, 0};
  std::array<std::uint64_t, 2> frame_of{kNoFrame, kNoFrame};
  GLuint pairs = 0;
  std::uint64_t pairs_version = kNoFrame;
  std::unique_ptr<GpuInterpolator> interpolator;
  void release() {
    if (frames[0]) glDeleteBuffers(2, frames.data());
    if (pairs) glDeleteBuffers(1, &pairs);
    frames = {0, 0};
    pairs = 0;
    interpolator.reset();
    id = 0;
  }
};

}  // namespace

struct GpuFrames::Impl {
  std::uint64_t capacity = 0;  // bytes of the interpolated records buffer
  GLint alignment = 256;
  GLuint out = 0;
  std::unique_ptr<GpuSorter> sorter;  // made on the first sorted frame
  std::array<Source, 2 * kMaxBatches> sources;
  std::uint64_t frame_counter = 0;

  Source& source_for(const FramePair& p);
  // The buffer slot holding frame `frame` of `s` (uploading `bytes` into the slot not in `keep`).
  int frame_slot(Source& s, std::uint64_t frame, std::span<const std::byte> bytes, int keep, std::uint64_t& uploaded);
};

GpuFrames::GpuFrames(std::uint64_t max_bytes_per_frame, GLint ssbo_alignment) : impl_(std::make_unique<Impl>()) {
  Impl& d = *impl_;
  d.capacity = std::max<std::uint64_t>(max_bytes_per_frame, 4096);
  d.alignment = std::max<GLint>(ssbo_alignment, 4);
  glCreateBuffers(1, &d.out);
  glNamedBufferStorage(d.out, GLsizeiptr(d.capacity), nullptr, 0);
}

GpuFrames::~GpuFrames() {
  Impl& d = *impl_;
  for (Source& s : d.sources) s.release();
  d.sorter.reset();
  glDeleteBuffers(1, &d.out);
}

Source& GpuFrames::Impl::source_for(const FramePair& p) {
  Source* victim = &sources[0];
  for (Source& s : sources) {
    if (s.id == p.source && s.record_size == p.record_size && s.max_count >= p.max_count) return s;
    if (s.id == 0 || (victim->id != 0 && s.last_used < victim->last_used)) victim = &s;
  }
  // A clip seen for the first time (or one whose buffers were given to another): its buffers
  // for its largest frame, made once.
  Source& s = *victim;
  s.release();
  s.id = p.source;
  s.max_count = std::max<std::uint64_t>(p.max_count, 1);
  s.record_size = p.record_size;
  glCreateBuffers(2, s.frames.data());
  for (GLuint b : s.frames)
    glNamedBufferStorage(b, GLsizeiptr(s.max_count * s.record_size), nullptr, GL_DYNAMIC_STORAGE_BIT);
  glCreateBuffers(1, &s.pairs);
  glNamedBufferStorage(s.pairs, GLsizeiptr(2 * s.max_count * sizeof(ParticlePair)), nullptr, GL_DYNAMIC_STORAGE_BIT);
  s.frame_of = {kNoFrame, kNoFrame};
  s.pairs_version = kNoFrame;
  s.interpolator = std::make_unique<GpuInterpolator>(p.lanes, p.velocity_offset, p.color_offset);
  return s;
}

int GpuFrames::Impl::frame_slot(Source& s, std::uint64_t frame, std::span<const std::byte> bytes, int keep,
                                std::uint64_t& uploaded) {
  for (int i = 0; i < 2; ++i) {
    if (s.frame_of[std::size_t(i)] == frame) return i;
  }
  const int slot = keep == 0 ? 1 : 0;
  if (bytes.size() > s.max_count * s.record_size)
    throw Error(fmt::format("GPU playback: a frame of {} bytes, more than its clip's largest ({} bytes)", bytes.size(),
                            s.max_count * s.record_size));
  if (!bytes.empty()) glNamedBufferSubData(s.frames[std::size_t(slot)], 0, GLsizeiptr(bytes.size()), bytes.data());
  s.frame_of[std::size_t(slot)] = frame;
  uploaded += bytes.size();
  return slot;
}

std::uint64_t GpuFrames::stage(std::span<const ParticleBatch> batches, SortMode sort, const Mat4& sort_view,
                               const Mat4& view, StagedBatches& st, bool& merged) {
  Impl& d = *impl_;
  ++d.frame_counter;
  if (batches.size() > kMaxBatches)
    throw Error(fmt::format("{} clips drawn together; the renderer takes at most {}", batches.size(), kMaxBatches));
  std::uint64_t at = 0, total = 0;
  std::array<std::uint64_t, kMaxBatches> offset{};
  for (std::size_t k = 0; k < batches.size(); ++k) {
    at = align_up(at, std::uint64_t(d.alignment));
    offset[k] = at;
    at += batches[k].count * batches[k].record_size;
    total += batches[k].count;
  }
  if (at > d.capacity) {
    throw Error(fmt::format("a frame of {:.1f} MiB exceeds the renderer's {:.1f} MiB per frame (RendererOptions)",
                            at / 1048576.0, d.capacity / 1048576.0));
  }
  const bool sorting = sort != SortMode::None && total > 1;
  if (sorting && (!d.sorter || d.sorter->capacity() < total)) {
    // Sized once for the most particles a frame can have: every byte of the buffer a record.
    d.sorter.reset();
    d.sorter = std::make_unique<GpuSorter>(std::uint32_t(std::max<std::uint64_t>(total, d.capacity / kRecordHeadSize)));
  }
  merged = sorting && batches.size() > 1;
  st.n = batches.size();
  std::uint32_t first = 0;
  GLuint records = d.out;  // where the frame's records end up
  for (std::size_t k = 0; k < batches.size(); ++k) {
    const ParticleBatch& b = batches[k];
    const FramePair& p = *b.pair;
    Source& s = d.source_for(p);
    s.last_used = d.frame_counter;
    const int ia = d.frame_slot(s, p.a_frame, p.a, -1, uploaded_bytes);
    if (!p.pairs.empty()) {
      const int ib = d.frame_slot(s, p.b_frame, p.b, ia, uploaded_bytes);
      if (s.pairs_version != p.pairs_version) {
        glNamedBufferSubData(s.pairs, 0, GLsizeiptr(p.pairs.size_bytes()), p.pairs.data());
        s.pairs_version = p.pairs_version;
        uploaded_bytes += p.pairs.size_bytes();
      }
      s.interpolator->run(s.frames[std::size_t(ia)], s.frames[std::size_t(ib)], s.pairs, std::uint32_t(p.pairs.size()),
                          p.t, p.dt, p.hermite, p.nearer, d.out, offset[k]);
    } else if (batches.size() == 1) {  // on a cached frame, alone: drawn from its buffer, no copy
      records = s.frames[std::size_t(ia)];
    } else if (b.count > 0) {  // on a cached frame: its records as they are
      glCopyNamedBufferSubData(s.frames[std::size_t(ia)], d.out, 0, GLintptr(offset[k]),
                               GLsizeiptr(b.count * b.record_size));
    }
    stage_batch(st, k, b, offset[k] / 4, view);
    if (sorting) {
      glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
      const sort::DepthAxis a = sort::depth_axis(multiply(sort_view, b.world));
      d.sorter->depth_keys(records, offset[k], std::uint32_t(b.count), b.record_size, {a.x, a.y, a.z, a.offset},
                           sort == SortMode::BackToFront, first, merged ? std::uint32_t(k) << kMergedIndexBits : 0u);
    }
    first += std::uint32_t(b.count);
  }
  glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
  if (sorting) d.sorter->sort(std::uint32_t(total));  // (it binds its own buffers)
  glBindBufferRange(GL_SHADER_STORAGE_BUFFER, 0, records, 0, GLsizeiptr(std::max<std::uint64_t>(at, 4)));
  if (!sorting) {
    glBindBufferRange(GL_SHADER_STORAGE_BUFFER, 1, d.out, 0, 4);  // unread
    return 0;
  }
  glBindBufferRange(GL_SHADER_STORAGE_BUFFER, 1, d.sorter->values_buffer(), 0, GLsizeiptr(total * 4));
  return total;
}

}  // namespace pstream::render::detail
