// The GPU playback path's per-frame work (passes.hpp: GpuFrames): cached frames uploaded once (the
// frame ahead of the playhead copied on a staging thread before it is reached), interpolation
// and the depth sort in compute shaders, the result bound where the draw passes read records and
// order.
#include <algorithm>
#include <array>
#include <atomic>
#include <cstring>

#include <epoxy/gl.h>
#include <fmt/format.h>

#include "base/job_thread.hpp"
#include "particlestream/render.hpp"
#include "particlestream/sort.hpp"
#include "passes.hpp"

namespace pstream::render::detail {
namespace {

constexpr std::uint64_t kNoFrame = ~0ull;
std::uint64_t align_up(std::uint64_t v, std::uint64_t a) { return (v + a - 1) / a * a; }

// A copy of the frame ahead of the playhead (FramePair::ahead) into a clip's staging buffer, made
// on the staging thread; collected by the host, whose GPU-side copy then moves it into the
// clip's buffers.
struct AheadCopy final : base::JobThread::Job {
  std::span<const std::byte> records;
  std::span<const ParticlePair> pairs;
  std::byte* into = nullptr;  // the mapped staging buffer; the table at into + pairs_at
  std::uint64_t pairs_at = 0;
  std::atomic<std::uint32_t>* lent = nullptr;
  std::uint64_t frame = kNoFrame, pairs_version = kNoFrame;

  void run() override {
    if (!records.empty()) std::memcpy(into, records.data(), records.size());
    if (!pairs.empty()) std::memcpy(into + pairs_at, pairs.data(), pairs.size_bytes());
    lent->store(0, std::memory_order_release);  // the player's bytes are its own again (it polls)
  }
};

// One clip's buffers: three cached frames (the pair on screen and the frame after it), two pair
// tables (this pair's and the next one's), and a persistently mapped staging buffer the staging
// thread writes the frame ahead into.
struct Source {
  std::uint64_t id = 0, last_used = 0;
  std::uint64_t max_count = 0;
  std::uint32_t record_size = 0;
  std::array<GLuint, 3> frames{0, 0, 0};
  std::array<std::uint64_t, 3> frame_of{kNoFrame, kNoFrame, kNoFrame};
  std::array<GLuint, 2> pairs{0, 0};
  std::array<std::uint64_t, 2> pairs_version{kNoFrame, kNoFrame};
  GLuint staging = 0;
  std::byte* mapped = nullptr;
  std::uint64_t pairs_at = 0;     // where the table starts in the staging buffer
  GLsync staging_free = nullptr;  // signalled once the GPU has copied out of the staging buffer
  AheadCopy copy;
  std::unique_ptr<GpuInterpolator> interpolator;

