#include "base/output_file.hpp"

#include <dirent.h>
#include <fcntl.h>
#include <pthread.h>
#include <signal.h>
#include <sys/file.h>
#include <sys/random.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <climits>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <utility>

#include <fmt/format.h>

#include "particlestream/error.hpp"

namespace pstream {
namespace {

constexpr std::string_view kPartial = ".partial-";
constexpr std::size_t kBufferSize = 1 << 20;

// Open temporaries, for the signal handler: fixed storage, read without locks.
constexpr int kMaxTemporaries = 64;
std::array<std::array<char, 4096>, kMaxTemporaries> temp_names{};
std::array<std::atomic<bool>, kMaxTemporaries> temp_used{};
std::array<std::atomic<bool>, kMaxTemporaries> temp_is_folder{};  // a ScratchFolder
std::mutex temp_mutex;
std::atomic<bool> handlers_installed{false};

// A scratch folder's files, then the folder, with async-signal-safe calls only (the kernel's
// directory listing, not readdir's heap). Passes repeat from the start until one removes nothing:
// a listing need not return every entry while entries are removed.
void remove_folder_in_handler(const char* path) {
  const int fd = ::open(path, O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
  if (fd >= 0) {
    alignas(8) char listing[4096];
    for (int pass = 0; pass < 64; ++pass) {
      bool removed = false;
      ::lseek(fd, 0, SEEK_SET);
      for (long n; (n = ::syscall(SYS_getdents64, fd, listing, sizeof listing)) > 0;) {
        for (long at = 0; at < n;) {
          const auto* entry = reinterpret_cast<const struct dirent64*>(listing + at);
          at += entry->d_reclen;
          const char* name = entry->d_name;
          if (name[0] == '.' && (name[1] == 0 || (name[1] == '.' && name[2] == 0))) continue;
          removed = ::unlinkat(fd, name, 0) == 0 || removed;
        }
      }
      if (!removed) break;
    }
    ::close(fd);
  }
  ::rmdir(path);
}

void on_fatal_signal(int signal) {
  for (const bool folders : {false, true}) {  // files first: a temporary may lie in a scratch folder
    for (int i = 0; i < kMaxTemporaries; ++i) {
      const auto k = static_cast<std::size_t>(i);
      if (!temp_used[k].load() || temp_is_folder[k].load() != folders) continue;
      if (folders)
        remove_folder_in_handler(temp_names[k].data());
      else
        ::unlink(temp_names[k].data());
    }
  }
  ::signal(signal, SIG_DFL);  // then end as the signal would have ended us
  ::raise(signal);
}

void install_handlers() {
  if (handlers_installed.exchange(true)) return;
  for (const int s : {SIGINT, SIGTERM, SIGHUP}) {
    struct sigaction old {};
    ::sigaction(s, nullptr, &old);
    if (old.sa_handler == SIG_IGN) continue;  // nohup and friends: leave it ignored
    struct sigaction action {};
    action.sa_handler = on_fatal_signal;
    sigemptyset(&action.sa_mask);
    ::sigaction(s, &action, nullptr);
  }
}

int register_temporary(const std::string& name, bool folder = false) {
  std::lock_guard lock(temp_mutex);
  install_handlers();
  if (name.size() >= temp_names[0].size()) return -1;
  for (int i = 0; i < kMaxTemporaries; ++i) {
    auto& used = temp_used[static_cast<std::size_t>(i)];
    if (used.load()) continue;
    std::memcpy(temp_names[static_cast<std::size_t>(i)].data(), name.c_str(), name.size() + 1);
    temp_is_folder[static_cast<std::size_t>(i)].store(folder);
    used.store(true);
    return i;
  }
  return -1;
}

// SIGINT, SIGTERM and SIGHUP wait while this lives: while a temporary is made and registered, so
// that the handler knows of every temporary a signal could leave behind (one arriving in between
// had ended the process with the new file unknown to it).
class EndingSignalsWait {
 public:
  EndingSignalsWait() {
    sigset_t ending;
    sigemptyset(&ending);
    for (const int s : {SIGINT, SIGTERM, SIGHUP}) sigaddset(&ending, s);
    ::pthread_sigmask(SIG_BLOCK, &ending, &before_);
  }
  ~EndingSignalsWait() { ::pthread_sigmask(SIG_SETMASK, &before_, nullptr); }
  EndingSignalsWait(const EndingSignalsWait&) = delete;
  EndingSignalsWait& operator=(const EndingSignalsWait&) = delete;

 private:
  sigset_t before_{};
};

void unregister_temporary(int slot) {
  if (slot < 0) return;
  std::lock_guard lock(temp_mutex);
  temp_used[static_cast<std::size_t>(slot)].store(false);
}

// Whether `name` is one of our temporaries: `.NAME.partial-TAG`, TAG hexadecimal (random now;
// a process id in earlier versions).
bool is_temporary_name(std::string_view name) {
  const auto at = name.rfind(kPartial);
  if (name.size() < 2 || name[0] != '.' || at == std::string_view::npos) return false;
  const std::string_view tag = name.substr(at + kPartial.size());
  return !tag.empty() && tag.find_first_not_of("0123456789abcdef") == std::string_view::npos;
}

// Temporaries nobody holds any more (their writer was killed with SIGKILL, in this container or
// another, on this host or another sharing the folder). A writer holds an exclusive flock on its
// temporary for as long as it lives, so a lock we can take means the writer is gone; process ids
// say nothing across PID namespaces and hosts.
void remove_stale_temporaries(const std::filesystem::path& dir) {
  std::error_code ec;
  for (std::filesystem::directory_iterator it(dir.empty() ? "." : dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::filesystem::path path = it->path();
    if (!is_temporary_name(path.filename().string())) continue;
    const int fd = ::open(path.c_str(), O_RDWR | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) continue;  // gone already, or not ours to judge
    struct stat held {
    }, named{};
    if (::fstat(fd, &held) == 0 && S_ISREG(held.st_mode) && ::flock(fd, LOCK_EX | LOCK_NB) == 0 &&
        ::lstat(path.c_str(), &named) == 0 && named.st_dev == held.st_dev && named.st_ino == held.st_ino) {
      ::unlink(path.c_str());
    }
    ::close(fd);
  }
}

// Creates `.NAME.partial-TAG` beside `path` (NAME cut so that the whole fits NAME_MAX), open for
// writing and exclusively locked for the descriptor's life. Returns the descriptor, or -1 with
// errno set.
int create_locked_temporary(const std::filesystem::path& path, std::filesystem::path& temp) {
  for (int attempt = 0; attempt < 16; ++attempt) {
    std::uint64_t tag = 0;
    if (::getrandom(&tag, sizeof tag, 0) != static_cast<ssize_t>(sizeof tag)) {
      tag = (static_cast<std::uint64_t>(::getpid()) << 32) ^ static_cast<std::uint64_t>(attempt) ^
            reinterpret_cast<std::uintptr_t>(&tag);
    }
    const std::string suffix = fmt::format("{}{:016x}", kPartial, tag);
    std::string name = path.filename().string();
    name.resize(std::min(name.size(), std::size_t(NAME_MAX) - 1 - suffix.size()));
    temp = path.parent_path() / fmt::format(".{}{}", name, suffix);
    const int fd = ::open(temp.c_str(), O_RDWR | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
    if (fd < 0) {
      if (errno == EEXIST) continue;
      return -1;
    }
    // Between the open and the lock another process's cleanup may have taken the lock of the
    // new, empty file and removed it: then the inode is unlinked, and a fresh name is tried.
    struct stat st {};
    if (::flock(fd, LOCK_EX | LOCK_NB) == 0 && ::fstat(fd, &st) == 0 && st.st_nlink > 0) return fd;
    ::close(fd);
  }
  errno = EEXIST;
  return -1;
}

const char* kind_of(mode_t mode) {
  return S_ISDIR(mode)    ? "a directory"
         : S_ISFIFO(mode) ? "a FIFO"
         : S_ISSOCK(mode) ? "a socket"
         : S_ISBLK(mode)  ? "a block device"
                          : "not a regular file";
}

}  // namespace

void check_output(const std::filesystem::path& path, std::span<const std::filesystem::path> inputs) {
  const std::string name = path.string();
  if (name.empty()) throw Error("the output has no name");
  struct stat st {};
  if (::stat(name.c_str(), &st) != 0) {
    if (errno != ENOENT) throw Error(fmt::format("{}: cannot write there: {}", name, std::strerror(errno)));
    const std::filesystem::path dir = path.parent_path().empty() ? std::filesystem::path(".") : path.parent_path();
    struct stat d {};
    if (::stat(dir.c_str(), &d) != 0 || !S_ISDIR(d.st_mode)) {
      throw Error(fmt::format("{}: the folder {} does not exist", name, dir.string()));
    }
    return;
  }
  if (S_ISDIR(st.st_mode)) {
    throw Error(fmt::format("{}: is a directory; give the output a file name (for example {})", name,
                            (path / "out.pstream").string()));
  }
  if (!S_ISREG(st.st_mode) && !S_ISCHR(st.st_mode)) {
    throw Error(fmt::format("{}: is {}; write to a regular file", name, kind_of(st.st_mode)));
  }
  for (const auto& input : inputs) {
    struct stat in {};
    if (::stat(input.string().c_str(), &in) == 0 && in.st_dev == st.st_dev && in.st_ino == st.st_ino) {
      throw Error(fmt::format("{}: is the input {}; writing it would destroy the input. Choose another output", name,
                              input.string()));
    }
  }
}

OutputFile OutputFile::create(const std::filesystem::path& path, std::span<const std::filesystem::path> inputs) {
  check_output(path, inputs);
  OutputFile out;
  out.path_ = path;
  const std::string name = path.string();
  struct stat st {};
  const bool exists = ::stat(name.c_str(), &st) == 0;
  out.buffer_.reserve(kBufferSize);
  if (exists && S_ISCHR(st.st_mode)) {  // /dev/null and the like: no temporary, no rename
    out.direct_ = true;
    out.fd_ = ::open(name.c_str(), O_WRONLY | O_CLOEXEC);
    if (out.fd_ < 0) throw Error(fmt::format("{}: cannot open: {}", name, std::strerror(errno)));
    return out;
  }
  const std::filesystem::path dir = path.parent_path();
  remove_stale_temporaries(dir);
  int err = 0;
  {
    const EndingSignalsWait wait;
    out.fd_ = create_locked_temporary(path, out.temp_);
    err = errno;
    if (out.fd_ >= 0) out.slot_ = register_temporary(out.temp_.string());
  }
  if (out.fd_ < 0) {
    const std::string folder = dir.empty() ? std::string(".") : dir.string();
    out.temp_.clear();
    throw Error(fmt::format("{}: cannot create a temporary in {}: {}", name, folder, std::strerror(err)));
  }
  return out;
}

OutputFile::OutputFile(OutputFile&& other) noexcept
    : path_(std::move(other.path_)),
      temp_(std::move(other.temp_)),
      fd_(std::exchange(other.fd_, -1)),
      slot_(std::exchange(other.slot_, -1)),
      direct_(other.direct_),
      end_(other.end_),
      flushed_(other.flushed_),
      buffer_(std::move(other.buffer_)) {}

OutputFile& OutputFile::operator=(OutputFile&& other) noexcept {
  if (this != &other) {
    discard();
    path_ = std::move(other.path_);
    temp_ = std::move(other.temp_);
    fd_ = std::exchange(other.fd_, -1);
    slot_ = std::exchange(other.slot_, -1);
    direct_ = other.direct_;
    end_ = other.end_;
    flushed_ = other.flushed_;
    buffer_ = std::move(other.buffer_);
  }
  return *this;
}

OutputFile::~OutputFile() { discard(); }

void OutputFile::discard() noexcept {
  if (!temp_.empty()) ::unlink(temp_.c_str());  // while still locked (see commit())
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  temp_.clear();
  unregister_temporary(std::exchange(slot_, -1));
}

void OutputFile::write_at(std::uint64_t offset, std::span<const std::byte> bytes) {
  if (fd_ < 0) throw Error(fmt::format("{}: write after the output was closed", path_.string()));
  if (offset + bytes.size() > flushed_ && !buffer_.empty()) flush();
  while (!bytes.empty()) {
    const ssize_t n = ::pwrite(fd_, bytes.data(), bytes.size(), static_cast<off_t>(offset));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      throw Error(fmt::format("{}: write of {} bytes at offset {} failed: {}", path_.string(), bytes.size(), offset,
                              n < 0 ? std::strerror(errno) : "no space left on device"));
    }
    bytes = bytes.subspan(static_cast<std::size_t>(n));
    offset += static_cast<std::uint64_t>(n);
  }
  end_ = std::max(end_, offset);
  flushed_ = std::max(flushed_, offset);
}

void OutputFile::flush() {
  if (buffer_.empty()) return;
  std::vector<std::byte> pending;
  pending.swap(buffer_);
  const std::uint64_t at = flushed_;
  buffer_.reserve(kBufferSize);
  write_at(at, pending);
}

void OutputFile::append(std::span<const std::byte> bytes) {
  if (bytes.size() >= kBufferSize) {
    flush();
    write_at(end_, bytes);
    return;
  }
  if (buffer_.size() + bytes.size() > kBufferSize) flush();
  buffer_.insert(buffer_.end(), bytes.begin(), bytes.end());
  end_ += bytes.size();
}

std::uint64_t OutputFile::commit() {
  if (fd_ < 0) throw Error(fmt::format("{}: commit after the output was closed", path_.string()));
  flush();
  if (!direct_ && ::fsync(fd_) != 0)
    throw Error(fmt::format("{}: cannot sync {}: {}", path_.string(), temp_.string(), std::strerror(errno)));
  // Renamed while the descriptor (and so the temporary's lock) is still held: once it is closed,
  // another process's cleanup may take the lock and remove the temporary as stale.
  if (!direct_) {
    if (::rename(temp_.c_str(), path_.c_str()) != 0) {
      throw Error(
          fmt::format("{}: cannot rename {} over it: {}", path_.string(), temp_.string(), std::strerror(errno)));
    }
    temp_.clear();
    unregister_temporary(std::exchange(slot_, -1));
  }
  const int fd = std::exchange(fd_, -1);
  if (::close(fd) != 0) throw Error(fmt::format("{}: cannot close: {}", path_.string(), std::strerror(errno)));
  return end_;
}

void write_file(const std::filesystem::path& path, std::span<const std::byte> bytes,
                std::span<const std::filesystem::path> inputs) {
  OutputFile out = OutputFile::create(path, inputs);
  out.append(bytes);
  out.commit();
}

void write_file(const std::filesystem::path& path, std::string_view text,
                std::span<const std::filesystem::path> inputs) {
  write_file(path, std::as_bytes(std::span(text.data(), text.size())), inputs);
}

std::uint64_t free_space(const std::filesystem::path& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) == 0 && !S_ISREG(st.st_mode)) return UINT64_MAX;
  std::filesystem::path dir = path.parent_path();
  if (dir.empty()) dir = ".";
  struct statvfs vfs {};
  if (::statvfs(dir.c_str(), &vfs) != 0) return UINT64_MAX;
  return static_cast<std::uint64_t>(vfs.f_bavail) * vfs.f_frsize;
}

ScratchFolder::ScratchFolder(std::string_view what) {
  std::error_code ec;
  const std::filesystem::path base = std::filesystem::temp_directory_path(ec);
  if (ec) {
    const char* tmpdir = std::getenv("TMPDIR");
    throw Error(fmt::format("no folder for temporary files: TMPDIR is '{}' ({})", tmpdir ? tmpdir : "", ec.message()));
  }
  std::string name = (base / fmt::format("pstream-{}-XXXXXX", what)).string();
  const char* made = nullptr;
  int error = 0;
  {
    const EndingSignalsWait wait;
    made = ::mkdtemp(name.data());
    error = errno;
    if (made != nullptr) slot_ = register_temporary(name, true);
  }
  if (made == nullptr) throw Error(fmt::format("{}: cannot make a scratch folder: {}", name, std::strerror(error)));
  path_ = name;
}

ScratchFolder::~ScratchFolder() {
  std::error_code ec;
  std::filesystem::remove_all(path_, ec);
  unregister_temporary(std::exchange(slot_, -1));
}

std::vector<std::string> open_temporaries() {
  std::lock_guard lock(temp_mutex);
  std::vector<std::string> out;
  for (int i = 0; i < kMaxTemporaries; ++i) {
    if (temp_used[static_cast<std::size_t>(i)].load()) out.emplace_back(temp_names[static_cast<std::size_t>(i)].data());
  }
  return out;
}

}  // namespace pstream
