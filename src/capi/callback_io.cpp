#include "capi/callback_io.hpp"

#include <condition_variable>
#include <mutex>
#include <string>

#include <fmt/format.h>

namespace pstream::capi {
namespace {

class CallbackIo final : public stream::IoBackend {
 public:
  explicit CallbackIo(const pstream_io& io) : io_(io), name_(io.name ? io.name : "pstream_io") {
    if (io_.read == nullptr && io_.read_async == nullptr) throw Error(name_ + ": neither read nor read_async is set");
  }

  void read(std::uint64_t offset, std::span<std::byte> out) override {
    check_range(offset, out.size());
    int status = 0;
    if (io_.read != nullptr) {
      status = io_.read(io_.user, offset, out.data(), out.size());
    } else {  // only asynchronous reads: wait for this one (the header and tables at open)
      Wait wait;
      status = io_.read_async(io_.user, offset, out.data(), out.size(), &Wait::done, &wait);
      if (status == 0) status = wait.get();
    }
    if (status != 0)
      throw Error(fmt::format("{}: the read callback failed (status {}) for {} bytes at offset {}", name_, status,
                              out.size(), offset));
  }

  bool start_read(std::uint64_t offset, std::span<std::byte> out, ReadDone done, void* context) override {
    if (io_.read_async == nullptr) return false;
    check_range(offset, out.size());
    const int status = io_.read_async(io_.user, offset, out.data(), out.size(), done, context);
    if (status != 0)  // refused at once: no completion will come
      throw Error(
          fmt::format("{}: read_async refused {} bytes at offset {} (status {})", name_, out.size(), offset, status));
    return true;
  }

  std::uint64_t size() const override { return io_.size; }
  const std::string& name() const override { return name_; }

 private:
  struct Wait {
    std::mutex mutex;
    std::condition_variable cv;
    bool finished = false;
    int status = 0;
    static void done(void* self, int status) {
      auto* w = static_cast<Wait*>(self);
      std::lock_guard lock(w->mutex);
      w->status = status;
      w->finished = true;
      w->cv.notify_all();
    }
    int get() {
      std::unique_lock lock(mutex);
      cv.wait(lock, [&] { return finished; });
      return status;
    }
  };

  void check_range(std::uint64_t offset, std::uint64_t size) const {
    if (offset > io_.size || size > io_.size - offset)
      throw Error(
          fmt::format("{}: a read of {} bytes at offset {} is past its end ({} bytes)", name_, size, offset, io_.size));
  }

  pstream_io io_;
  std::string name_;
};

}  // namespace

std::unique_ptr<stream::IoBackend> callback_io(const pstream_io& io) { return std::make_unique<CallbackIo>(io); }

}  // namespace pstream::capi
