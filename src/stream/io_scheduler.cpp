#include <condition_variable>
#include <mutex>

#include "particlestream/stream.hpp"
#include "stream/load_request.hpp"

namespace pstream::stream {

std::span<std::byte> LoadRequest::read_target() const {
  return entry.codec == format::Codec::Raw ? destination : staging.first(entry.stored_size);
}

bool LoadRequest::start_async_read() {
  if (produce || read_phase != NotStarted) return false;
  t0 = std::chrono::steady_clock::now();
  error.clear();
  read_phase = Started;
  try {
    if (io->start_read(entry.file_offset, read_target(), &IoScheduler::read_done, this)) return true;
  } catch (const std::exception& e) {  // a backend that fails to start: the load fails
    read_phase = Completed;
    read_status = -1;
    error = e.what();
    return false;
  }
  read_phase = NotStarted;  // no asynchronous reads: execute() reads
  return false;
}

void LoadRequest::execute() {
  using Clock = std::chrono::steady_clock;
  if (produce) {  // the stream's callback does the work
    status.store(Done, std::memory_order_release);
    return;
  }
  const bool was_async = read_phase == Completed;
  read_phase = NotStarted;
  try {
    const std::span<std::byte> target = read_target();
    if (was_async) {
      if (read_status != 0) {
        if (error.empty()) error = io->failure_message(read_status);
        if (!error.empty()) {
          error += " (chunk " + std::to_string(chunk) + ")";
        } else {
          error = io->name() + ": the asynchronous read of " + std::to_string(target.size()) + " bytes at offset " +
                  std::to_string(entry.file_offset) + " (chunk " + std::to_string(chunk) + ") failed with status " +
                  std::to_string(read_status);
        }
        status.store(Failed, std::memory_order_release);
        status.notify_all();
        return;
      }
    } else {
      t0 = Clock::now();
      io->read(entry.file_offset, target);
    }
    const auto t1 = Clock::now();
    // Raw chunks were read straight into their slot: the bytes move once, disk to cache.
    if (entry.codec != format::Codec::Raw || !format::checksum_matches(target, entry.checksum)) {
      decoder->decode(entry, target, destination, io->name(), chunk);  // raises a checksum error
    }
    io_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(t1 - t0).count();
    decode_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now() - t1).count();
    status.store(Done, std::memory_order_release);
  } catch (const std::exception& e) {
    error = e.what();
    status.store(Failed, std::memory_order_release);
  }
  status.notify_all();
}

struct IoScheduler::Queue {
  std::mutex mutex;
  std::condition_variable wake;
  std::vector<LoadRequest*> ring;  // fixed capacity, grown only by reserve()
  std::size_t head = 0, count = 0, reserved = 0;
  bool stop = false;
};

IoScheduler::IoScheduler(unsigned workers) : queue_(std::make_unique<Queue>()) {
  for (unsigned i = 0; i < std::max(workers, 1u); ++i) threads_.emplace_back([this] { run(); });
}

IoScheduler::IoScheduler(HostSubmit submit) : queue_(std::make_unique<Queue>()), host_(std::move(submit)) {
  if (!host_) throw Error("an IO scheduler on the host's jobs needs a submit function");
}

void IoScheduler::run_job(void* request) {
  auto* r = static_cast<LoadRequest*>(request);
  if (r->start_async_read()) return;  // read_done() submits the rest; r may already be gone
  r->execute();
  if (r->on_done != nullptr) r->on_done(r->owner, r);  // must be the last use of r here
}

void IoScheduler::read_done(void* request, int status) {
  auto* r = static_cast<LoadRequest*>(request);
  r->read_status = status;
  r->read_phase = LoadRequest::Completed;
  r->scheduler->submit(r);  // verify and decode as a job of its own
}

IoScheduler::~IoScheduler() {
  {
    std::lock_guard lock(queue_->mutex);
    queue_->stop = true;
  }
  queue_->wake.notify_all();
  for (auto& t : threads_) t.join();
}

std::shared_ptr<IoScheduler> IoScheduler::shared_default() {
  static const std::shared_ptr<IoScheduler> scheduler = std::make_shared<IoScheduler>(1);
  return scheduler;
}

void IoScheduler::reserve(std::size_t requests) {
  std::lock_guard lock(queue_->mutex);
  Queue& q = *queue_;
  q.reserved += requests;
  if (q.ring.size() < q.reserved) {  // re-pack the ring into a larger one (at open only)
    std::vector<LoadRequest*> bigger(q.reserved);
    for (std::size_t i = 0; i < q.count; ++i) bigger[i] = q.ring[(q.head + i) % q.ring.size()];
    q.ring = std::move(bigger);
    q.head = 0;
  }
}

void IoScheduler::release(std::size_t requests) {
  std::lock_guard lock(queue_->mutex);
  queue_->reserved -= requests;
}

void IoScheduler::submit(LoadRequest* request) {
  request->status.store(LoadRequest::Pending, std::memory_order_relaxed);
  request->scheduler = this;
  if (host_) {
    host_(&IoScheduler::run_job, request);
    return;
  }
  // The wake-up is sent under the lock. A worker may take the request as soon as the lock is
  // free, and its completion may let the stream that owns this scheduler close and destroy it;
  // sent after the unlock, from a host's thread (read_done()), it could reach a destroyed queue.
  std::lock_guard lock(queue_->mutex);
  Queue& q = *queue_;
  q.ring[(q.head + q.count) % q.ring.size()] = request;  // room was reserved at open
  ++q.count;
  q.wake.notify_one();
}

void IoScheduler::run() {
  Queue& q = *queue_;
  for (;;) {
    LoadRequest* r = nullptr;
    {
      std::unique_lock lock(q.mutex);
      q.wake.wait(lock, [&] { return q.stop || q.count > 0; });
      if (q.count == 0) return;  // stopping, and nothing left to do
      r = q.ring[q.head];
      q.head = (q.head + 1) % q.ring.size();
      --q.count;
    }
    run_job(r);
  }
}

bool MemoryBudget::try_reserve(std::uint64_t bytes) {
  std::uint64_t used = used_.load();
  do {
    if (used + bytes > total_) return false;
  } while (!used_.compare_exchange_weak(used, used + bytes));
  return true;
}

}  // namespace pstream::stream
