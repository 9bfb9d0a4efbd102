// The chunk cache, the decoded-frame ring and their state machine (docs/streaming.md).
//
// Chunks are loaded in playback order. The k-th chunk of that order ("sequence number" k) maps
// to chunk c0 + k mod N of the playback range [c0, c1] (N chunks; laps repeat it when looping),
// and lives in slot (slot_base + k - seq_base) mod s. The slots holding sequence numbers
// [oldest, next) are Loading or Ready; all others are Empty. Because consecutive chunks sit in
// consecutive slots, a frame's packet is contiguous in the cache except across the ring's wrap.
//
// Frames are decoded in playback order by the producer, which runs on an IO worker: the frame
// codec needs each predicted frame's predecessor, so after a seek (and at each lap's start) it
// decodes from the keyframe at or before the first wanted frame, publishing only wanted frames.
// It consumes chunks (releasing those before the next frame's packet) and fills the decoded-frame
// ring; the host releases decoded frames it has passed and shows the target frame when it is
// ready, keeping the last complete one otherwise (a stall).
//
// Threads: update() (the host's thread) and the IO workers share the states under one mutex,
// held for a few hundred nanoseconds; a frame is decoded with the mutex released (its packet's
// chunk slots stay pinned, its frame slot marked Decoding). A seek bumps the epoch, so a decode
// that was under way is thrown away when it ends.
#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <new>

#include <fmt/format.h>

#include "particlestream/codec.hpp"
#include "particlestream/stream.hpp"
#include "stream/load_request.hpp"
#include "stream/playhead.hpp"

namespace pstream::stream {
namespace {

constexpr std::size_t kCacheAlignment = 4096;

struct AlignedDelete {
  void operator()(std::byte* p) const { ::operator delete[](p, std::align_val_t(kCacheAlignment)); }
};

std::unique_ptr<std::byte[], AlignedDelete> aligned_bytes(std::uint64_t n) {
  return std::unique_ptr<std::byte[], AlignedDelete>(
      static_cast<std::byte*>(::operator new[](std::max<std::uint64_t>(n, 1), std::align_val_t(kCacheAlignment))));
}

struct FrameSlot {
  enum State : std::uint8_t { Empty, Decoding, Ready };
  static constexpr std::uint64_t kHeld = UINT64_MAX;  // shown, but not a frame of the sequence
  State state = Empty;
  std::uint64_t seq = 0;  // lap × frame_count + frame, or kHeld
  // Runs pairing the frame's particles with the frame before it (format::MatchRun), or
  // kNoMatching; they lie in the slot's part of Impl::matching.
  std::size_t runs = format::kNoMatching;
  // The runs are those forward play gives the frame (false: the frame before was not decoded just
  // before it, so no matching by id could be made). Only such a frame outlives a restart.
  bool exact = true;
};

}  // namespace

std::size_t cache_slots(const format::Metadata& m, double seconds) {
  // A clip of empty frames has no chunks: one slot keeps the ring's arithmetic whole (it is never
  // loaded, and the cache behind it is empty).
  if (m.chunk_count() == 0) return 1;
  const double wanted = std::ceil(seconds * m.fps * double(m.max_count) / m.particles_per_chunk());
  // Every frame must fit: the most chunks any one frame's packet spans, read from the frame index.
  std::uint64_t frame_chunks = 1;
  for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
    const auto [first, last] = m.frame_chunks(f);
    frame_chunks = std::max(frame_chunks, last - first + 1);
  }
  std::uint64_t s = std::max<std::uint64_t>(2, static_cast<std::uint64_t>(std::max(wanted, 0.0)));
  s = std::min<std::uint64_t>(s, m.chunk_count());
  s = std::max<std::uint64_t>(s, frame_chunks);
  return static_cast<std::size_t>(s);
}

struct ParticleStream::Impl {
  const format::Metadata* meta = nullptr;
  std::unique_ptr<io::ByteSource> io;
  std::shared_ptr<IoScheduler> scheduler;
  std::shared_ptr<MemoryBudget> budget;
  std::string name;

  // The chunk ring.
  std::unique_ptr<std::byte[], AlignedDelete> cache;
  std::size_t slot_count = 0;
  std::uint64_t chunk_size = 0, cache_bytes = 0, decode_bytes = 0;
  std::vector<LoadRequest> requests;
  std::vector<std::unique_ptr<format::ChunkDecoder>> decoders;
  std::unique_ptr<std::byte[]> staging;  // one max-stored-size region per request
  std::uint64_t staging_each = 0;

  // The decoded-frame ring and the producer's own state (worker side, one producer at a time).
  std::unique_ptr<std::byte[], AlignedDelete> decoded;
  std::uint64_t frame_bytes = 0;
  std::vector<FrameSlot> frame_slots;
  std::unique_ptr<format::FrameDecoder> frame_decoder;
  std::unique_ptr<std::byte[]> packet_staging;  // a packet that wraps the ring, made contiguous
  LoadRequest produce_request;
  // With interpolation: per decoded slot, room for the runs matching its frame to the one before.
  std::unique_ptr<format::MatchRun[]> matching;
  std::size_t match_capacity = 0;
  // The slot the producer decoded its last frame into and that frame's sequence number (so the
  // next frame can be matched to it by id when the codec has no matching of its own).
  std::size_t p_prev_slot = SIZE_MAX;
  std::uint64_t p_prev_seq = 0;

