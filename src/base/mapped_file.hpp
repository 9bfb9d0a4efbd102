// Reading input files: opening only regular files (never blocking on a FIFO or a device), and
// read-only memory mappings that survive the file being truncated while they are read.
#pragma once

#include <cstddef>
#include <filesystem>
#include <span>
#include <string>

namespace pstream {

// Opens `path` read-only. Refuses (pstream::Error naming the file) anything that is not a regular
// file: a FIFO, socket or device would block or never end. Never blocks. Returns the descriptor
// (close-on-exec, blocking reads) and stores the size in `size`.
int open_regular_file(const std::filesystem::path& path, std::uint64_t& size);

class MappedFile {
 public:
  // Maps the file read-only; throws pstream::Error naming the file and the OS error.
  //
  // Truncation while mapped: a read past the file's new end would raise SIGBUS. While a mapping
  // is open a SIGBUS handler puts a page of zeros in place of the missing one and marks the
  // mapping, so the reader sees zeros (which the parsers reject or the caller ignores) instead
  // of dying; check_intact() then reports it. Up to kMaxGuarded mappings are guarded at once.
  static MappedFile open(const std::filesystem::path& path);
  static constexpr int kMaxGuarded = 256;

  MappedFile() = default;
  MappedFile(MappedFile&& other) noexcept;
  MappedFile& operator=(MappedFile&& other) noexcept;
  MappedFile(const MappedFile&) = delete;
  MappedFile& operator=(const MappedFile&) = delete;
  ~MappedFile();

  std::span<const std::byte> bytes() const { return {data_, size_}; }
  const std::string& path() const { return path_; }

  // Throws pstream::Error ("FILE: the file was truncated while it was being read ...") when a
  // read of this mapping went past the file's end since it was opened.
  void check_intact() const;
  // The same for every mapping this process has had: the file that was truncated, or "".
  // Commands check it before they finish, whatever the error they met on the way.
  static std::string truncated_file();

 private:
  void release();
  const std::byte* data_ = nullptr;
  std::size_t size_ = 0;
  int slot_ = -1;  // in the guard table, -1 when not guarded
  std::string path_;
};

}  // namespace pstream
