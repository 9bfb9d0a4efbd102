// One worker thread for background jobs handed over once per cached frame (the renderer's copy
// of the frame ahead, the player's next pair table): a job is queued by its owner, run on the
// thread, and waited for or collected by its owner. Each job object is queued at most once at a
// time, so a queue as long as the jobs that exist never fills and submitting allocates nothing.
// The thread touches a job after marking it Done (to wake its waiters): jobs must outlive the
// JobThread, or at least its handling of them.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <thread>
#include <vector>

namespace pstream::base {

class JobThread {
 public:
  // Idle -> Queued (owner: submit) -> Done (the thread, after run()) -> Idle (owner: collect).
  class Job {
   public:
    enum : std::uint32_t { Idle, Queued, Done };
    virtual ~Job() = default;
    std::uint32_t state() const { return state_.load(std::memory_order_acquire); }
    // Blocks while the job is queued or running (a futex wait, no spinning).
    void wait() const {
      for (std::uint32_t v; (v = state_.load(std::memory_order_acquire)) == Queued;)
        state_.wait(v, std::memory_order_acquire);
    }
    // A Done job back to Idle, its results read; false when it is not Done.
    bool collect() {
      if (state() != Done) return false;
      state_.store(Idle, std::memory_order_relaxed);
      return true;
    }
    void reset() { state_.store(Idle, std::memory_order_relaxed); }  // (nothing queued it: the owner's own)

   protected:
    virtual void run() = 0;  // on the thread

   private:
    friend class JobThread;
    std::atomic<std::uint32_t> state_{Idle};
  };

  // Room for `jobs` jobs queued at once: the number of job objects the owner has.
  explicit JobThread(std::size_t jobs) : ring_(jobs == 0 ? 1 : jobs), thread_([this] { loop(); }) {}
  ~JobThread() {  // runs what is queued, then ends
    {
      std::lock_guard lock(mutex_);
      stopping_ = true;
    }
    wake_.notify_all();
    thread_.join();
  }
  JobThread(const JobThread&) = delete;
  JobThread& operator=(const JobThread&) = delete;

  // Queues an Idle job (its inputs set). Under the mutex, so the thread sees the job and its count
  // together.
  void submit(Job& job) {
    {
      std::lock_guard lock(mutex_);
      job.state_.store(Job::Queued, std::memory_order_release);
      ring_[(head_ + count_) % ring_.size()] = &job;
      ++count_;
    }
    wake_.notify_one();
  }

 private:
  void loop() {
    std::unique_lock lock(mutex_);
    for (;;) {
      wake_.wait(lock, [&] { return stopping_ || count_ > 0; });
      if (count_ == 0) return;  // stopping, nothing left
      Job* job = ring_[head_];
      head_ = (head_ + 1) % ring_.size();
      --count_;
      lock.unlock();
      job->run();
      job->state_.store(Job::Done, std::memory_order_release);
      job->state_.notify_all();
      lock.lock();
    }
  }

  std::mutex mutex_;
  std::condition_variable wake_;
  std::vector<Job*> ring_;
  std::size_t head_ = 0, count_ = 0;
  bool stopping_ = false;
  std::thread thread_;  // last: it starts once the rest is made
};

}  // namespace pstream::base
