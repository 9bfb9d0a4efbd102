// The chunk cache and its state machine (docs/streaming.md).
//
// Chunks are loaded in playback order. The k-th chunk of that order ("sequence number" k) maps
// to chunk c0 + k mod N of the playback range [c0, c1] (N chunks; laps repeat it when looping),
// and lives in slot (slot_base + k - seq_base) mod s. The slots holding sequence numbers
// [oldest, next) are Loading or Ready; all others are Empty. Because consecutive chunks sit in
// consecutive slots, a frame is contiguous in the cache except across the ring's wrap.
#include <algorithm>
#include <cmath>
#include <cstring>
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

}  // namespace

std::size_t cache_slots(const format::Metadata& m, double seconds) {
  if (m.chunk_count() == 0) return 0;
  const double wanted = std::ceil(seconds * m.fps * double(m.max_count) / m.particles_per_chunk());
  // A largest frame may start anywhere in a chunk: it spans up to ceil(bytes / chunk) + 1 chunks.
  const std::uint64_t frame_bytes = m.max_count * m.record_size;
  const std::uint64_t frame_chunks = (frame_bytes + m.chunk_size - 1) / m.chunk_size + 1;
  std::uint64_t s = std::max<std::uint64_t>(2, static_cast<std::uint64_t>(std::max(wanted, 0.0)));
  s = std::min<std::uint64_t>(s, m.chunk_count());
  s = std::max<std::uint64_t>(s, std::min<std::uint64_t>(frame_chunks + 1, m.chunk_count()));
  return static_cast<std::size_t>(s);
}

struct ParticleStream::Impl {
  std::unique_ptr<IoBackend> io;
  std::shared_ptr<IoScheduler> scheduler;
  std::shared_ptr<MemoryBudget> budget;
  bool blocking = false;
  std::string name;

  std::unique_ptr<std::byte[], AlignedDelete> cache;
  std::size_t slot_count = 0;
  std::uint64_t chunk_size = 0, cache_bytes = 0;
  std::vector<SlotInfo> slots;
  std::vector<std::uint64_t> slot_seq;

  std::vector<LoadRequest> requests;
  std::vector<std::unique_ptr<format::ChunkDecoder>> decoders;
  std::unique_ptr<std::byte[]> staging;  // one max-stored-size region per request
  std::uint64_t staging_each = 0;
  std::uint32_t in_flight = 0;

  // Playback range in frames and the chunks covering it.
  std::uint64_t frame_begin = 0, frame_end = 0, c0 = 0, c1 = 0;
  bool loop = false, playing = false;
  double speed = 1.0;
  // Sequence bookkeeping.
  std::uint64_t seq_base = 0, slot_base = 0, oldest = 0, next = 0;
  std::uint64_t lap = 0;  // of the current playback time
  // The current (last complete) frame.
  bool current_valid = false;
  std::uint64_t current_frame = 0, current_lap = 0;
  // Statistics.
  std::uint64_t loads_done = 0, bytes_read = 0, stalls = 0;
  std::int64_t io_ns = 0, decode_ns = 0;
  bool closed = false;

  std::uint64_t range_chunks() const { return c1 - c0 + 1; }
  std::size_t slot_of(std::uint64_t seq) const { return (slot_base + (seq - seq_base)) % slot_count; }
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
    throw Error(fmt::format("{}: its cache of {} slots x {} KiB = {:.1f} MiB does not fit the memory budget ({:.1f} of {:.1f} "
                            "MiB used)", impl->name, slots, m.chunk_size >> 10, impl->cache_bytes / 1048576.0,
                            options.budget->used() / 1048576.0, options.budget->total() / 1048576.0));
  }
  impl->budget = options.budget;
  // The cache: one allocation of s x chunk_size bytes, made here and never again.
  impl->cache.reset(static_cast<std::byte*>(::operator new[](std::max<std::uint64_t>(impl->cache_bytes, 1),
                                                             std::align_val_t(kCacheAlignment))));
  impl->slots.assign(slots, SlotInfo{});
  impl->slot_seq.assign(slots, 0);
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
  for (LoadRequest& r : impl_->requests) {
    int st = r.status.load(std::memory_order_acquire);
    while (st == LoadRequest::Pending) {  // a worker may still be writing into the cache
      r.status.wait(st);
      st = r.status.load(std::memory_order_acquire);
    }
  }
  impl_->scheduler->release(impl_->requests.size());
  if (impl_->budget) impl_->budget->release(impl_->cache_bytes);
  impl_->closed = true;
}

