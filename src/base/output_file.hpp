// Writing outputs so that no file is ever lost: an output appears complete or not at all, never
// replaces one of the command's inputs, and leaves no temporary behind on an error or a signal.
#pragma once

#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace pstream {

class OutputFile {
 public:
  // Opens `path` for writing.
  // - A regular file, or a name that does not exist yet: the bytes go to a temporary beside it,
  //   `.NAME.partial-TAG` (TAG random, NAME shortened to fit NAME_MAX), renamed over `path` by
  //   commit(). Until then `path` is untouched. The temporary is exclusively flock()ed while this
  //   object lives: that lock, not a process id, tells other processes (other PID namespaces,
  //   other hosts on a shared folder) that it is in use.
  // - A character device (/dev/null): written directly; commit() only checks the writes.
  // - A directory, FIFO, socket or block device: refused.
  // - The same file (device and inode) as one of `inputs`: refused, it would destroy its input.
  // Temporaries in the same folder whose lock nobody holds (their writer was SIGKILLed) are removed
  // first.
  // SIGINT, SIGTERM and SIGHUP remove every open temporary before the process ends.
  static OutputFile create(const std::filesystem::path& path, std::span<const std::filesystem::path> inputs = {});

  OutputFile() = default;
  OutputFile(OutputFile&& other) noexcept;
  OutputFile& operator=(OutputFile&& other) noexcept;
  OutputFile(const OutputFile&) = delete;
  OutputFile& operator=(const OutputFile&) = delete;
  ~OutputFile();  // not committed: the temporary is removed

  // Appends at the end of what was written (buffered).
  void append(std::span<const std::byte> bytes);
  void append(const void* data, std::size_t size) { append({static_cast<const std::byte*>(data), size}); }
  // Writes at `offset` (unbuffered; pending appends are written first). Every write is checked:
  // a failure throws pstream::Error naming the output and the OS error (disk full, ...).
  void write_at(std::uint64_t offset, std::span<const std::byte> bytes);
  std::uint64_t size() const { return end_; }  // bytes appended or written so far (the end)
  int descriptor() const { return fd_; }
  const std::filesystem::path& path() const { return path_; }
  // The temporary being written (empty for a device): another program may write it in place (a
  // video from ffmpeg) while this object holds its lock; commit() then renames what it wrote.
  const std::filesystem::path& temporary() const { return temp_; }

  // Flushes, syncs, closes and renames the temporary over the output. Returns the size.
  std::uint64_t commit();

 private:
  void flush();
  void discard() noexcept;
  std::filesystem::path path_, temp_;
  int fd_ = -1;
  int slot_ = -1;  // in the signal-cleanup table
  bool direct_ = false;
  std::uint64_t end_ = 0, flushed_ = 0;
  std::vector<std::byte> buffer_;
};

// A private folder for a command's scratch files (a clip a benchmark generates and reads back) in
// the system's temporary folder ($TMPDIR, else /tmp), named pstream-WHAT-XXXXXX. It goes with
// everything in it when this object goes, and on SIGINT, SIGTERM or SIGHUP as OutputFile's
// temporaries do; files go at its top level (the signal handler empties one level).
class ScratchFolder {
 public:
  explicit ScratchFolder(std::string_view what);  // throws pstream::Error naming the folder
  ScratchFolder(const ScratchFolder&) = delete;
  ScratchFolder& operator=(const ScratchFolder&) = delete;
  ~ScratchFolder();
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
  int slot_ = -1;  // in the signal-cleanup table
};

// The checks create() makes, without creating anything: a command calls it before long work.
void check_output(const std::filesystem::path& path, std::span<const std::filesystem::path> inputs = {});

// Writes `bytes` as the whole of `path` through an OutputFile.
void write_file(const std::filesystem::path& path, std::span<const std::byte> bytes,
                std::span<const std::filesystem::path> inputs = {});
void write_file(const std::filesystem::path& path, std::string_view text,
                std::span<const std::filesystem::path> inputs = {});

// Bytes free for an unprivileged writer in the file system that holds `path` (or its folder when it
// does not exist yet); the maximum when it cannot be told (a device, /dev/null).
std::uint64_t free_space(const std::filesystem::path& path);

// The temporaries of this process's open outputs, for tests.
std::vector<std::string> open_temporaries();

}  // namespace pstream
