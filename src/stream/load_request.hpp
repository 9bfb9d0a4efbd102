// One chunk load, handed from a stream to an IO worker. The stream owns a fixed set of these
// (one per allowed load in flight), so submitting a load allocates nothing.
#pragma once

#include <atomic>
#include <string>

#include "particlestream/stream.hpp"

namespace pstream::stream {

struct LoadRequest {
  enum Status : int { Idle = 0, Pending = 1, Done = 2, Failed = 3 };

  // Set by the stream before submit().
  io::ByteSource* io = nullptr;
  format::ChunkDecoder* decoder = nullptr;
  format::ChunkEntry entry;
  std::uint64_t chunk = 0;
  std::span<std::byte> destination;  // the slot, exactly the chunk's raw size
  std::span<std::byte> staging;      // compressed bytes land here first
  std::size_t slot = 0;
  std::uint64_t seq = 0;
  bool discard = false;  // a seek made this load useless; its slot frees on completion
  bool produce = false;  // not a load: a turn for the stream's frame decoding on the worker

  // Called by the worker right after execute(): the stream marks the slot and chains its next
  // load without waiting for the host's next update().
  void (*on_done)(void* owner, LoadRequest* request) = nullptr;
  void* owner = nullptr;

  // Set by the worker (and the scheduler, for a read started with io::ByteSource::start_read()).
  std::atomic<int> status{Idle};
  std::string error;  // only on failure
  std::int64_t io_ns = 0, decode_ns = 0;
  IoScheduler* scheduler = nullptr;          // set by IoScheduler::submit()
  std::chrono::steady_clock::time_point t0;  // when the read started
  // Where an asynchronous read is: NotStarted, Started (waiting for its completion), Completed
  // (read_status holds the backend's status; the next execute() verifies and decodes).
  enum ReadPhase : std::uint8_t { NotStarted, Started, Completed };
  ReadPhase read_phase = NotStarted;
  int read_status = 0;

  // The span the chunk's stored bytes are read into: raw chunks straight into their slot.
  std::span<std::byte> read_target() const;
  // On an IO worker: start an asynchronous read when the backend offers one (returns true: the
  // load continues when it completes), else nothing (returns false).
  bool start_async_read();
  void execute();  // on an IO worker: read (unless already read), verify, decode; never throws
};

}  // namespace pstream::stream