  // Playback range in frames and the chunks covering it, from the range's first keyframe.
  std::uint64_t frame_begin = 0, frame_end = 0, preroll = 0, c0 = 0, c1 = 0;
  Playhead playhead;        // the host's clock (host thread)
  std::size_t current = 0;  // the frame slot shown
  std::uint64_t current_seq = 0;

  // Shared with the IO workers, under `mutex`.
  mutable std::mutex mutex;
  std::condition_variable loaded;  // a load or a decode finished (blocking mode, close)
  std::vector<SlotInfo> slots;
  mutable std::vector<SlotInfo> slots_snapshot;  // what debug() hands out
  std::uint64_t seq_base = 0, slot_base = 0, oldest = 0, next = 0;
  std::string failure;
  std::uint64_t loads_done = 0, bytes_read = 0, stalls = 0, frames_decoded = 0, wrapped_packets = 0;
  std::int64_t io_ns = 0, decode_ns = 0;
  std::uint32_t in_flight = 0;
  // The producer: the next frame to decode, and from which frame of its first lap to publish.
  std::uint64_t p_lap = 0, p_frame = 0, p_publish_from = 0, epoch = 0;
  // Playing backwards (the host's speed, under `mutex`): the producer decodes nothing after the
  // frame the host shows and the one after it (the host only goes back from there: decoding on
  // would only hold the decoder when the host restarts).
  bool p_backwards = false;
  bool p_resume = false;                    // a restart came while a decode ran: ask the decoder where to start
  std::uint64_t host_seq = 0;               // the frame the host wants now (lap × frame_count + frame)
  std::size_t pin_slot = 0, pin_count = 0;  // chunk slots a decode under way reads

  // Flags last, packed together.
  bool blocking = false, current_valid = false, interpolate = false;  // host thread
  bool loop = false, closing = false, failed = false;                 // under `mutex`
  bool producing = false, produce_again = false, produce_queued = false, producer_done = false;
  bool closed = false, abandoned = false;

  // The backend's word on a host that broke its contract (fault()): the stream fails with it.
  bool io_fault_locked() {
    if (failed) return true;
    std::string fault = io->fault();
    if (fault.empty()) return false;
    failed = true;
    failure = std::move(fault);
    loaded.notify_all();
    return true;
  }

  std::uint64_t range_chunks() const { return c1 - c0 + 1; }
  FrameView decoded_after(std::uint64_t ahead) const;
  // A Ready slot's runs are written before it became Ready and read only while it is held.
  void set_matching(std::size_t slot, FrameView& v) const {
    const std::size_t runs = frame_slots[slot].runs;
    v.matched = runs != format::kNoMatching;
    if (v.matched) v.matching = {matching.get() + slot * match_capacity, runs};
  }
  // The Ready decoded slot holding sequence number `seq`, or frame_slots.size().
  std::size_t ready_slot(std::uint64_t seq) const {
    for (std::size_t i = 0; i < frame_slots.size(); ++i) {
      if (frame_slots[i].state == FrameSlot::Ready && frame_slots[i].seq == seq) return i;
    }
    return frame_slots.size();
  }
  std::size_t slot_of(std::uint64_t seq) const { return (slot_base + (seq - seq_base)) % slot_count; }
  std::uint64_t frame_seq(std::uint64_t lap_, std::uint64_t frame) const { return lap_ * meta->frame_count() + frame; }
  // Chunk sequence numbers of frame f's packet in lap `lap_`.
  std::pair<std::uint64_t, std::uint64_t> packet_seqs(std::uint64_t lap_, std::uint64_t frame) const {
    const auto [first, last] = meta->frame_chunks(frame);
    return {lap_ * range_chunks() + (first - c0), lap_ * range_chunks() + (last - c0)};
  }

