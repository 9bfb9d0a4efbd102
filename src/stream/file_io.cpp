#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include <fmt/format.h>

#include "particlestream/stream.hpp"

namespace pstream::stream {
namespace {

class FileIo final : public IoBackend {
 public:
  explicit FileIo(const std::filesystem::path& path) : name_(path.string()) {
    fd_ = ::open(name_.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd_ < 0) throw Error(fmt::format("{}: cannot open: {}", name_, std::strerror(errno)));
    const off_t end = ::lseek(fd_, 0, SEEK_END);
    if (end < 0) {
      ::close(fd_);
      throw Error(fmt::format("{}: cannot size: {}", name_, std::strerror(errno)));
    }
    size_ = static_cast<std::uint64_t>(end);
  }
  ~FileIo() override { ::close(fd_); }

  void read(std::uint64_t offset, std::span<std::byte> out) override {
    while (!out.empty()) {
      const ssize_t n = ::pread(fd_, out.data(), out.size(), static_cast<off_t>(offset));
      if (n < 0 && errno == EINTR) continue;
      if (n < 0)
        throw Error(fmt::format("{}: read of {} bytes at offset {} failed: {}", name_, out.size(), offset,
                                std::strerror(errno)));
      if (n == 0) throw Error(fmt::format("{}: read at offset {} hit the end of the file (truncated?)", name_, offset));
      out = out.subspan(static_cast<std::size_t>(n));
      offset += static_cast<std::uint64_t>(n);
    }
  }
  std::uint64_t size() const override { return size_; }
  const std::string& name() const override { return name_; }

 private:
  std::string name_;
  int fd_ = -1;
  std::uint64_t size_ = 0;
};

}  // namespace

std::unique_ptr<IoBackend> open_file(const std::filesystem::path& path) { return std::make_unique<FileIo>(path); }

bool MemoryBudget::try_reserve(std::uint64_t bytes) {
  std::uint64_t used = used_.load();
  do {
    if (used + bytes > total_) return false;
  } while (!used_.compare_exchange_weak(used, used + bytes));
  return true;
}

}  // namespace pstream::stream
