// Local files as byte sources: pread on a descriptor, or a guarded read-only mapping.
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include <fmt/format.h>

#include "base/mapped_file.hpp"
#include "particlestream/io.hpp"

namespace pstream::io {
namespace {

class FileSource final : public ByteSource {
 public:
  // Regular files only: a FIFO without a writer would block the open forever.
  explicit FileSource(const std::filesystem::path& path) : name_(path.string()) {
    fd_ = open_regular_file(path, size_);
  }
  ~FileSource() override { ::close(fd_); }
  FileSource(const FileSource&) = delete;
  FileSource& operator=(const FileSource&) = delete;

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

class MappedSource final : public ByteSource {
 public:
  explicit MappedSource(const std::filesystem::path& path) : file_(MappedFile::open(path)), name_(path.string()) {}
  void read(std::uint64_t offset, std::span<std::byte> out) override {
    const auto bytes = file_.bytes();
    if (offset > bytes.size() || out.size() > bytes.size() - offset) {
      throw Error(fmt::format("{}: read of {} bytes at offset {} is past the end of the file ({} bytes)", name_,
                              out.size(), offset, bytes.size()));
    }
    std::memcpy(out.data(), bytes.data() + offset, out.size());
    file_.check_intact();
  }
  std::uint64_t size() const override { return file_.bytes().size(); }
  const std::string& name() const override { return name_; }
  std::span<const std::byte> mapped() const override { return file_.bytes(); }

 private:
  MappedFile file_;
  std::string name_;
};

}  // namespace

std::unique_ptr<ByteSource> open_file(const std::filesystem::path& path) { return std::make_unique<FileSource>(path); }
std::unique_ptr<ByteSource> open_mapped_file(const std::filesystem::path& path) {
  return std::make_unique<MappedSource>(path);
}

bool is_url(std::string_view location) {
  const auto starts = [&](std::string_view scheme) {
    if (location.size() < scheme.size()) return false;
    for (std::size_t i = 0; i < scheme.size(); ++i) {
      char c = location[i];
      if (c >= 'A' && c <= 'Z') c = static_cast<char>(c - 'A' + 'a');
      if (c != scheme[i]) return false;
    }
    return true;
  };
  return starts("http://") || starts("https://");
}

std::unique_ptr<ByteSource> open(const std::string& location) {
  return is_url(location) ? open_url(location) : open_file(location);
}

}  // namespace pstream::io
