// The chunk cache and its state machine (docs/streaming.md).
//
// Chunks are loaded in playback order. The k-th chunk of that order ("sequence number" k) maps
// to chunk c0 + k mod N of the playback range [c0, c1] (N chunks; laps repeat it when looping),
// and lives in slot (slot_base + k - seq_base) mod s. The slots holding sequence numbers
// [oldest, next) are Loading or Ready; all others are Empty. Because consecutive chunks sit in
// consecutive slots, a frame is contiguous in the cache except across the ring's wrap.
//
// Threads: update() (the host's thread) and the IO worker's completion callback share the slot
// states and the load queue under one mutex, held for a few hundred nanoseconds. The callback
// marks a finished slot Ready and chains the next load, so loading never waits for the host's
// next frame; update() releases consumed slots and moves the current frame.
#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <new>

#include <fmt/format.h>

#include "particlestream/stream.hpp"
#include "stream/load_request.hpp"

namespace pstream::stream {
namespace {

constexpr std::size_t kCacheAlignment = 4096;

struct AlignedDelete {
  void operator()(std::byte* p) const { ::operator delete[](p, std::align_val_t(kCacheAlignment)); }
};

std::uint64_t first_chunk(const format::Metadata& m, std::uint64_t frame) {
  return std::min(m.frames[frame].byte_offset / m.chunk_size, m.chunk_count() ? m.chunk_count() - 1 : 0);
}

std::uint64_t last_chunk(const format::Metadata& m, std::uint64_t frame) {
  const auto& f = m.frames[frame];
  if (f.count == 0) return first_chunk(m, frame);
  return (f.byte_offset + f.count * m.record_size - 1) / m.chunk_size;
}

}  // namespace

std::size_t cache_slots(const format::Metadata& m, double seconds) {
  if (m.chunk_count() == 0) return 0;
  const double wanted = std::ceil(seconds * m.fps * double(m.max_count) / m.particles_per_chunk());
  // Every frame must fit: the most chunks any one frame spans, read from the frame index.
  std::uint64_t frame_chunks = 1;
  for (std::uint64_t f = 0; f < m.frame_count(); ++f)
    frame_chunks = std::max(frame_chunks, last_chunk(m, f) - first_chunk(m, f) + 1);
  std::uint64_t s = std::max<std::uint64_t>(2, static_cast<std::uint64_t>(std::max(wanted, 0.0)));
  s = std::min<std::uint64_t>(s, m.chunk_count());
  s = std::max<std::uint64_t>(s, frame_chunks);
  return static_cast<std::size_t>(s);
}

struct ParticleStream::Impl {
  const format::Metadata* meta = nullptr;
  std::unique_ptr<IoBackend> io;
  std::shared_ptr<IoScheduler> scheduler;
  std::shared_ptr<MemoryBudget> budget;
  std::string name;

  std::unique_ptr<std::byte[], AlignedDelete> cache;
  std::size_t slot_count = 0;
  std::uint64_t chunk_size = 0, cache_bytes = 0;

  std::vector<LoadRequest> requests;
  std::vector<std::unique_ptr<format::ChunkDecoder>> decoders;
  std::unique_ptr<std::byte[]> staging;  // one max-stored-size region per request
  std::uint64_t staging_each = 0;

  // Playback range in frames and the chunks covering it (host thread only).
  std::uint64_t frame_begin = 0, frame_end = 0, c0 = 0, c1 = 0;
  double speed = 1.0;
  std::uint64_t lap = 0;
  std::uint64_t current_frame = 0, current_lap = 0;

  // Shared with the IO worker, under `mutex`.
  mutable std::mutex mutex;
  std::condition_variable loaded;  // a load finished (blocking mode, close)
  std::vector<SlotInfo> slots;
  mutable std::vector<SlotInfo> slots_snapshot;  // what debug() hands out
  std::uint64_t seq_base = 0, slot_base = 0, oldest = 0, next = 0;
  std::string failure;
  std::uint64_t loads_done = 0, bytes_read = 0, stalls = 0;
  std::int64_t io_ns = 0, decode_ns = 0;
  std::uint32_t in_flight = 0;

