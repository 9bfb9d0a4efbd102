#include <algorithm>
#include <cerrno>
#include <cstring>
#include <limits>
#include <utility>
#include <vector>

#include <fcntl.h>
#include <fmt/format.h>
#include <unistd.h>
#define XXH_STATIC_LINKING_ONLY  // XXH3_state_t as a complete type, held by value
#include <xxhash.h>

#include "base/output_file.hpp"
#include "particlestream/format.hpp"

namespace pstream::format {
namespace {

std::uint64_t align_up(std::uint64_t v, std::uint64_t a) { return (v + a - 1) / a * a; }

// Starts writing a finished chunk to the disk now, without waiting: the disk works while the
// next chunks are made, the final fsync has little left, and a multi-gigabyte cook does not
// pile up dirty pages. Linux only; elsewhere the fsync in commit() does it all.
void start_writeback([[maybe_unused]] int fd, [[maybe_unused]] std::uint64_t offset,
                     [[maybe_unused]] std::uint64_t size) {
#ifdef __linux__
  ::sync_file_range(fd, static_cast<off_t>(offset), static_cast<off_t>(size), SYNC_FILE_RANGE_WRITE);
#endif
}

}  // namespace

struct Writer::Output {
  OutputFile file;
};

// A raw chunk being written in pieces; it starts at position_ (which moves only when it ends).
struct Writer::RawChunk {
  XXH3_state_t hash{};  // in the chunk, not from XXH3_createState (malloc)
  std::uint64_t size = 0;
};

void Writer::write_at(std::uint64_t offset, std::span<const std::byte> bytes) { out_->file.write_at(offset, bytes); }

Writer::Writer(std::filesystem::path path, Metadata meta, std::span<const std::filesystem::path> inputs)
    : path_(std::move(path)), meta_(std::move(meta)) {
  meta_.version = kVersion;
  meta_.frames.clear();
  meta_.chunks.clear();
  meta_.record_size = record_size_of(meta_.layout);
  out_ = std::make_unique<Output>(Output{OutputFile::create(path_, inputs)});
  position_ = align_up(kHeaderSize, kChunkAlignment);
}

Writer::~Writer() = default;

void Writer::append_frame(std::uint64_t count, double time, std::array<float, 6> bounds) {
  if (meta_.codec.codec != FrameCodec::Records) {
    throw Error(
        fmt::format("{}: a {} frame needs its packet size", path_.string(), frame_codec_name(meta_.codec.codec)));
  }
  append_frame(count, time, bounds, count * meta_.record_size, true);
}

void Writer::append_frame(std::uint64_t count, double time, std::array<float, 6> bounds, std::uint64_t packet_size,
                          bool keyframe) {
  // A zero bound is stored as +0: whether a min/max meets -0 or +0 first depends on the order
  // particles are visited (SIMD lanes), and the bytes of a cook must not.
  for (float& b : bounds) b += 0.0f;
  FrameEntry f;
  f.count = count;
  f.byte_offset = meta_.decoded_size();
  f.time = time;
  f.bounds = bounds;
  f.packet_offset = meta_.stream_size();
  f.packet_size = packet_size;
  f.keyframe = keyframe;
  meta_.frames.push_back(f);
}

void Writer::append_chunk(const EncodedChunk& chunk) {
  append_chunk(chunk.stored, chunk.codec, chunk.codec_param, chunk.checksum);
}

void Writer::append_chunk(std::span<const std::byte> stored, Codec codec, std::uint32_t codec_param,
                          std::uint64_t sum) {
  if (raw_ && raw_->size != 0) throw Error(fmt::format("{}: a raw chunk was not ended", path_.string()));
  write_at(position_, stored);
  end_chunk(stored.size(), codec, codec_param, sum);
}

void Writer::append_raw_piece(std::span<const std::byte> bytes) {
  if (!raw_) raw_ = std::make_unique<RawChunk>();
  if (raw_->size == 0) XXH3_64bits_reset(&raw_->hash);
  write_at(position_ + raw_->size, bytes);
  XXH3_64bits_update(&raw_->hash, bytes.data(), bytes.size());
  raw_->size += bytes.size();
}

void Writer::append_stream(std::span<const std::byte> bytes) {
  while (!bytes.empty()) {
    const std::uint64_t filled = raw_ ? raw_->size : 0;
    const std::size_t take = static_cast<std::size_t>(std::min<std::uint64_t>(bytes.size(), meta_.chunk_size - filled));
    append_raw_piece(bytes.first(take));
    bytes = bytes.subspan(take);
    if (raw_->size == meta_.chunk_size) end_raw_chunk();
  }
}

void Writer::end_raw_chunk() {
  if (!raw_ || raw_->size == 0) throw Error(fmt::format("{}: end_raw_chunk() without a piece", path_.string()));
  end_chunk(std::exchange(raw_->size, 0), Codec::Raw, 0, XXH3_64bits_digest(&raw_->hash));
}

void Writer::end_chunk(std::uint64_t stored_size, Codec codec, std::uint32_t codec_param, std::uint64_t sum) {
  ChunkEntry e;
  e.file_offset = position_;
  e.stored_size = stored_size;
  e.checksum = sum;
  e.codec = codec;
  e.codec_param = codec_param;
  meta_.chunks.push_back(e);
  start_writeback(out_->file.descriptor(), position_, stored_size);
  position_ = align_up(position_ + stored_size, kChunkAlignment);
}

std::uint64_t Writer::commit() {
  // The stream's last chunk is shorter: append_stream() and raw pieces leave it open. (A chunk
  // ended too early or too late shows in the count below.)
  if (raw_ && raw_->size != 0) end_raw_chunk();
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
  out_->file.commit();
  return position_ + tables.size();
}

}  // namespace pstream::format