  bool holds(std::uint64_t frame) const { return frame == frame_of[0] || frame == frame_of[1] || frame == frame_of[2]; }
  void release() {
    if (frames[0]) glDeleteBuffers(3, frames.data());
    if (pairs[0]) glDeleteBuffers(2, pairs.data());
    if (staging) {
      glUnmapNamedBuffer(staging);
      glDeleteBuffers(1, &staging);
    }
    if (staging_free) glDeleteSync(staging_free);
    frames = {0, 0, 0};
    pairs = {0, 0};
    staging = 0;
    mapped = nullptr;
    staging_free = nullptr;
    copy.reset();
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
  // The staging thread: copies each queued frame ahead into its clip's mapped staging buffer.
  // Declared after the sources, so it ends before their jobs do.
  base::JobThread staging{2 * kMaxBatches};

  Source& source_for(const FramePair& p);
  // Moves a finished copy of the frame ahead from the staging buffer into the clip's buffers (a
  // GPU-side copy): into a frame buffer the pair on screen does not use, and the table into the
  // table buffer this pair does not use.
  void commit(Source& s, const FramePair& p);
  // Queues a copy of the frame ahead when it is not resident yet and the staging buffer is free.
  void start_copy(Source& s, const FramePair& p, std::uint64_t& staged);
  // The buffer slot holding frame `frame` of `s`, uploading `bytes` when none does: into a slot
  // that holds neither `keep` (the pair's other frame) nor, when one is left, `ahead`.
  int frame_slot(Source& s, std::uint64_t frame, std::span<const std::byte> bytes, std::uint64_t keep,
                 std::uint64_t ahead, std::uint64_t& uploaded);
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
  for (Source& s : d.sources) {
    s.copy.wait();  // the thread finishes what is queued (the player waits for it too)
    s.release();
  }
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
  s.copy.wait();
  s.release();
  s.id = p.source;
  s.max_count = std::max<std::uint64_t>(p.max_count, 1);
  s.record_size = p.record_size;
  const std::uint64_t frame_bytes = s.max_count * s.record_size, table_bytes = 2 * s.max_count * sizeof(ParticlePair);
  glCreateBuffers(3, s.frames.data());
  for (GLuint b : s.frames) glNamedBufferStorage(b, GLsizeiptr(frame_bytes), nullptr, GL_DYNAMIC_STORAGE_BIT);
  glCreateBuffers(2, s.pairs.data());
  for (GLuint b : s.pairs) glNamedBufferStorage(b, GLsizeiptr(table_bytes), nullptr, GL_DYNAMIC_STORAGE_BIT);
  // Written by the staging thread while mapped; coherent, so a copy issued after it finished sees it.
  constexpr GLbitfield kMap = GL_MAP_WRITE_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
  s.pairs_at = align_up(frame_bytes, 16);
  glCreateBuffers(1, &s.staging);
  glNamedBufferStorage(s.staging, GLsizeiptr(s.pairs_at + table_bytes), nullptr, kMap | GL_CLIENT_STORAGE_BIT);
  s.mapped = static_cast<std::byte*>(glMapNamedBufferRange(s.staging, 0, GLsizeiptr(s.pairs_at + table_bytes), kMap));
  if (s.mapped == nullptr) {
    s.release();
    throw Error("GPU playback: the driver could not map a staging buffer persistently (GL 4.4 buffer storage)");
  }
  s.frame_of = {kNoFrame, kNoFrame, kNoFrame};
  s.pairs_version = {kNoFrame, kNoFrame};
  s.interpolator = std::make_unique<GpuInterpolator>(p.lanes, p.velocity_offset, p.color_offset);
  return s;
}

void GpuFrames::Impl::commit(Source& s, const FramePair& p) {
  AheadCopy& c = s.copy;
  if (c.state() == AheadCopy::Queued && (c.frame == p.a_frame || (!p.pairs.empty() && c.frame == p.b_frame))) {
    c.wait();  // reached already (a slow staging thread, or a fast playhead): wait, never copy twice
  }
  if (!c.collect()) return;
  if (!c.records.empty() && !s.holds(c.frame)) {
    int slot = 0;
    while (slot < 2 && (s.frame_of[std::size_t(slot)] == p.a_frame ||
                        (!p.pairs.empty() && s.frame_of[std::size_t(slot)] == p.b_frame)))
      ++slot;
    glCopyNamedBufferSubData(s.staging, s.frames[std::size_t(slot)], 0, 0, GLsizeiptr(c.records.size()));
    s.frame_of[std::size_t(slot)] = c.frame;
  }
  if (!c.pairs.empty() && s.pairs_version[0] != c.pairs_version && s.pairs_version[1] != c.pairs_version) {
    const int slot = s.pairs_version[0] == p.pairs_version && p.pairs_version != c.pairs_version ? 1 : 0;
    glCopyNamedBufferSubData(s.staging, s.pairs[std::size_t(slot)], GLintptr(s.pairs_at), 0,
                             GLsizeiptr(c.pairs.size_bytes()));
    s.pairs_version[std::size_t(slot)] = c.pairs_version;
  }
  if (s.staging_free) glDeleteSync(s.staging_free);
  s.staging_free = glFenceSync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0);
}

void GpuFrames::Impl::start_copy(Source& s, const FramePair& p, std::uint64_t& staged) {
  AheadCopy& c = s.copy;
  if (p.ahead.empty() || p.lent == nullptr || c.state() != AheadCopy::Idle) return;
  const bool frame_needed = !s.holds(p.ahead_frame);
  const bool pairs_needed = !p.ahead_pairs.empty() && s.pairs_version[0] != p.ahead_pairs_version &&
                            s.pairs_version[1] != p.ahead_pairs_version;
  if (!frame_needed && !pairs_needed) return;
  if (p.ahead.size() > s.max_count * s.record_size || p.ahead_pairs.size() > 2 * s.max_count) return;
  if (s.staging_free) {  // the GPU still copies out of the staging buffer: try again next frame
    if (glClientWaitSync(s.staging_free, 0, 0) == GL_TIMEOUT_EXPIRED) return;
    glDeleteSync(s.staging_free);
    s.staging_free = nullptr;
  }
  c.records = frame_needed ? p.ahead : std::span<const std::byte>{};
  c.pairs = pairs_needed ? p.ahead_pairs : std::span<const ParticlePair>{};
  c.frame = frame_needed ? p.ahead_frame : kNoFrame;
  c.pairs_version = p.ahead_pairs_version;
  c.into = s.mapped;
  c.pairs_at = s.pairs_at;
  c.lent = p.lent;
  p.lent->store(1, std::memory_order_relaxed);  // (published to the thread by submit's mutex)
  staging.submit(c);
  staged += c.records.size() + c.pairs.size_bytes();
}

int GpuFrames::Impl::frame_slot(Source& s, std::uint64_t frame, std::span<const std::byte> bytes, std::uint64_t keep,
                                std::uint64_t ahead, std::uint64_t& uploaded) {
  for (int i = 0; i < 3; ++i) {
    if (s.frame_of[std::size_t(i)] == frame) return i;
  }
  if (bytes.size() > s.max_count * s.record_size)
    throw Error(fmt::format("GPU playback: a frame of {} bytes, more than its clip's largest ({} bytes)", bytes.size(),
                            s.max_count * s.record_size));
  int slot = -1;
  for (int i = 0; i < 3; ++i) {
    const std::uint64_t held = s.frame_of[std::size_t(i)];
    if (held == keep && keep != kNoFrame) continue;
    if (slot < 0 || s.frame_of[std::size_t(slot)] == ahead) slot = i;
  }
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
    d.commit(s, p);
    const std::uint64_t ahead = p.ahead.empty() ? kNoFrame : p.ahead_frame;
    const int ia = d.frame_slot(s, p.a_frame, p.a, p.pairs.empty() ? kNoFrame : p.b_frame, ahead, uploaded_bytes);
    if (!p.pairs.empty()) {
      const int ib = d.frame_slot(s, p.b_frame, p.b, p.a_frame, ahead, uploaded_bytes);
      int table = s.pairs_version[0] == p.pairs_version ? 0 : s.pairs_version[1] == p.pairs_version ? 1 : -1;
      if (table < 0) {  // not made ahead: uploaded now, over the table not kept for the pair ahead
        table = s.pairs_version[0] == p.ahead_pairs_version && !p.ahead_pairs.empty() ? 1 : 0;
        glNamedBufferSubData(s.pairs[std::size_t(table)], 0, GLsizeiptr(p.pairs.size_bytes()), p.pairs.data());
        s.pairs_version[std::size_t(table)] = p.pairs_version;
        uploaded_bytes += p.pairs.size_bytes();
      }
      s.interpolator->run(s.frames[std::size_t(ia)], s.frames[std::size_t(ib)], s.pairs[std::size_t(table)],
                          std::uint32_t(p.pairs.size()), p.t, p.dt, p.hermite, p.nearer, d.out, offset[k]);
    } else if (batches.size() == 1) {  // on a cached frame, alone: drawn from its buffer, no copy
      records = s.frames[std::size_t(ia)];
    } else if (b.count > 0) {  // on a cached frame: its records as they are
      glCopyNamedBufferSubData(s.frames[std::size_t(ia)], d.out, 0, GLintptr(offset[k]),
                               GLsizeiptr(b.count * b.record_size));
    }
    d.start_copy(s, p, staged_bytes);
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
