#include <algorithm>
#include <cerrno>
#include <cstring>
#include <limits>
#include <vector>

#include <fmt/format.h>
#include <unistd.h>

#include "particlestream/format.hpp"

namespace pstream::format {
namespace {

std::uint64_t align_up(std::uint64_t v, std::uint64_t a) { return (v + a - 1) / a * a; }

}  // namespace

void Writer::write_at(std::uint64_t offset, std::span<const std::byte> bytes) {
  const int fd = ::fileno(file_);
  while (!bytes.empty()) {
    const ssize_t n = ::pwrite(fd, bytes.data(), bytes.size(), static_cast<off_t>(offset));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0)
      throw Error(
          fmt::format("{}: write failed: {}", temp_path_.string(), n < 0 ? std::strerror(errno) : "disk full?"));
    bytes = bytes.subspan(static_cast<std::size_t>(n));
    offset += static_cast<std::uint64_t>(n);
  }
}

Writer::Writer(std::filesystem::path path, Metadata meta) : path_(std::move(path)), meta_(std::move(meta)) {
  meta_.frames.clear();
  meta_.chunks.clear();
  meta_.record_size = record_size_of(meta_.layout);
  // Same-directory temporary, so the final rename is atomic.
  temp_path_ = path_;
  temp_path_ += fmt::format(".tmp-{}", ::getpid());
  file_ = std::fopen(temp_path_.c_str(), "wb");
  if (file_ == nullptr) throw Error(fmt::format("{}: cannot create: {}", temp_path_.string(), std::strerror(errno)));
  position_ = align_up(kHeaderSize, kChunkAlignment);
}

Writer::~Writer() {
  if (file_ != nullptr) std::fclose(file_);
  if (!committed_) {
    std::error_code ec;
    std::filesystem::remove(temp_path_, ec);
  }
}

void Writer::append_frame(std::uint64_t count, double time, const std::array<float, 6>& bounds) {
  meta_.frames.push_back({count, meta_.stream_size(), time, bounds});
}

void Writer::append_chunk(const EncodedChunk& chunk) {
  append_chunk(chunk.stored, chunk.codec, chunk.codec_param, chunk.checksum);
}

void Writer::append_chunk(std::span<const std::byte> stored, Codec codec, std::uint32_t codec_param,
                          std::uint64_t sum) {
  ChunkEntry e;
  e.file_offset = position_;
  e.stored_size = stored.size();
  e.checksum = sum;
  e.codec = codec;
  e.codec_param = codec_param;
  write_at(position_, stored);
  position_ = align_up(position_ + stored.size(), kChunkAlignment);
  meta_.chunks.push_back(e);
}

std::uint64_t Writer::commit() {
  const std::uint64_t expected = (meta_.stream_size() + meta_.chunk_size - 1) / meta_.chunk_size;
  if (meta_.chunks.size() != expected) {
    throw Error(
        fmt::format("{}: {} chunks written, the frames need {}", path_.string(), meta_.chunks.size(), expected));
  }
  constexpr float inf = std::numeric_limits<float>::infinity();
  meta_.bounds = {inf, inf, inf, -inf, -inf, -inf};
  meta_.min_count = meta_.frames.empty() ? 0 : std::numeric_limits<std::uint64_t>::max();
  meta_.max_count = 0;
  double total = 0;
  for (const FrameEntry& f : meta_.frames) {
    meta_.min_count = std::min(meta_.min_count, f.count);
    meta_.max_count = std::max(meta_.max_count, f.count);
    total += static_cast<double>(f.count);
    for (int c = 0; c < 3; ++c) {
      meta_.bounds[c] = std::min(meta_.bounds[c], f.bounds[c]);
      meta_.bounds[c + 3] = std::max(meta_.bounds[c + 3], f.bounds[c + 3]);
    }
  }
  meta_.avg_count = meta_.frames.empty() ? 0.0 : total / static_cast<double>(meta_.frames.size());
  const std::vector<std::byte> tables = serialize_tables(meta_);
  const std::vector<std::byte> header = serialize_header(meta_, position_, tables);
  write_at(position_, tables);
  write_at(0, header);
  bool ok = ::fsync(::fileno(file_)) == 0;
  ok = (std::fclose(file_) == 0) && ok;
  file_ = nullptr;
  if (!ok) throw Error(fmt::format("{}: write failed: {}", temp_path_.string(), std::strerror(errno)));
  std::filesystem::rename(temp_path_, path_);
  committed_ = true;
  return position_ + tables.size();
}

}  // namespace pstream::format