namespace {

std::uint64_t first_chunk(const format::Metadata& m, std::uint64_t frame) {
  return std::min(m.frames[frame].byte_offset / m.chunk_size, m.chunk_count() ? m.chunk_count() - 1 : 0);
}

std::uint64_t last_chunk(const format::Metadata& m, std::uint64_t frame) {
  const auto& f = m.frames[frame];
  if (f.count == 0) return first_chunk(m, frame);
  return (f.byte_offset + f.count * m.record_size - 1) / m.chunk_size;
}

}  // namespace

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
  impl_->loop = loop;
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
  d.frame_begin = to_frame(std::min(start, end));
  d.frame_end = to_frame(std::max(start, end));
  d.c0 = first_chunk(meta_, d.frame_begin);
  d.c1 = std::max(d.c0, last_chunk(meta_, d.frame_end));
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
  // Drop the cache. Loads not yet polled (in flight or just finished) free their slots when
  // update() sees them complete.
  for (LoadRequest& r : d.requests) {
    if (r.status.load(std::memory_order_acquire) != LoadRequest::Idle) r.discard = true;
  }
  for (std::size_t i = 0; i < d.slot_count; ++i) {
    if (d.slots[i].state == SlotState::Ready) d.slots[i] = SlotInfo{};
  }
  const std::uint64_t frame = static_cast<std::uint64_t>(std::clamp(
      std::round((time_ - meta_.time_of_frame0) * meta_.fps), double(d.frame_begin), double(d.frame_end)));
  const std::uint64_t seq = first_chunk(meta_, frame) - d.c0;
  // Restart the ring after the slot of any load still in flight, so it is reused last.
  std::size_t after = 0;
  for (const LoadRequest& r : d.requests) {
    if (r.status.load(std::memory_order_acquire) != LoadRequest::Idle) after = (r.slot + 1) % d.slot_count;
  }
  d.seq_base = d.oldest = d.next = seq;
  d.slot_base = after;
  seeking_ = true;
  d.current_valid = false;
}