  // Starts loads in playback order into Empty slots, up to the allowed number in flight.
  void issue_locked() {
    if (closing || failed || meta->chunks.empty()) return;
    const std::uint64_t N = range_chunks();
    while (in_flight < requests.size() && next - oldest < slot_count) {
      if (!loop && next >= N) return;  // never past the last chunk unless looping
      const std::size_t slot = slot_of(next);
      // slot_of(next) lies outside [oldest, next), so a Ready chunk there belongs to no sequence:
      // one a restart kept for the decode under way then, which that decode's end could not free
      // (the slot was in the sequence at the time). Free it, unless a decode reads it now.
      const bool pinned = pin_count > 0 && (slot + slot_count - pin_slot) % slot_count < pin_count;
      if (slots[slot].state == SlotState::Ready && !pinned) slots[slot] = SlotInfo{};
      if (slots[slot].state != SlotState::Empty) return;  // still busy with a discarded load or decode
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

  // Asks a worker for a turn of decoding (when the host freed a decoded slot, say).
  void kick_locked() {
    if (produce_queued || producing || producer_done || closing || failed) return;
    produce_queued = true;
    ++in_flight;
    scheduler->submit(&produce_request);
  }

  // Decodes frames while their packets are in and a decoded slot is free.
  void produce_locked(std::unique_lock<std::mutex>& lock) {
    if (producing) {
      produce_again = true;
      return;
    }
    producing = true;
    do {
      produce_again = false;
      while (produce_one(lock)) {
      }
    } while (produce_again);
    producing = false;
  }

  bool produce_one(std::unique_lock<std::mutex>& lock) {
    if (closing || failed || producer_done || meta->frame_count() == 0) return false;
    if (p_resume) {  // the decoder is free now: start after its last frame or a saved state, if nearer
      p_resume = false;
      const std::uint64_t start = frame_decoder->resume_frame(p_publish_from);
      if (p_lap == 0 && start > p_frame) begin_at(start);
    }
    const std::uint64_t frame = p_frame, lap_ = p_lap;
    if (p_backwards && frame_seq(lap_, frame) > host_seq + 1) return false;
    // A frame a restart kept (restart_locked()): backwards, the frames from it on are held
    // already; forwards it is decoded again only when the next one is predicted from it.
    const std::size_t kept = ready_slot(frame_seq(lap_, frame));
    const bool held = kept != frame_slots.size();
    if (p_backwards && held) return false;
    if (held && (frame == frame_end || meta->frames[frame + 1].keyframe)) return move_on_locked(frame, lap_, kept);
    const format::FrameEntry& entry = meta->frames[frame];
    const auto [k_first, k_last] = packet_seqs(lap_, frame);
    if (entry.packet_size > 0) {
      if (k_first < oldest || k_last >= next) return false;
      for (std::uint64_t k = k_first; k <= k_last; ++k) {
        if (slots[slot_of(k)].state != SlotState::Ready) return false;
      }
    }
    // A free decoded slot: the frame lands there (and stays Empty when it is not published).
    // The one holding the frame decoded last is taken only when no other is free: the new frame
    // may be matched to it.
    std::size_t target = frame_slots.size(), empty = 0;
    for (std::size_t i = 0; i < frame_slots.size(); ++i) {
      if (frame_slots[i].state != FrameSlot::Empty) continue;
      ++empty;
      if (target == frame_slots.size() || target == p_prev_slot) target = i;
    }
    if (target == frame_slots.size()) return false;
    // Frames before the range, before a seek's target, or behind the frame the host waits for are
    // decoded only as references: nobody will show them. Backwards, the frames just before a
    // restart's target are kept too, as many as the free slots hold beside the frames still to
    // come (the target and the one after it, unless held): the host's next steps back find them.
    bool before_target = p_backwards && lap_ == 0 && frame < p_publish_from;
    if (before_target) {
      std::uint64_t wanted = p_publish_from - frame;  // this frame and those up to the target
      for (std::uint64_t f = p_publish_from; f <= std::min(host_seq + 1, frame_end); ++f)
        wanted += ready_slot(f) == frame_slots.size() ? 1 : 0;
      before_target = empty >= wanted;
    }
    const bool publish =
        !held && frame >= frame_begin &&
        (before_target || ((lap_ > 0 || frame >= p_publish_from) && frame_seq(lap_, frame) >= host_seq));
    frame_slots[target].state = FrameSlot::Decoding;
    const std::uint64_t my_epoch = epoch;
    pin_slot = slot_of(k_first);
    pin_count = entry.packet_size > 0 ? static_cast<std::size_t>(k_last - k_first + 1) : 0;
    // The packet: one span in the ring, or two across its wrap (then copied together).
    const std::uint64_t within = entry.packet_offset - meta->frame_chunks(frame).first * chunk_size;
    const std::uint64_t to_end = (slot_count - pin_slot) * chunk_size - within;
    const std::byte* start = cache.get() + pin_slot * chunk_size + within;
    const std::uint64_t size = entry.packet_size;
    if (size > to_end) ++wrapped_packets;
    // The frame decoded just before, when it is this one's predecessor and still in its slot.
    const bool after_prev = match_capacity > 0 && frame > 0 && p_prev_slot != target &&
                            p_prev_slot < frame_slots.size() && p_prev_seq + 1 == frame_seq(lap_, frame);
    const std::size_t prev_slot = p_prev_slot;
    // After a restart (a seek, a step back) the frames before the one wanted are decoded as
    // references: the decoder saves states among them, for the next step or seek back.
    const std::uint64_t towards = lap_ == 0 ? p_publish_from : format::FrameDecoder::kNoTarget;
    lock.unlock();
    const auto t0 = std::chrono::steady_clock::now();
    std::string error;
    std::size_t runs = format::kNoMatching;
    try {
      std::span<const std::byte> packet(start, size);
      if (size > to_end) {
        std::memcpy(packet_staging.get(), start, to_end);
        std::memcpy(packet_staging.get() + to_end, cache.get(), size - to_end);
        packet = {packet_staging.get(), size};
      }
      std::byte* out = decoded.get() + target * frame_bytes;
      const std::span<format::MatchRun> match(matching.get() + target * match_capacity, match_capacity);
      frame_decoder->set_target(towards);
      runs = frame_decoder->decode(frame, packet, {out, frame_bytes}, match);
      if (runs == format::kNoMatching && after_prev) {  // only the producer writes decoded slots
        runs = format::match_by_id(*meta, {decoded.get() + prev_slot * frame_bytes, frame_bytes},
                                   meta->frames[frame - 1].count, {out, frame_bytes}, entry.count, match);
      }
    } catch (const std::exception& e) {
      error = e.what();
    }
    const auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - t0).count();
    lock.lock();
    decode_ns += ns;
    ++frames_decoded;
    frame_slots[target].state = FrameSlot::Empty;
    if (my_epoch != epoch) {  // a seek: free what this decode held, start over where it says
      for (std::size_t i = 0; i < pin_count; ++i) {
        SlotInfo& slot = slots[(pin_slot + i) % slot_count];
        if (slot.state == SlotState::Ready && !in_sequence((pin_slot + i) % slot_count)) slot = SlotInfo{};
      }
      pin_count = 0;
      issue_locked();
      return true;
    }
    pin_count = 0;
    if (!error.empty()) {
      failed = true;
      failure = std::move(error);
      return false;
    }
    if (publish) {
      const bool exact = runs != format::kNoMatching || match_capacity == 0 || frame == 0 || after_prev;
      frame_slots[target] = {FrameSlot::Ready, frame_seq(lap_, frame), runs, exact};
    }
    // The next frame is matched to this one's records: those a restart kept, when the frame was
    // held (decoded again only as a reference, its slot stays free), or the slot it landed in.
    const std::size_t holding = ready_slot(frame_seq(lap_, frame));
    return move_on_locked(frame, lap_, holding < frame_slots.size() ? holding : target);
  }

  // The producer has `frame` of lap `lap_` in decoded slot `slot`: on to the next frame, giving
  // back the chunks before its packet.
  bool move_on_locked(std::uint64_t frame, std::uint64_t lap_, std::size_t slot) {
    p_prev_slot = slot;
    p_prev_seq = frame_seq(lap_, frame);
    if (frame < frame_end) {
      p_frame = frame + 1;
    } else if (loop) {
      p_frame = preroll;
      ++p_lap;
    } else {
      producer_done = true;
    }
    const std::uint64_t keep_from = producer_done ? next : packet_seqs(p_lap, p_frame).first;
    while (oldest < keep_from && oldest < next) {
      SlotInfo& slot = slots[slot_of(oldest)];
      if (slot.state == SlotState::Ready) slot = SlotInfo{};  // a Loading one frees on completion
      ++oldest;
    }
    if (next < keep_from) oldest = next = keep_from;
    issue_locked();
    loaded.notify_all();
    return true;
  }

  // Whether chunk slot `slot` holds a sequence number of the current [oldest, next).
  bool in_sequence(std::size_t slot) const {
    for (std::uint64_t k = oldest; k < next; ++k) {
      if (slot_of(k) == slot) return true;
    }
    return false;
  }

  // On the IO worker, after a load (or a decoding turn): Loading -> Ready (or Empty, or the
  // stream fails), the next load, and as many frames as can be decoded.
  static void on_done(void* owner, LoadRequest* r) {
    Impl& d = *static_cast<Impl*>(owner);
    std::unique_lock lock(d.mutex);
    const int st = r->status.load(std::memory_order_acquire);
    --d.in_flight;
    if (r->produce) {
      d.produce_queued = false;
    } else if (st == LoadRequest::Failed && !r->discard) {
      d.failed = true;
      d.failure = r->error;
      d.slots[r->slot] = SlotInfo{};
    } else if (r->discard || r->seq < d.oldest) {  // made useless by a seek
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
    d.produce_locked(lock);
    d.loaded.notify_all();
  }

  // Playback restarts at `frame` (a seek, or a jump ahead): decoding starts at its keyframe, or
  // nearer (begin_at()); the frames decoded before are dropped. A decode under way is thrown away
  // (the epoch changes) and keeps its chunk slots until it ends.
  void restart_locked(std::uint64_t frame) {
    ++epoch;
    // The frames decoded before are dropped, but the target and the one after it, which
    // playback needs next (a step back's target is the frame before the one shown): they are
    // renumbered into lap 0, and the producer takes them as decoded.
    const std::uint64_t n = meta->frame_count();
    for (FrameSlot& f : frame_slots) {
      if (f.state != FrameSlot::Ready) continue;
      const std::uint64_t at = f.seq == FrameSlot::kHeld ? FrameSlot::kHeld : f.seq % n;
      const bool needed = at != FrameSlot::kHeld && at >= frame && at <= std::min(frame + 1, frame_end);
      if (needed && f.exact) {
        f.seq = at;
      } else {
        f = FrameSlot{};
      }
    }
    p_publish_from = frame;
    p_backwards = playhead.speed < 0.0;
    p_prev_slot = SIZE_MAX;
    host_seq = frame;  // lap 0: what the host waits for (update() sets it again)
    producer_done = false;
    // The decoder says where to start (after the frame it decoded last, or after a state it saved,
    // when either is nearer than the keyframe), but it is the producer's while a decode runs: the
    // producer then asks it when it is free (p_resume).
    p_resume = producing;
    begin_at(producing ? format::keyframe_of(*meta, frame) : frame_decoder->resume_frame(frame));
    kick_locked();
  }

  // The producer decodes on from `start`, the chunk ring loading from its packet. Loads under way
  // free their slots when they end.
  void begin_at(std::uint64_t start) {
    std::size_t after = 0;
    for (LoadRequest& r : requests) {
      if (r.status.load(std::memory_order_acquire) != LoadRequest::Idle) {
        r.discard = true;
        if (!r.produce) io->cancel(&r);     // a remote read may end now (it then completes as failed)
        after = (r.slot + 1) % slot_count;  // restart the ring after it, so it is reused last
      }
    }
    for (std::size_t i = 0; i < slot_count; ++i) {
      const bool pinned = pin_count > 0 && (i + slot_count - pin_slot) % slot_count < pin_count;
      if (slots[i].state == SlotState::Ready && !pinned) slots[i] = SlotInfo{};
    }
    seq_base = oldest = next = meta->frame_chunks(start).first - c0;
    slot_base = after;
    p_lap = 0;
    p_frame = start;
    issue_locked();
  }

  // restart_locked(), with the frame on screen (if any) still shown, as sequence number
  // `shown_seq`, until the target is decoded.
  void restart_keeping_shown(std::uint64_t frame, std::uint64_t shown_seq) {
    FrameSlot shown = frame_slots[current];
    restart_locked(frame);
    if (!current_valid || frame_slots[current].state == FrameSlot::Ready) return;  // kept
    shown.seq = shown_seq;
    frame_slots[current] = shown;
  }
};

std::unique_ptr<ParticleStream> ParticleStream::open(const std::filesystem::path& path, StreamOptions options) {
  std::unique_ptr<ParticleStream> s(new ParticleStream());
  auto impl = std::make_unique<Impl>();
  impl->io = options.io ? std::move(options.io) : io::open(path.string());
  impl->name = impl->io->name();
  s->meta_ = format::read_metadata(*impl->io);
  const format::Metadata& m = s->meta_;
  impl->meta = &s->meta_;

  impl->blocking = options.blocking;
  impl->interpolate = options.interpolate;
  impl->scheduler = options.scheduler ? options.scheduler : IoScheduler::shared_default();
  impl->chunk_size = m.chunk_size;
  const unsigned loads = std::max(1u, options.max_loads_in_flight ? options.max_loads_in_flight
                                                                  : impl->io->preferred_reads_in_flight(m.chunk_size));
  // A source with reads in flight (HTTP) sizes the look-ahead from what its open measured: at
  // least 4 round trips of playback, and a slot for every load in flight plus two (the chunk
  // being read and one ready). Fixed at open, like every other buffer.
  double seconds = options.cache_seconds;
  std::size_t least = 0;
  if (loads > 1) {
    seconds = std::max(seconds, 4.0 * impl->io->stats().latency_ms / 1000.0);
    least = std::min<std::size_t>(loads + 2, m.chunk_count());
  }
  std::size_t slots = std::max(cache_slots(m, seconds), least);
  if (options.min_slots) slots = std::max(slots, std::min<std::size_t>(options.min_slots, m.chunk_count()));
  if (options.max_slots) {
    const std::size_t floor = cache_slots(m, 0.0);  // what a largest frame needs
    slots = std::max(floor, std::min(slots, options.max_slots));
  }
  impl->slot_count = slots;
  impl->cache_bytes = m.chunk_count() ? slots * m.chunk_size : 0;
  // The decoding side: the ring of decoded frames, the frame decoder's state, a packet's staging.
  // Interpolating holds two frames and decodes ahead: at least three.
  const std::size_t frame_slots = std::max<std::size_t>(options.interpolate ? 3 : 2, options.decoded_frames);
  impl->frame_bytes = (m.max_count * m.record_size + 63) / 64 * 64;
  std::uint64_t max_packet = 0;
  for (std::uint64_t f = 0; f < m.frame_count(); ++f) max_packet = std::max(max_packet, m.frames[f].packet_size);
  // Interpolating, each decoded frame also keeps how its particles continue the frame before: room
  // for runs of one particle in eight changing (more than that: the pair is not matched).
  impl->match_capacity = options.interpolate ? std::size_t(m.max_count / 8 + 64) : 0;
  // The decoded frames with their matching, and a packet's staging: the decoding side but the
  // decoder's own state.
  const std::uint64_t ring_bytes =
      frame_slots * (impl->frame_bytes + impl->match_capacity * sizeof(format::MatchRun)) + max_packet;
  // The decoder's saved states for going back, as many of those asked for as the memory allows
  // beside everything else (the budget's room, or what the clip's stored bytes justify).
  const std::size_t saved_states = format::FrameDecoder::saved_states_that_fit(
      m, options.saved_states, options.budget ? options.budget->total() : format::unbudgeted_memory_limit(m),
      ring_bytes + (options.budget ? impl->cache_bytes + options.budget->used() : 0));
  impl->frame_decoder = std::make_unique<format::FrameDecoder>(
      s->meta_, impl->name, options.budget ? options.budget->total() : 0, saved_states);
  const std::uint64_t decode_bytes = ring_bytes + impl->frame_decoder->state_bytes();
  const std::uint64_t total_bytes = impl->cache_bytes + decode_bytes;
  // Without the host's budget, the decoded side is held to what the clip's stored bytes justify.
  if (!options.budget && decode_bytes > format::unbudgeted_memory_limit(m)) {
    throw OptionError("budget", fmt::format("{}: max_count {} particles needs {} decoded frames and decoding state of "
                                            "{:.1f} MiB, more than the clip's stored bytes justify ({:.1f} MiB); set "
                                            "a memory `budget` to allow it",
                                            impl->name, m.max_count, frame_slots, decode_bytes / 1048576.0,
                                            format::unbudgeted_memory_limit(m) / 1048576.0));
  }
  if (options.budget && !options.budget->try_reserve(total_bytes)) {
    throw OptionError("budget", fmt::format("{}: its cache of {} slots x {} KiB plus {} decoded frames and decoding "
                                            "state, {:.1f} MiB in all, does not fit "
                                            "the memory budget ({:.1f} of {:.1f} MiB used)",
                                            impl->name, slots, m.chunk_size >> 10, frame_slots, total_bytes / 1048576.0,
                                            options.budget->used() / 1048576.0, options.budget->total() / 1048576.0));
  }
  impl->decode_bytes = decode_bytes;
  impl->budget = options.budget;
  // The cache: one allocation of s x chunk_size bytes, one for the decoded frames, made here and
  // never again.
  impl->cache = aligned_bytes(impl->cache_bytes);
  impl->decoded = aligned_bytes(frame_slots * impl->frame_bytes);
  impl->matching.reset(new format::MatchRun[std::max<std::size_t>(frame_slots * impl->match_capacity, 1)]);
  impl->frame_slots.assign(frame_slots, FrameSlot{});
  impl->packet_staging.reset(new std::byte[std::max<std::uint64_t>(max_packet, 1)]);
  impl->slots.assign(slots, SlotInfo{});
  impl->slots_snapshot.assign(slots, SlotInfo{});
  impl->requests = std::vector<LoadRequest>(loads);
  for (unsigned i = 0; i < loads; ++i) impl->decoders.push_back(std::make_unique<format::ChunkDecoder>());
  std::uint64_t max_stored = 0;
  for (const auto& c : m.chunks) {
    if (c.codec != format::Codec::Raw) max_stored = std::max(max_stored, c.stored_size);
  }
  impl->staging_each = max_stored;
  impl->staging.reset(new std::byte[std::max<std::uint64_t>(max_stored * loads, 1)]);
  impl->produce_request.produce = true;
  impl->produce_request.on_done = &Impl::on_done;
  impl->produce_request.owner = impl.get();
  impl->scheduler->reserve(loads + 1);

  s->impl_ = std::move(impl);
  s->set_range(m.frame_count() ? m.frames.front().time : 0.0, m.frame_count() ? m.frames.back().time : 0.0);
  s->update(0.0);  // start loading
  return s;
}

ParticleStream::~ParticleStream() {
  close();
  // A read the host never completed may still write into the cache and call back into the
  // backend: both stay allocated (io::ByteSource::abandon()).
  if (impl_ && impl_->abandoned) (void)impl_.release();
}

void ParticleStream::close() {
  if (!impl_ || impl_->closed) return;
  Impl& d = *impl_;
  {
    std::unique_lock lock(d.mutex);
    d.closing = true;  // no new loads or decodes; wait for those under way, which write into the cache
    // Until they end, or until the backend says a host's completion is overdue (then it is
    // abandoned: close never hangs on a host that forgot a completion).
    while (!d.loaded.wait_for(lock, std::chrono::milliseconds(50), [&] { return d.in_flight == 0 && !d.producing; })) {
      if (!d.producing && !d.io->fault().empty()) {
        d.io->abandon();
        d.abandoned = true;
        break;
      }
    }
  }
  d.scheduler->release(d.requests.size() + 1);
  if (d.budget) d.budget->release(d.cache_bytes + d.decode_bytes);
  d.closed = true;
}

const std::string& ParticleStream::name() const { return impl_->name; }

void ParticleStream::play() {
  if (state_ == PlayState::Error) return;
  state_ = PlayState::Playing;
  impl_->playhead.playing = true;
}

void ParticleStream::pause() {
  if (state_ == PlayState::Error) return;
  state_ = PlayState::Paused;
  impl_->playhead.playing = false;
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
    if (loop) impl_->producer_done = false;
    impl_->kick_locked();
  }
  if (!loop && impl_->playhead.lap > 0) seek(impl_->playhead.time);  // renumber the chunk sequence from lap 0
}

void ParticleStream::set_speed(double speed) { impl_->playhead.speed = std::isfinite(speed) ? speed : 0.0; }
double ParticleStream::time() const { return impl_->playhead.time; }
double ParticleStream::fraction() const { return impl_->playhead.fraction; }

void ParticleStream::set_range(double start, double end) {
  Impl& d = *impl_;
  if (meta_.frame_count() == 0) return;
  {
    std::lock_guard lock(d.mutex);  // the IO worker reads c0/c1 when it chains loads
    d.frame_begin = meta_.frame_at(std::min(start, end));
    d.frame_end = meta_.frame_at(std::max(start, end));
    d.preroll = format::keyframe_of(meta_, d.frame_begin);
    d.c0 = meta_.frame_chunks(d.preroll).first;
    d.c1 = std::max(d.c0, meta_.frame_chunks(d.frame_end).second);
  }
  seek(std::clamp(d.playhead.time, meta_.frames[d.frame_begin].time, meta_.frames[d.frame_end].time));
}

void ParticleStream::seek(double time) {
  Impl& d = *impl_;
  if (state_ == PlayState::Error || meta_.frame_count() == 0) {
    d.playhead.time = time;
    return;
  }
  d.playhead.time = std::clamp(time, meta_.frames[d.frame_begin].time, meta_.frames[d.frame_end].time);
  d.playhead.lap = 0;
  // The frame update() will want: between two frames, interpolating, the one before.
  const std::uint64_t frame = d.playhead.target(meta_, d.frame_begin, d.frame_end, d.interpolate);
  std::lock_guard lock(d.mutex);
  d.restart_locked(frame);
  seeking_ = true;
  d.current_valid = false;
}

void ParticleStream::update(double dt) {
  if (!impl_ || impl_->closed || state_ == PlayState::Error) return;
  Impl& d = *impl_;
  const format::Metadata& m = meta_;
  if (m.frame_count() == 0) {  // nothing to play
    seeking_ = false;
    return;
  }

  // 1. Advance time on the host's clock, and pick the frame to hold.
  if (!d.playhead.advance(m, d.frame_begin, d.frame_end, d.loop, dt)) state_ = PlayState::Paused;
  const std::uint64_t target = d.playhead.target(m, d.frame_begin, d.frame_end, d.interpolate);
  std::uint64_t target_seq = d.frame_seq(d.playhead.lap, target);

  std::unique_lock lock(d.mutex);
  const auto failed = [&] {  // the IO worker reported a fault: the stream stops, the host goes on
    if (!d.failed) return false;
    state_ = PlayState::Error;
    error_ = d.failure;
    d.playhead.playing = false;
    d.current_valid = false;
    return true;
  };
  d.io_fault_locked();
  if (failed()) return;
  d.host_seq = target_seq;
  if (const bool backwards = d.playhead.speed < 0.0; backwards != d.p_backwards) {
    d.p_backwards = backwards;
    d.kick_locked();  // forwards again: decoding ahead resumes
  }
  // Backwards (reverse speed, or a host clock that went back): the producer only decodes forwards,
  // so once the playhead is before everything it holds, decoding restarts at the target, from its
  // keyframe or a state the decoder saved on the way; the target and the frame after it stay when
  // they are decoded already (restart_locked()). The frame shown stays shown until the target is
  // decoded.
  {
    // The producer will not bring the target: it has decoded past it, or it decodes it only as a
    // reference (before where a restart asked it to publish from).
    const bool passed = d.frame_seq(d.p_lap, d.p_frame) > target_seq ||
                        (d.p_lap == 0 && d.playhead.lap == 0 && target < d.p_publish_from);
    if (passed && d.ready_slot(target_seq) == d.frame_slots.size()) {
      d.playhead.lap = 0;  // sequence numbers restart with the decoding
      target_seq = target;
      d.current_seq %= m.frame_count();
      // Held for display only: a sequence number no lookup matches (the frame is decoded again
      // after its predecessor, matched to it).
      d.restart_keeping_shown(target, FrameSlot::kHeld);
    }
  }
  // 2. Release decoded frames playback has passed (the current one stays until a newer one is
  // shown): backwards, those after the target's successor. When the producer is so far behind
  // that a keyframe lies between it and the target, it jumps there: the frames in between need
  // not be decoded.
  const bool backwards = d.playhead.speed < 0.0;
  for (std::size_t i = 0; i < d.frame_slots.size(); ++i) {
    FrameSlot& f = d.frame_slots[i];
    const bool passed = backwards ? f.seq > target_seq + 1 : f.seq < target_seq;
    if (f.state == FrameSlot::Ready && passed && !(d.current_valid && i == d.current)) f = FrameSlot{};
  }
  const std::uint64_t producer_seq = d.frame_seq(d.p_lap, d.p_frame);
  const std::uint64_t target_key = format::keyframe_of(m, target);
  if (!d.producer_done && producer_seq < d.frame_seq(d.playhead.lap, target_key) && target_key > d.frame_begin &&
      d.packet_seqs(d.playhead.lap, target_key).first >= d.next) {
    const std::uint64_t lap = d.playhead.lap;
    d.restart_keeping_shown(target, d.current_seq);
    d.p_lap = lap;  // the same lap: chunk sequence numbers and frames stay in step
    d.seq_base = d.oldest = d.next = d.packet_seqs(lap, d.p_frame).first;
    d.issue_locked();
  }
  // 3. Keep the IO worker busy (it also chains loads and decodes by itself as each one completes).
  d.issue_locked();
  d.kick_locked();
  // 4. Blocking mode (offline rendering): wait for the frame instead of stalling.
  if (d.blocking) {
    const bool want_next = d.playhead.fraction > 0.0;  // interpolating: the next frame too
    const auto ready_or_failed = [&] {
      return d.failed || d.producer_done ||
             (d.ready_slot(target_seq) < d.frame_slots.size() &&
              (!want_next || d.ready_slot(target_seq + 1) < d.frame_slots.size()));
    };
    while (!d.loaded.wait_for(lock, std::chrono::milliseconds(50), ready_or_failed)) d.io_fault_locked();
    if (failed()) return;
  }
  const std::size_t ready = d.ready_slot(target_seq);
  if (ready < d.frame_slots.size()) {
    const std::uint64_t shown = d.frame_slots[d.current].seq;
    if (d.current_valid && d.current != ready && (shown < target_seq || shown == FrameSlot::kHeld))
      d.frame_slots[d.current] = FrameSlot{};
    d.current_valid = true;
    d.current = ready;
    d.current_seq = target_seq;
    seeking_ = false;
    d.kick_locked();  // a slot may have been freed
  } else if (d.current_valid && !seeking_ && target_seq != d.current_seq) {
    ++d.stalls;  // the last complete frame stays current; playback catches up when data arrives
  }
}

FrameView ParticleStream::frame() const {
  FrameView v;
  const Impl& d = *impl_;
  if (!d.current_valid || state_ == PlayState::Error) return v;
  const std::uint64_t frame = d.current_seq % meta_.frame_count();
  const auto& f = meta_.frames[frame];
  v.frame = frame;
  v.count = f.count;
  v.time = f.time;
  v.valid = true;
  // The decoded slot is Ready and held: only the host thread releases it.
  v.first = {d.decoded.get() + d.current * d.frame_bytes, static_cast<std::size_t>(f.count * meta_.record_size)};
  d.set_matching(d.current, v);
  return v;
}

// The decoded frame `ahead` frames after the current one, when it is Ready (a Ready slot is only
// released by the host thread, so the view stays valid until the host's next update()).
FrameView ParticleStream::Impl::decoded_after(std::uint64_t ahead) const {
  const format::Metadata& m = *meta;
  FrameView v;
  for (std::uint64_t k = 1; k <= ahead; ++k) {
    if ((current_seq + k) % m.frame_count() == 0) return v;  // across a loop's end: not interpolated
  }
  const std::uint64_t seq = current_seq + ahead;
  const std::size_t slot = [&] {
    std::lock_guard lock(mutex);
    return ready_slot(seq);
  }();
  if (slot == frame_slots.size()) return v;  // still being decoded: the caller shows the current frame
  const std::uint64_t frame = seq % m.frame_count();
  const auto& f = m.frames[frame];
  v.frame = frame;
  v.count = f.count;
  v.time = f.time;
  v.valid = true;
  v.first = {decoded.get() + slot * frame_bytes, static_cast<std::size_t>(f.count * m.record_size)};
  set_matching(slot, v);
  return v;
}

FrameView ParticleStream::next_frame() const {
  const Impl& d = *impl_;
  if (!d.current_valid || state_ == PlayState::Error || d.playhead.fraction <= 0.0) return {};
  return d.decoded_after(1);
}

FrameView ParticleStream::frame_after_next() const {
  const Impl& d = *impl_;
  if (!d.current_valid || state_ == PlayState::Error || d.playhead.fraction <= 0.0) return {};
  return d.decoded_after(2);
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
  info.source = d.io->stats();  // the source's own lock, never under the stream's
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
  info.decode_bytes = d.decode_bytes;
  info.wrapped_packets = d.wrapped_packets;
  info.seeking = seeking_;
  info.frames_decoded = d.frames_decoded;
  info.decoded_slots = d.frame_slots.size();
  for (const FrameSlot& f : d.frame_slots) info.decoded_ready += f.state == FrameSlot::Ready ? 1 : 0;
  if (meta_.frame_count()) {
    info.decode_frame = d.p_frame;
    info.read_offset = meta_.frames[d.p_frame].packet_offset;
    if (d.slot_count) info.read_slot = d.slot_of(d.packet_seqs(d.p_lap, d.p_frame).first);
  }
  return info;
}

}  // namespace pstream::stream