  // Flags last, packed together.
  bool blocking = false, playing = false, current_valid = false;  // host thread
  bool loop = false, closing = false, failed = false;             // under `mutex`
  bool closed = false;

  std::uint64_t range_chunks() const { return c1 - c0 + 1; }
  std::size_t slot_of(std::uint64_t seq) const { return (slot_base + (seq - seq_base)) % slot_count; }

  // Starts loads in playback order into Empty slots, up to the allowed number in flight.
  void issue_locked() {
    if (closing || failed) return;
    const std::uint64_t N = range_chunks();
    while (in_flight < requests.size() && next - oldest < slot_count) {
      if (!loop && next >= N) return;  // never past the last chunk unless looping
      const std::size_t slot = slot_of(next);
      if (slots[slot].state != SlotState::Empty) return;  // still busy with a discarded load
      LoadRequest* r = nullptr;
      for (LoadRequest& candidate : requests) {
        if (candidate.status.load(std::memory_order_relaxed) == LoadRequest::Idle) {
          r = &candidate;
          break;
        }
      }
      if (r == nullptr) return;
      const std::uint64_t chunk = c0 + next % N;
      const std::size_t index = static_cast<std::size_t>(r - requests.data());
      r->io = io.get();
      r->decoder = decoders[index].get();
      r->entry = meta->chunks[chunk];
      r->chunk = chunk;
      r->destination = {cache.get() + slot * chunk_size, meta->chunk_raw_size(chunk)};
      r->staging = {staging.get() + index * staging_each, staging_each};
      r->slot = slot;
      r->seq = next;
      r->discard = false;
      r->on_done = &Impl::on_done;
      r->owner = this;
      slots[slot] = SlotInfo{SlotState::Loading, static_cast<std::int64_t>(chunk)};
      ++next;
      ++in_flight;
      scheduler->submit(r);
    }
  }

