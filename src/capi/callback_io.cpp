#include "capi/callback_io.hpp"

#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <string>
#include <vector>

#include <fmt/format.h>

namespace pstream::capi {
namespace {

using Clock = std::chrono::steady_clock;

class CallbackIo final : public io::ByteSource {
 public:
  CallbackIo(const pstream_io& io, double timeout_seconds)
      : io_(io),
        name_(io.name ? io.name : "pstream_io"),
        timeout_(std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(timeout_seconds))) {
    if (io_.read == nullptr && io_.read_async == nullptr) throw Error(name_ + ": neither read nor read_async is set");
    for (Ticket& t : tickets_) t.owner = this;
  }

  void read(std::uint64_t offset, std::span<std::byte> out) override {
    check_range(offset, out.size());
    if (io_.read != nullptr) {
      const int status = io_.read(io_.user, offset, out.data(), out.size());
      if (status != 0) throw failed(status, offset, out.size());
      return;
    }
    // Only asynchronous reads (the header and tables at open): wait for this one, at most the
    // timeout. The host fills a buffer of the wait's own, which is left allocated if the
    // completion never comes, so a late one writes nothing that was freed.
    auto* wait = new Wait;
    wait->bytes.resize(out.size());
    int status = io_.read_async(io_.user, offset, wait->bytes.data(), out.size(), &Wait::done, wait);
    if (status == 0) {
      std::unique_lock lock(wait->mutex);
      if (!wait->cv.wait_for(lock, timeout_, [&] { return wait->finished; })) {
        wait->abandoned = true;  // left allocated: see above
        throw Error(fmt::format("{}: read_async of {} bytes at offset {} did not complete within {:g} s", name_,
                                out.size(), offset, seconds()));
      }
      status = wait->status;
      if (status == 0) std::memcpy(out.data(), wait->bytes.data(), out.size());
    }
    delete wait;
    if (status != 0) throw failed(status, offset, out.size());
  }

  bool start_read(std::uint64_t offset, std::span<std::byte> out, ReadDone done, void* context) override {
    if (io_.read_async == nullptr) return false;
    check_range(offset, out.size());
    Ticket* t = nullptr;
    for (Ticket& candidate : tickets_) {
      int idle = kIdle;
      if (candidate.state.compare_exchange_strong(idle, kClaimed)) {
        t = &candidate;
        break;
      }
    }
    if (t == nullptr) throw Error(fmt::format("{}: more than {} reads under way", name_, tickets_.size()));
    t->done = done;
    t->context = context;
    t->offset.store(offset, std::memory_order_relaxed);
    t->size.store(out.size(), std::memory_order_relaxed);
    t->started.store(Clock::now().time_since_epoch().count(), std::memory_order_relaxed);
    t->state.store(kPending, std::memory_order_release);
    const int status = io_.read_async(io_.user, offset, out.data(), out.size(), &Ticket::complete, t);
    if (status != 0) {  // refused at once: no completion will come
      int pending = kPending;
      t->state.compare_exchange_strong(pending, kIdle);
      throw Error(
          fmt::format("{}: read_async refused {} bytes at offset {} (status {})", name_, out.size(), offset, status));
    }
    return true;
  }

  std::uint64_t size() const override { return io_.size; }
  const std::string& name() const override { return name_; }

  std::string fault() const override {
    if (const Ticket* m = misuse_.load(std::memory_order_acquire)) {
      return fmt::format(
          "{}: the host completed the read of {} bytes at offset {} more than once (read_async's "
          "completion must be called exactly once)",
          name_, m->size.load(std::memory_order_relaxed), m->offset.load(std::memory_order_relaxed));
    }
    const Clock::time_point now = Clock::now();
    for (const Ticket& t : tickets_) {
      if (t.state.load(std::memory_order_acquire) == kPending &&
          now - Clock::time_point(Clock::duration(t.started.load(std::memory_order_relaxed))) > timeout_) {
        return fmt::format("{}: read_async of {} bytes at offset {} did not complete within {:g} s", name_,
                           t.size.load(std::memory_order_relaxed), t.offset.load(std::memory_order_relaxed), seconds());
      }
    }
    return {};
  }

  void abandon() override {
    for (Ticket& t : tickets_) t.state.store(kAbandoned, std::memory_order_release);
  }

 private:
  enum : int { kIdle, kClaimed, kPending, kAbandoned, kCompleting };
  // One read under way: the completion the host calls goes through it, so a second call (or one
  // after the stream gave up on it) is caught instead of completing a load twice.
  struct Ticket {
    CallbackIo* owner = nullptr;
    std::atomic<int> state{kIdle};
    ReadDone done = nullptr;
    void* context = nullptr;
    // What fault() reports of the read, read by the stream's thread while the worker may start the
    // ticket's next read: atomics, so that a report races with nothing (ThreadSanitizer found it).
    std::atomic<std::uint64_t> offset{0}, size{0};
    std::atomic<Clock::rep> started{0};
    static void complete(void* token, int status) {
      auto* t = static_cast<Ticket*>(token);
      int pending = kPending;
      if (t->state.compare_exchange_strong(pending, kCompleting, std::memory_order_acq_rel)) {
        // The read's completion is taken out before the ticket is free again: once it is idle, the
        // stream's worker may claim it for its next read and overwrite them, and this read would
        // complete that one. Nor is the ticket touched after done(): the stream, which owns it,
        // may close as soon as its last read is done.
        const ReadDone done = t->done;
        void* const context = t->context;
        int completing = kCompleting;
        t->state.compare_exchange_strong(completing, kIdle, std::memory_order_acq_rel);  // not if abandoned since
        done(context, status);
        return;
      }
      if (pending == kAbandoned) return;  // late: the stream gave up on it
      // Completed already (or never started): remember it; the stream fails with fault(). (Were
      // the ticket started again in between, the extra call completes that read early: its
      // checksum then fails the stream instead.)
      const Ticket* none = nullptr;
      t->owner->misuse_.compare_exchange_strong(none, t);
    }
  };
  struct Wait {
    std::mutex mutex;
    std::condition_variable cv;
    std::vector<std::byte> bytes;
    bool finished = false, abandoned = false;
    int status = 0;
    static void done(void* self, int status) {
      auto* w = static_cast<Wait*>(self);
      std::lock_guard lock(w->mutex);
      if (w->finished || w->abandoned) return;  // twice, or after open gave up on it
      w->status = status;
      w->finished = true;
      w->cv.notify_all();
    }
  };

  double seconds() const { return std::chrono::duration<double>(timeout_).count(); }
  Error failed(int status, std::uint64_t offset, std::uint64_t size) const {
    return Error(
        fmt::format("{}: the read callback failed (status {}) for {} bytes at offset {}", name_, status, size, offset));
  }
  void check_range(std::uint64_t offset, std::uint64_t size) const {
    if (offset > io_.size || size > io_.size - offset)
      throw Error(
          fmt::format("{}: a read of {} bytes at offset {} is past its end ({} bytes)", name_, size, offset, io_.size));
  }

  pstream_io io_;
  std::string name_;
  Clock::duration timeout_;
  std::array<Ticket, 8> tickets_;
  std::atomic<const Ticket*> misuse_{nullptr};
};

}  // namespace

std::unique_ptr<io::ByteSource> callback_io(const pstream_io& io, double timeout_seconds) {
  return std::make_unique<CallbackIo>(io, timeout_seconds > 0.0 ? timeout_seconds : kDefaultIoTimeoutSeconds);
}

}  // namespace pstream::capi
