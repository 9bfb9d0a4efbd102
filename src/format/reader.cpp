#include <algorithm>
#include <cstring>

#include <fmt/format.h>

#include "particlestream/codec.hpp"
#include "particlestream/format.hpp"

namespace pstream::format {
namespace {
constexpr std::uint64_t kNoChunk = UINT64_MAX;
// The decoder's saved states once frames are read going back (as the stream's default).
constexpr std::size_t kSavedStatesGoingBack = 3;
}  // namespace

struct Reader::Impl {
  std::unique_ptr<io::ByteSource> source;  // null for from_memory()
  std::span<const std::byte> bytes;        // the whole file, when it is in memory (mapped)
  std::uint64_t size = 0;
  std::vector<std::byte> fetched;  // a stored chunk read from a source not in memory
  std::string name;
  Metadata meta;
  // Decoding state, made on first use (a Reader is not for concurrent use).
  std::unique_ptr<ChunkDecoder> chunks;
  std::unique_ptr<FrameDecoder> frames;
  std::vector<std::byte> packet, scratch, decoded;
  // The chunk whose raw bytes `scratch` holds, checked, for read_frame(): the packets of the
  // frames read in turn mostly share a chunk, which is then read (fetched, checked, decompressed)
  // once instead of once per frame. kNoChunk when it holds none.
  std::uint64_t scratch_chunk = kNoChunk;
  std::uint64_t frames_decoded = 0;
  // A read went back: the decoder was made again with saved states (once; a Reader read forwards
  // never holds them).
  bool went_back = false;
};

Reader::Reader(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Reader::Reader(Reader&&) noexcept = default;
Reader& Reader::operator=(Reader&&) noexcept = default;
Reader::~Reader() = default;

Reader Reader::open(const std::filesystem::path& path) {
  const std::string location = path.string();
  return open(io::is_url(location) ? io::open_url(location) : io::open_mapped_file(path));
}

Reader Reader::open(std::unique_ptr<io::ByteSource> source) {
  auto impl = std::make_unique<Impl>();
  impl->name = source->name();
  impl->size = source->size();
  impl->bytes = source->mapped();
  if (!impl->bytes.empty() || impl->size == 0) {
    impl->meta = parse_metadata(impl->bytes, impl->name);
  } else {
    impl->meta = read_metadata(*source);
    std::uint64_t largest = 0;
    for (const ChunkEntry& c : impl->meta.chunks) largest = std::max(largest, c.stored_size);
    impl->fetched.resize(largest);
  }
  impl->source = std::move(source);
  return Reader(std::move(impl));
}

Metadata read_metadata(io::ByteSource& source) {
  // Header, then the tables it points at: two reads, whatever the file's size.
  const std::uint64_t size = source.size();
  std::vector<std::byte> head(std::min<std::uint64_t>(size, kHeaderSize));
  source.read(0, head);
  const Header header = parse_header(head, size, source.name());
  std::vector<std::byte> tables(header.tables_size);
  source.read(header.tables_offset, tables);
  return parse_tables(header, tables, source.name());
}

Reader Reader::from_memory(std::span<const std::byte> bytes, std::string name) {
  auto impl = std::make_unique<Impl>();
  impl->bytes = bytes;
  impl->size = bytes.size();
  impl->name = std::move(name);
  impl->meta = parse_metadata(bytes, impl->name);
  return Reader(std::move(impl));
}

const Metadata& Reader::metadata() const { return impl_->meta; }
const std::string& Reader::name() const { return impl_->name; }
std::uint64_t Reader::file_size() const { return impl_->size; }

std::span<const std::byte> Reader::stored_chunk(std::uint64_t chunk) const {
  Impl& d = *impl_;
  const ChunkEntry& c = d.meta.chunks.at(chunk);
  if (!d.bytes.empty() || !d.source) return d.bytes.subspan(c.file_offset, c.stored_size);
  const std::span<std::byte> out = std::span(d.fetched).first(c.stored_size);
  d.source->read(c.file_offset, out);
  return out;
}

void Reader::read_chunk(std::uint64_t chunk, std::span<std::byte> out) const {
  const Metadata& m = impl_->meta;
  if (chunk >= m.chunk_count()) {
    throw Error(fmt::format("{}: chunk {} requested, the file has {}", impl_->name, chunk, m.chunk_count()));
  }
  const std::uint64_t raw = m.chunk_raw_size(chunk);
  if (out.size() < raw)
    throw Error(fmt::format("{}: buffer of {} bytes for chunk {} of {} bytes", impl_->name, out.size(), chunk, raw));
  if (!impl_->chunks) impl_->chunks = std::make_unique<ChunkDecoder>();
  impl_->chunks->decode(m.chunks[chunk], stored_chunk(chunk), out.first(raw), impl_->name, chunk);
}

namespace {

// The frame's packet: a span of `scratch` when the packet lies in one chunk, else assembled in
// `out`. Chunks are read into `scratch` unless `held` says it holds that chunk already (kNoChunk:
// none); it is updated as chunks are read.
std::span<const std::byte> packet_bytes(const Reader& reader, std::uint64_t frame, std::span<std::byte> out,
                                        std::span<std::byte> scratch, std::uint64_t& held) {
  const Metadata& m = reader.metadata();
  if (frame >= m.frame_count()) {
    throw Error(fmt::format("{}: frame {} requested, the file has {}", reader.name(), frame, m.frame_count()));
  }
  const FramePacket p = frame_packet(m, frame);
  if (out.size() < p.size) {
    throw Error(fmt::format("{}: buffer of {} bytes for frame {}'s packet of {} bytes", reader.name(), out.size(),
                            frame, p.size));
  }
  std::uint64_t pos = p.offset, done = 0;
  while (done < p.size) {
    const std::uint64_t chunk = pos / m.chunk_size;
    const std::uint64_t within = pos - chunk * m.chunk_size;
    const std::uint64_t take = std::min(p.size - done, m.chunk_raw_size(chunk) - within);
    if (scratch.size() < m.chunk_raw_size(chunk)) {
      throw Error(fmt::format("{}: scratch buffer of {} bytes for chunk {} of {} bytes", reader.name(), scratch.size(),
                              chunk, m.chunk_raw_size(chunk)));
    }
    if (held != chunk) {
      held = kNoChunk;  // until the chunk is read whole and checked
      reader.read_chunk(chunk, scratch);
      held = chunk;
    }
    if (take == p.size) return scratch.subspan(within, take);  // the whole packet in one chunk
    std::memcpy(out.data() + done, scratch.data() + within, take);
    done += take;
    pos += take;
  }
  return out.first(p.size);
}

}  // namespace

void Reader::read_packet(std::uint64_t frame, std::span<std::byte> out, std::span<std::byte> scratch) const {
  std::uint64_t held = kNoChunk;  // the caller's scratch holds nothing of ours
  const std::span<const std::byte> packet = packet_bytes(*this, frame, out, scratch, held);
  if (packet.data() != out.data() && !packet.empty()) std::memcpy(out.data(), packet.data(), packet.size());
}

std::uint64_t Reader::frames_decoded() const { return impl_->frames_decoded; }

std::size_t Reader::read_frame(std::uint64_t frame, std::span<std::byte> out, std::span<MatchRun> matching) const {
  Impl& d = *impl_;
  const Metadata& m = d.meta;
  if (frame >= m.frame_count()) {
    throw Error(fmt::format("{}: frame {} requested, the file has {}", d.name, frame, m.frame_count()));
  }
  if (out.size() < m.frames[frame].count * m.record_size) {
    throw Error(fmt::format("{}: buffer of {} bytes for frame {} of {} bytes", d.name, out.size(), frame,
                            m.frames[frame].count * m.record_size));
  }
  if (!d.frames) {
    d.frames = std::make_unique<FrameDecoder>(m, d.name);
    std::uint64_t largest = 0;
    for (std::uint64_t f = 0; f < m.frame_count(); ++f) largest = std::max(largest, frame_packet(m, f).size);
    d.packet.resize(largest);
    d.scratch.resize(std::min(m.chunk_size, m.stream_size()));
    d.decoded = frame_buffer(m, d.name);
  }
  // The first read that goes back (to a frame a keyframe does not start, at or before the last
  // one read) makes the decoder again with saved states, as many as fit beside it in what the
  // clip's stored bytes justify: each later read back resumes from the nearest one saved on the
  // way, instead of from the keyframe.
  const std::uint64_t last = d.frames->last_decoded();
  if (!d.went_back && last != UINT64_MAX && frame <= last && !m.frames[frame].keyframe) {
    d.went_back = true;
    const std::size_t states =
        FrameDecoder::saved_states_that_fit(m, kSavedStatesGoingBack, unbudgeted_memory_limit(m), d.decoded.size());
    if (states != 0) {
      d.frames.reset();  // its state goes before the new one is allocated
      d.frames = std::make_unique<FrameDecoder>(m, d.name, 0, states);
    }
  }
  // Forward from the keyframe, or on from the frame decoded last or a state saved on the way.
  d.frames->set_target(frame);
  std::size_t runs = kNoMatching;
  for (std::uint64_t f = d.frames->resume_frame(frame); f <= frame; ++f) {
    const std::span<const std::byte> packet = packet_bytes(*this, f, d.packet, d.scratch, d.scratch_chunk);
    ++d.frames_decoded;
    // Frames on the way are decoded aside: they may hold more particles than `out`.
    if (f == frame)
      runs = d.frames->decode(f, packet, out, matching);
    else
      d.frames->decode(f, packet, std::span(d.decoded));
  }
  return runs;
}

}  // namespace pstream::format
