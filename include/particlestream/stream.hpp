// Playing back a .pstream with fixed memory: a ring of chunk-sized cache slots holding the file's
// stored bytes (compressed packets with the particle codec), fed by IO workers (at most a set
// number of loads in flight); frames decoded in playback order on the IO worker into a small ring
// of decoded frames (which also carries the codec's reference frames); advanced once per host
// frame by update(dt), handing out the current frame as a span into that ring. After open,
// playback allocates nothing, and the caller's thread never waits on disk or decoding (unless
// blocking mode is asked for, for offline rendering).
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "particlestream/codec.hpp"
#include "particlestream/format.hpp"
#include "particlestream/io.hpp"

namespace pstream::stream {

// ---- IO ----------------------------------------------------------------------------------

// Chunk bytes come from an io::ByteSource (particlestream/io.hpp): a local file, the host's
// callbacks, or an http(s):// URL. Chunk loads use its start_read() when it offers one (no worker
// waits for the read; verifying and decoding run as a new job after the completion); the two
// reads of the header and tables at open use read().

class IoScheduler;
struct LoadRequest;

// IO worker threads shared by streams: at most `workers` loads in flight across all of them
// (one per device, as in the seed design). Or no threads of its own: each load (read, verify,
// decode) and each frame-decoding turn is handed to the host's job system as a job, `run(job)`.
class IoScheduler {
 public:
  explicit IoScheduler(unsigned workers = 1);
  // `submit` is called with a stream's lock held: it must queue the job and return, never run
  // it there; the job may run on any thread, and every job must run (closing a stream waits for
  // its jobs).
  using HostSubmit = std::function<void(void (*run)(void* job), void* job)>;
  explicit IoScheduler(HostSubmit submit);
  ~IoScheduler();
  IoScheduler(const IoScheduler&) = delete;
  IoScheduler& operator=(const IoScheduler&) = delete;
  static std::shared_ptr<IoScheduler> shared_default();

  // Streams reserve queue room for their own loads at open (so submitting never allocates).
  void reserve(std::size_t requests);
  void release(std::size_t requests);
  void submit(LoadRequest* request);
  unsigned workers() const { return static_cast<unsigned>(threads_.size()); }
  // The completion a ByteSource's start_read() calls (context: the load): the load goes on as a
  // new job.
  static void read_done(void* request, int status);

 private:
  void run();
  static void run_job(void* request);
  struct Queue;
  std::unique_ptr<Queue> queue_;
  std::vector<std::thread> threads_;
  HostSubmit host_;
};

// Memory that several streams' caches must fit in together.
class MemoryBudget {
 public:
  explicit MemoryBudget(std::uint64_t bytes) : total_(bytes) {}
  std::uint64_t total() const { return total_; }
  std::uint64_t used() const { return used_.load(); }
  bool try_reserve(std::uint64_t bytes);
  void release(std::uint64_t bytes) { used_.fetch_sub(bytes); }