void ParticleStream::update(double dt) {
  if (!impl_ || impl_->closed || state_ == PlayState::Error) return;
  Impl& d = *impl_;
  const format::Metadata& m = meta_;
  const std::uint64_t N = d.range_chunks();

  const auto frame_of = [&](double t) {
    return static_cast<std::uint64_t>(std::clamp(std::round((t - m.time_of_frame0) * m.fps), double(d.frame_begin),
                                                 double(d.frame_end)));
  };
  const auto seq_range = [&](std::uint64_t lap, std::uint64_t frame) {
    return std::pair{lap * N + (first_chunk(m, frame) - d.c0), lap * N + (last_chunk(m, frame) - d.c0)};
  };
  // 1. Completions: Loading slots whose IO finished become Ready (or the stream fails).
  const auto poll = [&] {
    for (LoadRequest& r : d.requests) {
      const int st = r.status.load(std::memory_order_acquire);
      if (st != LoadRequest::Done && st != LoadRequest::Failed) continue;
      r.status.store(LoadRequest::Idle, std::memory_order_relaxed);
      --d.in_flight;
      if (st == LoadRequest::Failed && !r.discard) {
        state_ = PlayState::Error;
        d.playing = false;
        error_ = r.error;
        return false;
      }
      if (r.discard || r.seq < d.oldest) {  // made useless by a seek or a jump ahead
        d.slots[r.slot] = SlotInfo{};
      } else {
        d.slots[r.slot].state = SlotState::Ready;
        ++d.loads_done;
        d.bytes_read += r.entry.stored_size;
        d.io_ns += r.io_ns;
        d.decode_ns += r.decode_ns;
      }
      r.discard = false;
    }
    return true;
  };
  if (m.frame_count() == 0 || m.chunk_count() == 0) {  // nothing to load: every frame is empty
    seeking_ = false;
    d.current_valid = m.frame_count() > 0;
    d.current_frame = m.frame_count() ? frame_of(time_) : 0;
    return;
  }
  if (!poll()) return;

  // 2. Advance time on the host's clock.
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
  const auto [need_first, need_last] = seq_range(d.lap, target);

  const auto ready = [&] {
    if (m.frames[target].count == 0) return true;
    if (need_first < d.oldest || need_last >= d.next) return false;
    for (std::uint64_t k = need_first; k <= need_last; ++k) {
      if (d.slots[d.slot_of(k)].state != SlotState::Ready) return false;
    }
    return true;
  };
  // 3. Release what playback has passed; skip chunks no shown frame needs.
  const auto release_before = [&](std::uint64_t seq) {
    while (d.oldest < seq && d.oldest < d.next) {
      SlotInfo& slot = d.slots[d.slot_of(d.oldest)];
      if (slot.state == SlotState::Ready) slot = SlotInfo{};  // a Loading one frees on completion
      ++d.oldest;
    }
    if (d.next < seq) d.oldest = d.next = seq;
  };
  // The current frame is handed out until a newer one is complete, so its chunks stay held —
  // unless it and the target cannot both fit in the ring (a long stall): then it is dropped.
  std::uint64_t hold_from = need_first;
  if (d.current_valid) {
    const std::uint64_t current_first = seq_range(d.current_lap, d.current_frame).first;
    if (current_first < need_first && need_last >= current_first + d.slot_count) {
      d.current_valid = false;
    } else {
      hold_from = std::min(current_first, need_first);
    }
  }
  release_before(hold_from);
  // 4. Issue loads in playback order into Empty slots, up to the allowed number in flight.
  const auto issue = [&] {
    const unsigned max_loads = static_cast<unsigned>(d.requests.size());
    while (d.in_flight < max_loads && d.next - d.oldest < d.slot_count) {
      if (!d.loop && d.next >= N) break;  // never past the last chunk unless looping
      const std::size_t slot = d.slot_of(d.next);
      if (d.slots[slot].state != SlotState::Empty) break;  // still busy with a discarded load
      LoadRequest* r = nullptr;
      for (LoadRequest& candidate : d.requests) {
        if (candidate.status.load(std::memory_order_relaxed) == LoadRequest::Idle) {
          r = &candidate;
          break;
        }
      }
      if (r == nullptr) break;
      const std::uint64_t chunk = d.c0 + d.next % N;
      const std::size_t index = static_cast<std::size_t>(r - d.requests.data());
      r->io = d.io.get();
      r->decoder = d.decoders[index].get();
      r->entry = m.chunks[chunk];
      r->chunk = chunk;
      r->destination = {d.cache.get() + slot * d.chunk_size, m.chunk_raw_size(chunk)};
      r->staging = {d.staging.get() + index * d.staging_each, d.staging_each};
      r->slot = slot;
      r->seq = d.next;
      r->discard = false;
      d.slots[slot] = SlotInfo{SlotState::Loading, static_cast<std::int64_t>(chunk)};
      d.slot_seq[slot] = d.next;
      ++d.next;
      ++d.in_flight;
      d.scheduler->submit(r);
    }
  };
  issue();

  // 5. Blocking mode (offline rendering): wait for the frame instead of stalling.
  if (d.blocking) {
    while (!ready()) {
      LoadRequest* waiting = nullptr;
      for (LoadRequest& r : d.requests) {
        if (r.status.load(std::memory_order_acquire) != LoadRequest::Idle) waiting = &r;
      }
      if (waiting == nullptr) break;  // nothing in flight and nothing issuable: cannot happen
      waiting->status.wait(LoadRequest::Pending);  // returns at once if it already finished
      if (!poll()) return;
      issue();
    }
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
    throw Error(fmt::format("{}: frame {} needs {} bytes, the buffer has {}", impl_->name, v.frame, v.bytes(), out.size()));
  }
  if (!v.first.empty()) std::memcpy(out.data(), v.first.data(), v.first.size());
  if (!v.second.empty()) std::memcpy(out.data() + v.first.size(), v.second.data(), v.second.size());
  return v.bytes();
}

DebugInfo ParticleStream::debug() const {
  const Impl& d = *impl_;
  DebugInfo info;
  info.slots = d.slots;
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
