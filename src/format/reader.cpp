#include <algorithm>
#include <cstring>

#include <fmt/format.h>

#include "base/mapped_file.hpp"
#include "particlestream/format.hpp"

namespace pstream::format {

struct Reader::Impl {
  MappedFile mapping;
  std::span<const std::byte> bytes;
  std::string name;
  Metadata meta;
};

Reader::Reader(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Reader::Reader(Reader&&) noexcept = default;
Reader& Reader::operator=(Reader&&) noexcept = default;
Reader::~Reader() = default;

Reader Reader::open(const std::filesystem::path& path) {
  auto impl = std::make_unique<Impl>();
  impl->mapping = MappedFile::open(path);
  impl->bytes = impl->mapping.bytes();
  impl->name = path.string();
  impl->meta = parse_metadata(impl->bytes, impl->name);
  return Reader(std::move(impl));
}

Reader Reader::from_memory(std::span<const std::byte> bytes, std::string name) {
  auto impl = std::make_unique<Impl>();
  impl->bytes = bytes;
  impl->name = std::move(name);
  impl->meta = parse_metadata(bytes, impl->name);
  return Reader(std::move(impl));
}

const Metadata& Reader::metadata() const { return impl_->meta; }
const std::string& Reader::name() const { return impl_->name; }
std::uint64_t Reader::file_size() const { return impl_->bytes.size(); }

std::span<const std::byte> Reader::stored_chunk(std::uint64_t chunk) const {
  const ChunkEntry& c = impl_->meta.chunks.at(chunk);
  return impl_->bytes.subspan(c.file_offset, c.stored_size);
}

void Reader::read_chunk(std::uint64_t chunk, std::span<std::byte> out) const {
  const Metadata& m = impl_->meta;
  if (chunk >= m.chunk_count()) {
    throw Error(fmt::format("{}: chunk {} requested, the file has {}", impl_->name, chunk, m.chunk_count()));
  }
  const std::uint64_t raw = m.chunk_raw_size(chunk);
  if (out.size() < raw)
    throw Error(fmt::format("{}: buffer of {} bytes for chunk {} of {} bytes", impl_->name, out.size(), chunk, raw));
  decode_chunk(m.chunks[chunk], stored_chunk(chunk), out.first(raw),
               fmt::format("{}: chunk {} (file offset {})", impl_->name, chunk, m.chunks[chunk].file_offset));
}

void Reader::read_frame(std::uint64_t frame, std::span<std::byte> out, std::span<std::byte> scratch) const {
  const Metadata& m = impl_->meta;
  if (frame >= m.frame_count()) {
    throw Error(fmt::format("{}: frame {} requested, the file has {}", impl_->name, frame, m.frame_count()));
  }
  const FrameEntry& f = m.frames[frame];
  const std::uint64_t size = f.count * m.record_size;
  if (out.size() < size)
    throw Error(fmt::format("{}: buffer of {} bytes for frame {} of {} bytes", impl_->name, out.size(), frame, size));
  std::uint64_t pos = f.byte_offset, done = 0;
  while (done < size) {
    const std::uint64_t chunk = pos / m.chunk_size;
    const std::uint64_t within = pos - chunk * m.chunk_size;
    const std::uint64_t take = std::min(size - done, m.chunk_raw_size(chunk) - within);
    if (scratch.size() < m.chunk_raw_size(chunk)) {
      throw Error(fmt::format("{}: scratch buffer of {} bytes for chunk {} of {} bytes", impl_->name, scratch.size(),
                              chunk, m.chunk_raw_size(chunk)));
    }
    read_chunk(chunk, scratch);
    std::memcpy(out.data() + done, scratch.data() + within, take);
    done += take;
    pos += take;
  }
}

}  // namespace pstream::format
