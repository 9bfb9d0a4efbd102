// Frames kept on disk until they are cooked (cook.hpp: FrameSpool): an unnamed temporary file the
// frames' arrays are appended to, mapped as a MemoryClip at the end.
#include <fcntl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <vector>

#include <fmt/format.h>

#include "cook/source.hpp"

namespace pstream::cook {
namespace {

std::uint64_t padded(std::uint64_t bytes) { return (bytes + 7) / 8 * 8; }  // ids stay 8-byte aligned

}  // namespace

int unnamed_file(const std::filesystem::path& folder) {
  const int fd = ::open(folder.c_str(), O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
  if (fd >= 0) return fd;
  if (errno != EOPNOTSUPP && errno != EISDIR && errno != EINVAL) {
    throw Error(fmt::format("{}: cannot make the frame spool's temporary file there: {}", folder.string(),
                            std::strerror(errno)));
  }
  return named_then_unlinked_file(folder);
}

int named_then_unlinked_file(const std::filesystem::path& folder) {
  std::string path = (folder / ".pstream-spool-XXXXXX").string();
  const int fd = ::mkostemp(path.data(), O_CLOEXEC);
  if (fd < 0) {
    throw Error(fmt::format("{}: cannot make the frame spool's temporary file there: {}", folder.string(),
                            std::strerror(errno)));
  }
  if (::unlink(path.c_str()) != 0) {
    const int e = errno;
    ::close(fd);
    throw Error(
        fmt::format("{}: cannot unlink the frame spool's temporary file at once (so that none is left "
                    "behind): {}",
                    path, std::strerror(e)));
  }
  return fd;
}

struct FrameSpool::Impl {
  // A frame's arrays start at `offset`: those of `has` when it holds particles, none otherwise.
  struct Entry {
    double time = 0.0;
    std::uint64_t count = 0, offset = 0;
  };
  std::string name;
  std::filesystem::path folder;
  int fd = -1;
  std::uint64_t size = 0;  // bytes written
  std::vector<Entry> entries;
  MemoryAttributes has;  // of the frames with particles so far
  bool with_particles = false, drop_ids = false;
  const std::byte* map = nullptr;
  std::uint64_t mapped = 0;

  void unmap() {
    if (map != nullptr) ::munmap(const_cast<std::byte*>(map), mapped);
    map = nullptr;
    mapped = 0;
  }
  // Writes `bytes` at `at`, then zeros up to the next multiple of 8; every write checked.
  void write(std::uint64_t& at, std::span<const std::byte> bytes) {
    static constexpr std::byte kZeros[8] = {};
    const auto put = [&](const std::byte* data, std::size_t n) {
      while (n > 0) {
        const ssize_t w = ::pwrite(fd, data, n, static_cast<off_t>(at));
        if (w < 0 && errno == EINTR) continue;
        if (w <= 0) {
          throw Error(fmt::format("{}: writing frame {} to the frame spool's temporary file there failed: {}",
                                  folder.string(), entries.size(), w < 0 ? std::strerror(errno) : "nothing written"));
        }
        data += w;
        n -= static_cast<std::size_t>(w);
        at += static_cast<std::uint64_t>(w);
      }
    };
    put(bytes.data(), bytes.size());
    put(kZeros, padded(bytes.size()) - bytes.size());
  }
};

FrameSpool::FrameSpool(std::string name, const std::filesystem::path& folder) : impl_(std::make_unique<Impl>()) {
  impl_->name = std::move(name);
  impl_->folder = folder.empty() ? std::filesystem::temp_directory_path() : folder;
  impl_->fd = unnamed_file(impl_->folder);
}

FrameSpool::~FrameSpool() {
  if (!impl_) return;
  impl_->unmap();
  if (impl_->fd >= 0) ::close(impl_->fd);
}

FrameSpool::FrameSpool(FrameSpool&& other) noexcept = default;
FrameSpool& FrameSpool::operator=(FrameSpool&& other) noexcept {
  if (this != &other) {
    FrameSpool gone(std::move(*this));
    impl_ = std::move(other.impl_);
  }
  return *this;
}

void FrameSpool::check(const MemoryFrame& frame) const {
  const Impl& d = *impl_;
  const std::size_t index = d.entries.size();
  // The attributes are the first frame with particles' (cook() takes those of any frame with
  // particles: the same answer, or an error naming a frame).
  check_memory_frame(d.name, index, frame, !d.with_particles && frame.count > 0 ? attributes_of(frame) : d.has,
                     index > 0 ? d.entries.back().time : std::nan(""));
}

void FrameSpool::add(const MemoryFrame& frame) {
  Impl& d = *impl_;
  check(frame);
  if (!d.with_particles && frame.count > 0) d.has = attributes_of(frame);
  // Room for the entry before anything is written. A write that fails leaves the end where it
  // was: the next frame is written over what it wrote.
  if (d.entries.size() == d.entries.capacity()) d.entries.reserve(2 * d.entries.capacity() + 64);
  const Impl::Entry e{frame.time, frame.count, d.size};
  std::uint64_t at = d.size;
  d.write(at, std::as_bytes(frame.position));
  d.write(at, std::as_bytes(frame.width));
  d.write(at, std::as_bytes(frame.velocity));
  d.write(at, std::as_bytes(frame.color));
  for (const auto& [name, components] : d.has.floats) {  // in the spool's order, whatever the frame's
    if (const MemoryFloats* a = floats_named(frame, name); a != nullptr && frame.count > 0)
      d.write(at, std::as_bytes(a->values));
  }
  d.write(at, std::as_bytes(frame.id));
  d.size = at;
  d.with_particles = d.with_particles || frame.count > 0;
  d.entries.push_back(e);
}

void FrameSpool::drop_ids() { impl_->drop_ids = true; }
std::uint64_t FrameSpool::frames() const { return impl_->entries.size(); }
std::uint64_t FrameSpool::bytes() const { return impl_->size; }

MemoryClip FrameSpool::clip(std::string object, double fps) {
  Impl& d = *impl_;
  if (d.mapped != d.size) {
    d.unmap();
    if (d.size > 0) {
      void* p = ::mmap(nullptr, d.size, PROT_READ, MAP_SHARED, d.fd, 0);
      if (p == MAP_FAILED) {
        throw Error(fmt::format("{}: mapping the frame spool's temporary file ({} bytes) failed: {}", d.folder.string(),
                                d.size, std::strerror(errno)));
      }
      d.map = static_cast<const std::byte*>(p);
      d.mapped = d.size;
    }
  }
  MemoryClip clip;
  clip.name = d.name;
  clip.object = std::move(object);
  clip.fps = fps;
  clip.frames.reserve(d.entries.size());
  for (const Impl::Entry& e : d.entries) {
    MemoryFrame f;
    f.time = e.time;
    f.count = e.count;
    const std::byte* at = e.count > 0 ? d.map + e.offset : nullptr;
    const auto floats = [&](bool present, std::size_t components) {
      if (!present || e.count == 0) return std::span<const float>{};
      const std::span<const float> s(reinterpret_cast<const float*>(at), e.count * components);
      at += padded(s.size_bytes());
      return s;
    };
    f.position = floats(true, 3);
    f.width = floats(d.has.width, 1);
    f.velocity = floats(d.has.velocity, 3);
    f.color = floats(d.has.color, 4);
    if (e.count > 0) {
      for (const auto& [name, components] : d.has.floats)
        f.floats.push_back({name, components, floats(true, components)});
    }
    if (d.has.id && e.count > 0 && !d.drop_ids) f.id = {reinterpret_cast<const std::uint64_t*>(at), e.count};
    clip.frames.push_back(f);
  }
  return clip;
}

}  // namespace pstream::cook