 private:
  std::uint64_t total_;
  std::atomic<std::uint64_t> used_{0};
};

// ---- Cache sizing ----------------------------------------------------------------------------

// s = ceil(t * fps * T / p) slots: t seconds held, T the largest frame, p particles per chunk
// (chunk_size over the stored bytes per particle, so a compressed clip holds more seconds in the
// same memory); clamped to [2, chunk_count], and never fewer than the most chunks one frame's
// packet spans.
std::size_t cache_slots(const format::Metadata& meta, double seconds);

// ---- The stream ----------------------------------------------------------------------------

enum class SlotState : std::uint8_t { Empty, Loading, Ready };
enum class PlayState : std::uint8_t { Stopped, Playing, Paused, Error };

struct StreamOptions {
  double cache_seconds = 1.0;
  std::size_t min_slots = 0;         // tests: force a tiny cache (still at least what a frame needs)
  std::size_t max_slots = 0;         // tests: 0 = no cap beyond chunk_count
  unsigned max_loads_in_flight = 0;  // 0: what the source prefers (a local file 1, HTTP its connections)
  // Decoded frames held: the current one, the next, and room to decode ahead (at least 2).
  std::size_t decoded_frames = 3;
  // Going back (reverse play, a seek back): decoder states saved over a keyframe group, so that a
  // frame decodes from the nearest one rather than from its keyframe (format::FrameDecoder). Each
  // costs FrameDecoder::saved_state_bytes() (the particle codec: about 8 bytes per particle and
  // coded word, plus its zstd stream's 1.3 MiB); fewer are kept when the memory (the budget's
  // room, or without one what the clip's stored bytes justify) has no room for them, none for
  // codecs that need none. States are saved among the frames decoded only on the way to a seek's
  // or a step back's frame (a copy each), never in forward play past it.
  std::size_t saved_states = 3;
  bool blocking = false;  // update() waits for data instead of stalling
  // Hold the frame at or before the playhead and the one after it (next_frame(), fraction()) for
  // interpolation, instead of the nearest frame alone.
  bool interpolate = false;
  std::shared_ptr<IoScheduler> scheduler;  // default: a process-wide one with one worker
  std::shared_ptr<MemoryBudget> budget;    // optional: the cache must fit in it
  std::unique_ptr<io::ByteSource> io;      // default: io::open(path): the file, or the URL
};

struct FrameView {
  std::uint64_t frame = 0;                   // index in the clip
  std::uint64_t count = 0;                   // particles
  double time = 0.0;                         // the frame's time, seconds
  std::span<const std::byte> first, second;  // the records (decoded frames are contiguous: second is empty)
  bool valid = false;                        // false until the first frame is ready
  // With StreamOptions::interpolate: which particles continue from the frame before (frame - 1)
  // when that is known (format::MatchRun: from the particle codec, or by id), for next_frame()'s
  // interpolation. `matched` false: nothing is known (a keyframe without ids, say).
  std::span<const format::MatchRun> matching;
  bool matched = false;
  std::uint64_t bytes() const { return first.size() + second.size(); }
};

struct SlotInfo {
  SlotState state = SlotState::Empty;
  std::int64_t chunk = -1;
};

struct DebugInfo {
  std::span<const SlotInfo> slots;                   // one per cache slot, in ring order
  std::size_t read_slot = 0;                         // the slot holding the next frame to decode's first byte
  std::uint64_t read_offset = 0;                     // where that frame's packet starts in the chunked stream
  std::uint64_t decode_frame = 0;                    // the next frame the IO worker decodes
  std::uint64_t frames_decoded = 0;                  // frames decoded since open (seeks decode from a keyframe)
  std::size_t decoded_ready = 0, decoded_slots = 0;  // decoded frames waiting, of the ring's size
  std::uint32_t loads_in_flight = 0;
  std::uint64_t loads_done = 0, bytes_read = 0, stalls = 0;
  double io_ms = 0.0, decode_ms = 0.0;  // totals on the IO workers (decode: chunk codecs and frames)
  std::uint64_t cache_bytes = 0;        // the chunk ring: slots × chunk_size
  std::uint64_t decode_bytes = 0;       // the decoded frames, the frame decoder's state, a packet's staging
  std::uint64_t wrapped_packets = 0;    // packets decoded from across the ring's wrap (copied together)
  bool seeking = false;
  // What the byte source counts (HTTP: requests, bytes, retries, time to first byte, bandwidth;
  // zeros for a local file).
  io::SourceStats source;
};

class ParticleStream {
 public:
  // Opens and validates the file, sizes the cache and allocates it (one allocation), reserves IO
  // queue room, and starts loading the first chunks. Throws pstream::Error with a clear message
  // for a file that is not a .pstream, or pstream::OptionError("budget") for a cache that does not
  // fit the memory budget.
  static std::unique_ptr<ParticleStream> open(const std::filesystem::path& path, StreamOptions options = {});
  ~ParticleStream();
  void close();  // waits for the load in flight; safe after an error and twice

  // Playback. Time only advances through update(dt), with the host's clock.
  void play();
  void pause();
  void stop();  // pause and go back to the start of the range
  // The frame nearest `time` becomes current once it is decoded (from the keyframe at or before
  // it, or nearer: after the frame decoded last or a saved state of its group; at most
  // keyframe_interval - 1 extra frame decodes). Invalidates the current FrameView.
  void seek(double time);
  void set_loop(bool loop);
  // 0, fractional, > 1 (frames are skipped, never chunks), or negative: reverse. Decoding only runs
  // forwards, so in reverse each cached frame restarts it (records clips: the frame alone). A
  // particle clip restarts from the nearest of the decoder's saved states
  // (StreamOptions::saved_states): about 4 to 6 decodes a frame shown in groups of 64 frames
  // (docs/playback.md), and from the keyframe without them. In reverse the IO worker decodes no
  // further than the frame after the one shown.
  void set_speed(double speed);
  void set_range(double start, double end);
  void update(double dt);

  PlayState state() const { return state_; }
  const std::string& error() const { return error_; }  // set in the Error state
  double time() const;                                 // the playhead, clip seconds
  bool seeking() const { return seeking_; }
  const format::Metadata& metadata() const { return meta_; }
  const std::string& name() const;  // the file's (or the IO backend's) name, as messages give it
  std::span<const format::Attribute> layout() const { return meta_.layout; }

  // The current frame: zero-copy spans into the cache, valid until the next update().
  FrameView frame() const;
  // Copies the current frame's records into `out` (a mapped GPU buffer, say); returns bytes.
  std::size_t copy_frame(std::span<std::byte> out) const;
  // With StreamOptions::interpolate: the frame after the current one when it is decoded (invalid
  // at the end of the clip, or while it is still being decoded), and where the playhead is
  // between the two, in [0, 1).
  FrameView next_frame() const;
  // The frame after next_frame() when it is decoded too (invalid otherwise, and across a loop's
  // end): what a renderer can start moving to the GPU before the playhead reaches it. Like every
  // view, valid until the next update(), seek(), set_range() or stop().
  FrameView frame_after_next() const;
  double fraction() const;

  DebugInfo debug() const;

 private:
  ParticleStream() = default;
  struct Impl;
  std::unique_ptr<Impl> impl_;
  format::Metadata meta_;
  PlayState state_ = PlayState::Stopped;
  std::string error_;
  bool seeking_ = false;
  friend struct LoadRequest;
};

}  // namespace pstream::stream