  // On the IO worker, after a load: Loading -> Ready (or Empty, or the stream fails), then the
  // next load.
  static void on_done(void* owner, LoadRequest* r) {
    Impl& d = *static_cast<Impl*>(owner);
    std::lock_guard lock(d.mutex);
    const int st = r->status.load(std::memory_order_acquire);
    --d.in_flight;
    if (st == LoadRequest::Failed && !r->discard) {
      d.failed = true;
      d.failure = r->error;
      d.slots[r->slot] = SlotInfo{};
    } else if (r->discard || r->seq < d.oldest) {  // made useless by a seek or a jump ahead
      d.slots[r->slot] = SlotInfo{};
    } else {
      d.slots[r->slot].state = SlotState::Ready;
      ++d.loads_done;
      d.bytes_read += r->entry.stored_size;
      d.io_ns += r->io_ns;
      d.decode_ns += r->decode_ns;
    }
    r->discard = false;
    r->status.store(LoadRequest::Idle, std::memory_order_release);
    d.issue_locked();
    d.loaded.notify_all();
  }
};

std::unique_ptr<ParticleStream> ParticleStream::open(const std::filesystem::path& path, StreamOptions options) {
  std::unique_ptr<ParticleStream> s(new ParticleStream());
  auto impl = std::make_unique<Impl>();
  impl->io = options.io ? std::move(options.io) : open_file(path);
  impl->name = impl->io->name();
  // Header first, then the tables it points at: two reads, whatever the file's size.
  const std::uint64_t file_size = impl->io->size();
  std::vector<std::byte> head(std::min<std::uint64_t>(file_size, format::kHeaderSize));
  impl->io->read(0, head);
  const format::Header header = format::parse_header(head, file_size, impl->name);
  std::vector<std::byte> tables(header.tables_size);
  impl->io->read(header.tables_offset, tables);
  s->meta_ = format::parse_tables(header, tables, impl->name);
  const format::Metadata& m = s->meta_;
  impl->meta = &s->meta_;

  impl->blocking = options.blocking;
  impl->scheduler = options.scheduler ? options.scheduler : IoScheduler::shared_default();
  impl->chunk_size = m.chunk_size;
  std::size_t slots = cache_slots(m, options.cache_seconds);
  if (options.min_slots) slots = std::max(slots, std::min<std::size_t>(options.min_slots, m.chunk_count()));
  if (options.max_slots) {
    const std::size_t floor = cache_slots(m, 0.0);  // what a largest frame needs
    slots = std::max(floor, std::min(slots, options.max_slots));
  }
  impl->slot_count = slots;
  impl->cache_bytes = slots * m.chunk_size;
  if (options.budget && !options.budget->try_reserve(impl->cache_bytes)) {
    throw Error(
        fmt::format("{}: its cache of {} slots x {} KiB = {:.1f} MiB does not fit the memory budget ({:.1f} of {:.1f} "
                    "MiB used)",
                    impl->name, slots, m.chunk_size >> 10, impl->cache_bytes / 1048576.0,
                    options.budget->used() / 1048576.0, options.budget->total() / 1048576.0));
  }
  impl->budget = options.budget;
  // The cache: one allocation of s x chunk_size bytes, made here and never again.
  impl->cache.reset(static_cast<std::byte*>(
      ::operator new[](std::max<std::uint64_t>(impl->cache_bytes, 1), std::align_val_t(kCacheAlignment))));
  impl->slots.assign(slots, SlotInfo{});
  impl->slots_snapshot.assign(slots, SlotInfo{});
  const unsigned loads = std::max(1u, options.max_loads_in_flight);
  impl->requests = std::vector<LoadRequest>(loads);
  for (unsigned i = 0; i < loads; ++i) impl->decoders.push_back(std::make_unique<format::ChunkDecoder>());
  std::uint64_t max_stored = 0;
  for (const auto& c : m.chunks) {
    if (c.codec != format::Codec::Raw) max_stored = std::max(max_stored, c.stored_size);
  }
  impl->staging_each = max_stored;
  impl->staging.reset(new std::byte[std::max<std::uint64_t>(max_stored * loads, 1)]);
  impl->scheduler->reserve(loads);

  s->impl_ = std::move(impl);
  s->set_range(m.frame_count() ? m.frames.front().time : 0.0, m.frame_count() ? m.frames.back().time : 0.0);
  s->update(0.0);  // start loading
  return s;
}

ParticleStream::~ParticleStream() { close(); }

void ParticleStream::close() {
  if (!impl_ || impl_->closed) return;
  Impl& d = *impl_;
  {
    std::unique_lock lock(d.mutex);
    d.closing = true;  // no new loads; wait for those in flight, which write into the cache
    d.loaded.wait(lock, [&] { return d.in_flight == 0; });
  }
  d.scheduler->release(d.requests.size());
  if (d.budget) d.budget->release(d.cache_bytes);
  d.closed = true;
}

void ParticleStream::play() {
  if (state_ == PlayState::Error) return;
  state_ = PlayState::Playing;
  impl_->playing = true;
}

void ParticleStream::pause() {
  if (state_ == PlayState::Error) return;
  state_ = PlayState::Paused;
  impl_->playing = false;
}

void ParticleStream::stop() {
  if (state_ == PlayState::Error) return;
  pause();
  state_ = PlayState::Stopped;
  seek(meta_.frame_count() ? meta_.frames[impl_->frame_begin].time : 0.0);
}

void ParticleStream::set_loop(bool loop) {
  {
    std::lock_guard lock(impl_->mutex);
    impl_->loop = loop;
  }
  if (!loop && impl_->lap > 0) seek(time_);  // renumber the chunk sequence from lap 0
}

void ParticleStream::set_speed(double speed) { impl_->speed = std::max(0.0, speed); }

void ParticleStream::set_range(double start, double end) {
  Impl& d = *impl_;
  if (meta_.frame_count() == 0) return;
  const auto to_frame = [&](double t) {
    const double f = std::round((t - meta_.time_of_frame0) * meta_.fps);
    return static_cast<std::uint64_t>(std::clamp(f, 0.0, double(meta_.frame_count() - 1)));
  };
  {
    std::lock_guard lock(d.mutex);  // the IO worker reads c0/c1 when it chains loads
    d.frame_begin = to_frame(std::min(start, end));
    d.frame_end = to_frame(std::max(start, end));
    d.c0 = first_chunk(meta_, d.frame_begin);
    d.c1 = std::max(d.c0, last_chunk(meta_, d.frame_end));
  }
  seek(std::clamp(time_, meta_.frames[d.frame_begin].time, meta_.frames[d.frame_end].time));
}

void ParticleStream::seek(double time) {
  Impl& d = *impl_;
  if (state_ == PlayState::Error || meta_.frame_count() == 0) {
    time_ = time;
    return;
  }
  time_ = std::clamp(time, meta_.frames[d.frame_begin].time, meta_.frames[d.frame_end].time);
  d.lap = 0;
  const std::uint64_t frame = static_cast<std::uint64_t>(
      std::clamp(std::round((time_ - meta_.time_of_frame0) * meta_.fps), double(d.frame_begin), double(d.frame_end)));
  std::lock_guard lock(d.mutex);
  // Drop the cache. Loads still in flight free their slots when they complete.
  std::size_t after = 0;
  for (LoadRequest& r : d.requests) {
    if (r.status.load(std::memory_order_acquire) != LoadRequest::Idle) {
      r.discard = true;
      after = (r.slot + 1) % d.slot_count;  // restart the ring after it, so it is reused last
    }
  }
  for (SlotInfo& slot : d.slots) {
    if (slot.state == SlotState::Ready) slot = SlotInfo{};
  }
  d.seq_base = d.oldest = d.next = first_chunk(meta_, frame) - d.c0;
  d.slot_base = after;
  seeking_ = true;
  d.current_valid = false;
}

void ParticleStream::update(double dt) {
  if (!impl_ || impl_->closed || state_ == PlayState::Error) return;
  Impl& d = *impl_;
  const format::Metadata& m = meta_;
  if (m.frame_count() == 0 || m.chunk_count() == 0) {  // nothing to load: every frame is empty
    seeking_ = false;
    d.current_valid = m.frame_count() > 0;
    return;
  }
  const std::uint64_t N = d.range_chunks();
  const auto frame_of = [&](double t) {
    return static_cast<std::uint64_t>(
        std::clamp(std::round((t - m.time_of_frame0) * m.fps), double(d.frame_begin), double(d.frame_end)));
  };
  const auto seq_range = [&](std::uint64_t lap, std::uint64_t frame) {
    return std::pair{lap * N + (first_chunk(m, frame) - d.c0), lap * N + (last_chunk(m, frame) - d.c0)};
  };

  // 1. Advance time on the host's clock.
  if (d.playing && dt > 0.0) {
    time_ += dt * d.speed;
    const double start = m.frames[d.frame_begin].time, end = m.frames[d.frame_end].time;
    if (time_ > end + 0.5 / m.fps) {
      if (d.loop) {
        const double period = end - start + 1.0 / m.fps;
        while (time_ > end + 0.5 / m.fps) {
          time_ -= period;
          ++d.lap;
        }
      } else {
        time_ = end;
        d.playing = false;
        state_ = PlayState::Paused;
      }
    }
  }
  const std::uint64_t target = frame_of(time_);
  const auto needed = seq_range(d.lap, target);
  const std::uint64_t need_first = needed.first, need_last = needed.second;  // named: lambdas capture them

  std::unique_lock lock(d.mutex);
  const auto failed = [&] {  // the IO worker reported a fault: the stream stops, the host goes on
    if (!d.failed) return false;
    state_ = PlayState::Error;
    error_ = d.failure;
    d.playing = false;
    d.current_valid = false;
    return true;
  };
  if (failed()) return;
  const auto ready = [&] {
    if (m.frames[target].count == 0) return true;
    if (need_first < d.oldest || need_last >= d.next) return false;
    for (std::uint64_t k = need_first; k <= need_last; ++k) {
      if (d.slots[d.slot_of(k)].state != SlotState::Ready) return false;
    }
    return true;
  };
  // 2. Release what playback has passed. The current frame is handed out until a newer one is
  // complete, so its chunks stay held — unless it and the target cannot both fit in the ring
  // (a long stall): then it is dropped. Chunks no shown frame needs are skipped.
  std::uint64_t hold_from = need_first;
  if (d.current_valid) {
    const std::uint64_t current_first = seq_range(d.current_lap, d.current_frame).first;
    if (current_first < need_first && need_last >= current_first + d.slot_count) {
      d.current_valid = false;
    } else {
      hold_from = std::min(current_first, need_first);
    }
  }
  while (d.oldest < hold_from && d.oldest < d.next) {
    SlotInfo& slot = d.slots[d.slot_of(d.oldest)];
    if (slot.state == SlotState::Ready) slot = SlotInfo{};  // a Loading one frees on completion
    ++d.oldest;
  }
  if (d.next < hold_from) d.oldest = d.next = hold_from;
  // 3. Keep the IO worker busy (it also chains loads by itself as each one completes).
  d.issue_locked();
  // 4. Blocking mode (offline rendering): wait for the frame instead of stalling.
  if (d.blocking) {
    d.loaded.wait(lock,
                  [&] { return d.failed || ready() || (d.in_flight == 0 && (d.issue_locked(), d.in_flight == 0)); });
    if (failed()) return;
  }
  if (ready()) {
    d.current_valid = true;
    d.current_frame = target;
    d.current_lap = d.lap;
    seeking_ = false;
  } else if (d.current_valid && !seeking_ && (target != d.current_frame || d.lap != d.current_lap)) {
    ++d.stalls;  // the last complete frame stays current; playback catches up when data arrives
  }
}

FrameView ParticleStream::frame() const {
  FrameView v;
  const Impl& d = *impl_;
  if (!d.current_valid || state_ == PlayState::Error) return v;
  const format::Metadata& m = meta_;
  const auto& f = m.frames[d.current_frame];
  v.frame = d.current_frame;
  v.count = f.count;
  v.time = f.time;
  v.valid = true;
  if (f.count == 0) return v;
  // The slots of the current frame are Ready and held: only the host thread releases them.
  const std::uint64_t seq = d.current_lap * d.range_chunks() + (first_chunk(m, d.current_frame) - d.c0);
  const std::size_t slot = d.slot_of(seq);
  const std::uint64_t within = f.byte_offset - first_chunk(m, d.current_frame) * m.chunk_size;
  const std::uint64_t bytes = f.count * m.record_size;
  const std::uint64_t to_ring_end = (d.slot_count - slot) * d.chunk_size - within;
  const std::byte* start = d.cache.get() + slot * d.chunk_size + within;
  v.first = {start, static_cast<std::size_t>(std::min(bytes, to_ring_end))};
  if (bytes > to_ring_end) v.second = {d.cache.get(), static_cast<std::size_t>(bytes - to_ring_end)};
  return v;
}

std::size_t ParticleStream::copy_frame(std::span<std::byte> out) const {
  const FrameView v = frame();
  if (out.size() < v.bytes()) {
    throw Error(
        fmt::format("{}: frame {} needs {} bytes, the buffer has {}", impl_->name, v.frame, v.bytes(), out.size()));
  }
  if (!v.first.empty()) std::memcpy(out.data(), v.first.data(), v.first.size());
  if (!v.second.empty()) std::memcpy(out.data() + v.first.size(), v.second.data(), v.second.size());
  return v.bytes();
}

DebugInfo ParticleStream::debug() const {
  const Impl& d = *impl_;
  DebugInfo info;
  std::lock_guard lock(d.mutex);
  std::copy(d.slots.begin(), d.slots.end(), d.slots_snapshot.begin());
  info.slots = d.slots_snapshot;
  info.loads_in_flight = d.in_flight;
  info.loads_done = d.loads_done;
  info.bytes_read = d.bytes_read;
  info.stalls = d.stalls;
  info.io_ms = double(d.io_ns) / 1e6;
  info.decode_ms = double(d.decode_ns) / 1e6;
  info.cache_bytes = d.cache_bytes;
  info.seeking = seeking_;
  if (d.current_valid && meta_.frame_count()) {
    info.read_offset = meta_.frames[d.current_frame].byte_offset;
    info.read_slot = d.slot_of(d.current_lap * d.range_chunks() + (first_chunk(meta_, d.current_frame) - d.c0));
  }
  return info;
}

}  // namespace pstream::stream
