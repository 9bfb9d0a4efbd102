#include "base/mapped_file.hpp"

#include <fcntl.h>
#include <signal.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <mutex>
#include <utility>

#include <fmt/format.h>

#include "particlestream/error.hpp"

namespace pstream {
namespace {

// The guard table. The SIGBUS handler only reads it (atomics, no locks); open and close take a
// mutex among themselves.
struct Guard {
  std::atomic<std::uintptr_t> begin{0}, end{0};
  std::atomic<bool> truncated{false};
};
std::array<Guard, MappedFile::kMaxGuarded> guards;
std::mutex guards_mutex;
std::atomic<bool> handler_installed{false};
struct sigaction previous_action {};
// The first truncated file's name, copied at registration so the handler never allocates.
std::array<std::array<char, 1024>, MappedFile::kMaxGuarded> guard_names{};
std::array<char, 1024> truncated_name{};
std::atomic<bool> any_truncated{false};

void on_sigbus(int signal, siginfo_t* info, void* context) {
  const auto address = reinterpret_cast<std::uintptr_t>(info->si_addr);
  for (std::size_t i = 0; i < guards.size(); ++i) {
    Guard& g = guards[i];
    const std::uintptr_t begin = g.begin.load(std::memory_order_acquire), end = g.end.load(std::memory_order_acquire);
    if (begin == 0 || address < begin || address >= end) continue;
    const auto page = static_cast<std::uintptr_t>(::sysconf(_SC_PAGESIZE));
    void* at = reinterpret_cast<void*>(address & ~(page - 1));
    // A page of zeros over the missing one; the faulting read is retried and sees it.
    if (::mmap(at, page, PROT_READ, MAP_PRIVATE | MAP_ANONYMOUS | MAP_FIXED, -1, 0) == MAP_FAILED) break;
    g.truncated.store(true);
    if (!any_truncated.exchange(true)) std::memcpy(truncated_name.data(), guard_names[i].data(), truncated_name.size());
    return;
  }
  // Not one of ours: what would have happened without us.
  if (previous_action.sa_flags & SA_SIGINFO) {
    if (previous_action.sa_sigaction != nullptr) {
      previous_action.sa_sigaction(signal, info, context);
      return;
    }
  } else if (previous_action.sa_handler != SIG_DFL && previous_action.sa_handler != SIG_IGN &&
             previous_action.sa_handler != nullptr) {
    previous_action.sa_handler(signal);
    return;
  }
  ::signal(SIGBUS, SIG_DFL);
  ::raise(SIGBUS);
}

void install_handler() {
  if (handler_installed.exchange(true)) return;
  struct sigaction action {};
  action.sa_sigaction = on_sigbus;
  action.sa_flags = SA_SIGINFO | SA_NODEFER;
  sigemptyset(&action.sa_mask);
  ::sigaction(SIGBUS, &action, &previous_action);
}

int guard(const std::byte* data, std::size_t size, const std::string& path) {
  std::lock_guard lock(guards_mutex);
  install_handler();
  for (std::size_t i = 0; i < guards.size(); ++i) {
    if (guards[i].begin.load() != 0) continue;
    const std::size_t n = std::min(path.size(), guard_names[i].size() - 1);
    std::memcpy(guard_names[i].data(), path.data(), n);
    guard_names[i][n] = '\0';
    guards[i].truncated.store(false);
    guards[i].end.store(reinterpret_cast<std::uintptr_t>(data) + size, std::memory_order_release);
    guards[i].begin.store(reinterpret_cast<std::uintptr_t>(data), std::memory_order_release);
    return static_cast<int>(i);
  }
  return -1;
}

}  // namespace

int open_regular_file(const std::filesystem::path& path, std::uint64_t& size) {
  const std::string name = path.string();
  // O_NONBLOCK: opening a FIFO without a writer would otherwise wait forever.
  const int fd = ::open(name.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
  if (fd < 0) throw Error(fmt::format("{}: cannot open: {}", name, std::strerror(errno)));
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    const int err = errno;
    ::close(fd);
    throw Error(fmt::format("{}: cannot stat: {}", name, std::strerror(err)));
  }
  if (!S_ISREG(st.st_mode)) {
    ::close(fd);
    const char* kind = S_ISDIR(st.st_mode)    ? "a directory"
                       : S_ISFIFO(st.st_mode) ? "a FIFO"
                       : S_ISSOCK(st.st_mode) ? "a socket"
                       : S_ISCHR(st.st_mode)  ? "a character device"
                       : S_ISBLK(st.st_mode)  ? "a block device"
                                              : "not a regular file";
    throw Error(fmt::format("{}: is {}; expected a regular file", name, kind));
  }
  ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) & ~O_NONBLOCK);
  size = static_cast<std::uint64_t>(st.st_size);
  return fd;
}

MappedFile MappedFile::open(const std::filesystem::path& path) {
  MappedFile file;
  file.path_ = path.string();
  std::uint64_t size = 0;
  const int fd = open_regular_file(path, size);
  file.size_ = static_cast<std::size_t>(size);
  if (file.size_ > 0) {
    void* p = ::mmap(nullptr, file.size_, PROT_READ, MAP_PRIVATE, fd, 0);
    if (p == MAP_FAILED) {
      const int err = errno;
      ::close(fd);
      throw Error(fmt::format("{}: cannot map {} bytes: {}", file.path_, file.size_, std::strerror(err)));
    }
    file.data_ = static_cast<const std::byte*>(p);
    file.slot_ = guard(file.data_, file.size_, file.path_);
  }
  ::close(fd);  // the mapping keeps its own reference to the file
  return file;
}

void MappedFile::check_intact() const {
  if (slot_ < 0 || !guards[static_cast<std::size_t>(slot_)].truncated.load()) return;
  std::uint64_t now = 0;
  struct stat st {};
  const bool known = ::stat(path_.c_str(), &st) == 0;
  if (known) now = static_cast<std::uint64_t>(st.st_size);
  throw Error(
      fmt::format("{}: the file was truncated while it was being read (it had {} bytes{}); nothing read "
                  "from it after that point was used",
                  path_, size_, known ? fmt::format(", now {}", now) : std::string()));
}

std::string MappedFile::truncated_file() {
  if (!any_truncated.load()) return {};
  return std::string(truncated_name.data());
}

void MappedFile::release() {
  if (data_ == nullptr) return;
  if (slot_ >= 0) {
    std::lock_guard lock(guards_mutex);
    Guard& g = guards[static_cast<std::size_t>(slot_)];
    g.begin.store(0, std::memory_order_release);
    g.end.store(0, std::memory_order_release);
  }
  ::munmap(const_cast<std::byte*>(data_), size_);
  data_ = nullptr;
  slot_ = -1;
}

MappedFile::MappedFile(MappedFile&& other) noexcept
    : data_(std::exchange(other.data_, nullptr)),
      size_(std::exchange(other.size_, 0)),
      slot_(std::exchange(other.slot_, -1)),
      path_(std::move(other.path_)) {}

MappedFile& MappedFile::operator=(MappedFile&& other) noexcept {
  if (this != &other) {
    release();
    data_ = std::exchange(other.data_, nullptr);
    size_ = std::exchange(other.size_, 0);
    slot_ = std::exchange(other.slot_, -1);
    path_ = std::move(other.path_);
  }
  return *this;
}

MappedFile::~MappedFile() { release(); }

}  // namespace pstream
