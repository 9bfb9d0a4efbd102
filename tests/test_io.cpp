#include "test_io.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <condition_variable>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <string>
#include <thread>

#include "capi/callback_io.hpp"
#include "particlestream/error.hpp"

namespace pstream::test {
namespace {

// A file as an engine would serve it: an fd, its size and a latency per read.
struct HostFile {
  int fd = -1;
  std::uint64_t size = 0;
  std::string name;
  std::uint64_t reads = 0;
  ~HostFile() {
    if (fd >= 0) ::close(fd);
  }
  std::chrono::microseconds latency(std::uint64_t offset) const {
    return std::chrono::microseconds(50 + (offset * 2654435761u >> 7) % 200);
  }
  int pread_all(std::uint64_t offset, void* out, std::uint64_t size) const {
    auto* p = static_cast<char*>(out);
    while (size > 0) {
      const ssize_t n = ::pread(fd, p, size, static_cast<off_t>(offset));
      if (n <= 0) return n == 0 ? 2 : 1;
      p += n, size -= static_cast<std::uint64_t>(n), offset += static_cast<std::uint64_t>(n);
    }
    return 0;
  }
};

int read_sync(void* user, std::uint64_t offset, void* out, std::uint64_t size) {
  auto* f = static_cast<HostFile*>(user);
  ++f->reads;
  std::this_thread::sleep_for(f->latency(offset));
  return f->pread_all(offset, out, size);
}

// The host's IO thread: a fixed queue (nothing allocates once it runs), served in order.
class HostIoThread {
 public:
  static HostIoThread& instance() {
    static HostIoThread io;
    return io;
  }
  int submit(const HostFile* file, std::uint64_t offset, void* out, std::uint64_t size, pstream_io_done done,
             void* token) {
    std::lock_guard lock(mutex_);
    if (count_ == queue_.size()) return 3;  // refused: the completion never comes
    queue_[(head_ + count_) % queue_.size()] = {file, offset, out, size, done, token};
    ++count_;
    wake_.notify_one();
    return 0;
  }

 private:
  struct Request {
    const HostFile* file;
    std::uint64_t offset;
    void* out;
    std::uint64_t size;
    pstream_io_done done;
    void* token;
  };
  HostIoThread() : thread_([this] { run(); }) {}
  ~HostIoThread() {
    {
      std::lock_guard lock(mutex_);
      stop_ = true;
    }
    wake_.notify_one();
    thread_.join();
  }
  void run() {
    for (;;) {
      Request r{};
      {
        std::unique_lock lock(mutex_);
        wake_.wait(lock, [&] { return stop_ || count_ > 0; });
        if (count_ == 0) return;
        r = queue_[head_];
        head_ = (head_ + 1) % queue_.size();
        --count_;
      }
      std::this_thread::sleep_for(r.file->latency(r.offset));
      r.done(r.token, r.file->pread_all(r.offset, r.out, r.size));
    }
  }
  std::mutex mutex_;
  std::condition_variable wake_;
  std::array<Request, 256> queue_{};
  std::size_t head_ = 0, count_ = 0;
  bool stop_ = false;
  std::thread thread_;
};

int read_async(void* user, std::uint64_t offset, void* out, std::uint64_t size, pstream_io_done done, void* token) {
  auto* f = static_cast<HostFile*>(user);
  if (++f->reads % 4 == 0) {  // served at once: the completion comes before read_async returns
    done(token, f->pread_all(offset, out, size));
    return 0;
  }
  return HostIoThread::instance().submit(f, offset, out, size, done, token);
}

// Owns the host's file and the adapter the C API would build over it.
class CallbackBackend final : public io::ByteSource {
 public:
  CallbackBackend(const std::filesystem::path& path, bool async) {
    file_.name = path.string();
    file_.fd = ::open(file_.name.c_str(), O_RDONLY | O_CLOEXEC);
    if (file_.fd < 0) throw Error(file_.name + ": cannot open: " + std::strerror(errno));
    file_.size = static_cast<std::uint64_t>(::lseek(file_.fd, 0, SEEK_END));
    pstream_io io{};
    io.user = &file_;
    io.size = file_.size;
    io.name = file_.name.c_str();
    if (async) {
      io.read_async = read_async;
    } else {
      io.read = read_sync;
    }
    inner_ = capi::callback_io(io);
  }
  void read(std::uint64_t offset, std::span<std::byte> out) override { inner_->read(offset, out); }
  bool start_read(std::uint64_t offset, std::span<std::byte> out, ReadDone done, void* context) override {
    return inner_->start_read(offset, out, done, context);
  }
  std::uint64_t size() const override { return inner_->size(); }
  const std::string& name() const override { return inner_->name(); }

 private:
  HostFile file_;
  std::unique_ptr<io::ByteSource> inner_;
};

}  // namespace

std::string test_url(const std::filesystem::path& file, const std::string& faults) {
  const char* base = std::getenv("PSTREAM_TEST_URL_BASE");
  if (base == nullptr || *base == '\0') throw Error("no PSTREAM_TEST_URL_BASE: run under tests/http/with_server.sh");
  return std::string(base) + faults + std::filesystem::absolute(file).string();
}

const char* io_mode() {
  const char* mode = std::getenv("PSTREAM_TEST_IO");
  return mode != nullptr && *mode != '\0' ? mode : "file";
}

std::unique_ptr<io::ByteSource> test_io(const std::filesystem::path& file) {
  const std::string mode = io_mode();
  if (mode == "file") return io::open_file(file);
  if (mode == "callbacks" || mode == "async") return std::make_unique<CallbackBackend>(file, mode == "async");
  if (mode == "http") return io::open_url(test_url(file));
  throw Error("PSTREAM_TEST_IO=" + mode + ": expected file, callbacks, async or http");
}

}  // namespace pstream::test
