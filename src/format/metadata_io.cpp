// Header and tables of a .pstream: serialisation and validated parsing (docs/format.md).
#include <bit>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>

#include <fmt/format.h>

#include "particlestream/codec.hpp"
#include "particlestream/format.hpp"

namespace pstream::format {
namespace {

constexpr char kMagic[8] = {'P', 'S', 'T', 'R', 'E', 'A', 'M', '\0'};
constexpr std::size_t kAttributeEntrySize = 40;
constexpr std::size_t kFrameEntrySizeV1 = 48;
constexpr std::size_t kFrameEntrySize = 64;
constexpr std::size_t kWordCodingEntrySize = 16;
constexpr std::size_t kChunkEntrySize = 32;
constexpr std::size_t kHeaderChecksumAtV1 = 152;
constexpr std::size_t kHeaderChecksumAt = 184;
constexpr std::uint32_t kFrameFlagKeyframe = 1;

std::size_t header_size_of(std::uint32_t version) { return version == 1 ? kHeaderSizeV1 : kHeaderSize; }
std::size_t header_checksum_at(std::uint32_t version) { return version == 1 ? kHeaderChecksumAtV1 : kHeaderChecksumAt; }
std::size_t frame_entry_size(std::uint32_t version) { return version == 1 ? kFrameEntrySizeV1 : kFrameEntrySize; }

class Out {
 public:
  explicit Out(std::vector<std::byte>& buf) : buf_(buf) {}
  template <class T>
  void put(T v) {
    bytes(&v, sizeof(T));
  }
  void bytes(const void* p, std::size_t n) {
    const std::size_t at = buf_.size();
    buf_.resize(at + n);
    if (n != 0) std::memcpy(buf_.data() + at, p, n);
  }
  void str(const std::string& s) {
    put(static_cast<std::uint32_t>(s.size()));
    bytes(s.data(), s.size());
  }

 private:
  std::vector<std::byte>& buf_;
};

class In {
 public:
  In(std::span<const std::byte> bytes, std::uint64_t base, std::string_view name)
      : bytes_(bytes), base_(base), name_(name) {}
  template <class T>
  T get(std::string_view field) {
    need(sizeof(T), field);
    T v;
    std::memcpy(&v, bytes_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  std::string str(std::string_view field) {
    const auto n = get<std::uint32_t>(field);
    need(n, field);
    std::string s(reinterpret_cast<const char*>(bytes_.data() + pos_), n);
    pos_ += n;
    return s;
  }
  void skip(std::size_t n, std::string_view field) {
    need(n, field);
    pos_ += n;
  }
  std::uint64_t offset() const { return base_ + pos_; }
  std::size_t pos() const { return pos_; }
  [[noreturn]] void fail(std::string_view what) const {
    throw Error(fmt::format("{}: at offset {}: {}", name_, offset(), what));
  }

 private:
  void need(std::size_t n, std::string_view field) const {
    if (bytes_.size() - pos_ < n) {
      fail(fmt::format("{} needs {} bytes but the tables end after {} (truncated or corrupted)", field, n,
                       bytes_.size() - pos_));
    }
  }
  std::span<const std::byte> bytes_;
  std::uint64_t base_;
  std::size_t pos_ = 0;
  std::string_view name_;
};

// The particle codec's word table must describe the record layout: each word's coding (a small
// type, word_codings.cpp) says whether it can code that word.
template <class Fail>
void validate_word_codings(const Metadata& m, Fail fail) {
  for (const Attribute& a : m.layout) {
    for (std::uint32_t w = a.offset / 4; w < (a.offset + a.size()) / 4; ++w) {
      const WordCodingEntry& e = m.codec.words[w];
      const WordCodingType* type = find_word_coding(e.coding);
      if (type == nullptr) {
        fail(fmt::format("record word {} ('{}') has unknown coding {}", w, a.name, static_cast<int>(e.coding)));
        continue;
      }
      if (std::string why = type->check(m, a, w, e); !why.empty()) fail(why);
    }
  }
}

std::vector<std::byte> tables_bytes(const Metadata& m) {
  std::vector<std::byte> t;
  Out out(t);
  out.str(m.source_file);
  out.str(m.source_object);
  out.str(m.cooked_with);
  for (const Attribute& a : m.layout) {
    char name[kAttributeNameSize] = {};
    std::memcpy(name, a.name.data(), std::min(a.name.size(), kAttributeNameSize - 1));
    out.bytes(name, sizeof name);
    out.put(static_cast<std::uint8_t>(a.type));
    out.put(a.components);
    out.put(std::uint16_t{0});
    out.put(a.offset);
  }
  if (m.codec.codec == FrameCodec::Particle) {
    for (const WordCodingEntry& w : m.codec.words) {
      out.put(static_cast<std::uint8_t>(w.coding));
      out.put(std::uint8_t{0});
      out.put(std::uint16_t{0});
      out.put(w.step);
      out.put(w.error);
      out.put(w.base);
    }
  }
  for (const FrameEntry& f : m.frames) {
    out.put(f.count);
    out.put(f.byte_offset);
    out.put(f.time);
    for (float b : f.bounds) out.put(b);
    out.put(f.packet_offset);
    out.put(static_cast<std::uint32_t>(f.packet_size));
    out.put(f.keyframe ? kFrameFlagKeyframe : 0u);
  }
  for (const ChunkEntry& c : m.chunks) {
    out.put(c.file_offset);
    out.put(c.stored_size);
    out.put(c.checksum);
    out.put(static_cast<std::uint16_t>(c.codec));
    out.put(std::uint16_t{0});
    out.put(c.codec_param);
  }
  return t;
}

}  // namespace

std::vector<std::byte> serialize_tables(const Metadata& m) { return tables_bytes(m); }

std::vector<std::byte> serialize_header(const Metadata& m, std::uint64_t tables_offset,
                                        std::span<const std::byte> tables) {
  std::vector<std::byte> h;
  Out out(h);
  out.bytes(kMagic, sizeof kMagic);
  out.put(m.version);
  out.put(static_cast<std::uint32_t>(kHeaderSize));
  out.put(m.flags);
  out.put(m.fps);
  out.put(m.time_of_frame0);
  out.put(m.frame_count());
  out.put(m.chunk_size);
  out.put(m.chunk_count());
  out.put(m.stream_size());
  out.put(m.record_size);
  out.put(static_cast<std::uint32_t>(m.layout.size()));
  out.put(m.min_count);
  out.put(m.max_count);
  out.put(m.avg_count);
  for (float b : m.bounds) out.put(b);
  out.put(tables_offset);
  out.put(static_cast<std::uint64_t>(tables.size()));
  out.put(checksum(tables));
  out.put(static_cast<std::uint32_t>(m.codec.codec));
  out.put(static_cast<std::uint8_t>(m.codec.order));
  out.put(static_cast<std::uint8_t>(m.codec.lossless ? 1 : 0));
  out.put(std::uint16_t{0});
  out.put(m.codec.keyframe_interval);
  out.put(std::uint32_t{0});
  out.put(m.codec.error);
  out.put(std::uint64_t{0});
  out.put(checksum(std::span(h).first(kHeaderChecksumAt)));
  return h;
}

Metadata parse_metadata(std::span<const std::byte> bytes, std::string_view name) {
  const Header header = parse_header(bytes, bytes.size(), name);
  if (header.tables_offset + header.tables_size > bytes.size()) {
    throw Error(fmt::format("{}: truncated: the tables lie at bytes {}..{} but the file has {} bytes", name,
                            header.tables_offset, header.tables_offset + header.tables_size, bytes.size()));
  }
  return parse_tables(header, bytes.subspan(header.tables_offset, header.tables_size), name);
}

void check_magic(std::span<const std::byte> bytes, std::string_view name) {
  if (bytes.size() >= sizeof kMagic && std::memcmp(bytes.data(), kMagic, sizeof kMagic) == 0) return;
  // A source a user meant to cook: every reader of .pstream files says the same (the CLI, the C
  // API, Python).
  const std::string_view head(reinterpret_cast<const char*>(bytes.data()), std::min<std::size_t>(bytes.size(), 8));
  const bool alembic = head.starts_with("Ogawa") || (head.size() >= 4 && head.substr(1, 3) == "HDF");
  if (alembic || head.starts_with("ply")) {
    const std::filesystem::path p(name);
    throw Error(fmt::format("{}: is {}, not a cooked clip; cook it first: pstream cook {} -o {}", name,
                            alembic ? "an Alembic archive" : "a PLY file", name,
                            (p.parent_path() / p.stem()).string() + ".pstream"));
  }
  throw Error(fmt::format("{}: at offset 0: not a .pstream file (expected the magic \"PSTREAM\\0\")", name));
}

Header parse_header(std::span<const std::byte> bytes, std::uint64_t file_size, std::string_view name) {
  if (bytes.empty()) throw Error(fmt::format("{}: empty file (expected a .pstream)", name));
  check_magic(bytes, name);
  if (bytes.size() < kHeaderSizeV1) {
    throw Error(fmt::format("{}: truncated: {} bytes, the header alone has {}", name, bytes.size(), kHeaderSizeV1));
  }
  In h(bytes, 0, name);
  h.skip(sizeof kMagic, "magic");
  Header header;
  header.file_size = file_size;
  Metadata& m = header.meta;
  m.version = h.get<std::uint32_t>("version");
  if (m.version < 1 || m.version > kVersion)
    h.fail(fmt::format("unsupported format version {} (this build reads versions 1 to {})", m.version, kVersion));
  const std::size_t expected_header_size = header_size_of(m.version);
  const auto header_size = h.get<std::uint32_t>("header_size");
  if (header_size != expected_header_size)
    h.fail(fmt::format("header_size is {}, expected {} for version {}", header_size, expected_header_size, m.version));
  if (bytes.size() < expected_header_size) {
    throw Error(fmt::format("{}: truncated: {} bytes, the version {} header alone has {}", name, bytes.size(),
                            m.version, expected_header_size));
  }
  const std::size_t sum_at = header_checksum_at(m.version);
  std::uint64_t stored_header_sum = 0;
  std::memcpy(&stored_header_sum, bytes.data() + sum_at, 8);
  if (!checksum_matches(bytes.first(sum_at), stored_header_sum)) {
    throw Error(fmt::format("{}: at offset {}: header checksum mismatch (the header is corrupted)", name, sum_at));
  }
  m.flags = h.get<std::uint64_t>("flags");
  if ((m.flags & ~(kFlagXformsBaked | kFlagInterpolated)) != 0)
    h.fail(fmt::format("flags {:#x} has bits this version does not define (expected only bits 0 and 1)", m.flags));
  m.fps = h.get<double>("fps");
  if (!(m.fps > 0.0) || !std::isfinite(m.fps)) h.fail(fmt::format("fps is {}, expected a positive number", m.fps));
  m.time_of_frame0 = h.get<double>("time_of_frame0");
  if (!(std::abs(m.time_of_frame0) <= kMaxTime)) {
    h.fail(fmt::format("time_of_frame0 is {}, expected a finite time within +-{:g} s", m.time_of_frame0, kMaxTime));
  }
  header.frame_count = h.get<std::uint64_t>("frame_count");
  m.chunk_size = h.get<std::uint64_t>("chunk_size");
  if (!std::has_single_bit(m.chunk_size) || m.chunk_size < kMinChunkSize || m.chunk_size > kMaxChunkSize) {
    h.fail(fmt::format("chunk_size is {}, expected a power of two from {} to {}", m.chunk_size, kMinChunkSize,
                       kMaxChunkSize));
  }
  header.chunk_count = h.get<std::uint64_t>("chunk_count");
  header.stream_size = h.get<std::uint64_t>("stream_size");
  m.record_size = h.get<std::uint32_t>("record_size");
  if (m.record_size < 16 || m.record_size % 4 != 0 || m.record_size > 4096) {
    h.fail(fmt::format("record_size is {}, expected a multiple of 4 from 16 to 4096", m.record_size));
  }
  header.attribute_count = h.get<std::uint32_t>("attribute_count");
  if (header.attribute_count < 2 || header.attribute_count > kMaxAttributes) {
    h.fail(fmt::format("attribute_count is {}, expected 2 to {}", header.attribute_count, kMaxAttributes));
  }
  m.min_count = h.get<std::uint64_t>("min_count");
  m.max_count = h.get<std::uint64_t>("max_count");
  m.avg_count = h.get<double>("avg_count");
  for (float& b : m.bounds) b = h.get<float>("bounds");
  for (int axis = 0; axis < 3; ++axis) {  // each axis finite min <= max, or empty (+inf .. -inf)
    const float lo = m.bounds[std::size_t(axis)], hi = m.bounds[std::size_t(axis + 3)];
    const bool empty = lo == std::numeric_limits<float>::infinity() && hi == -std::numeric_limits<float>::infinity();
    if (!empty && !(std::isfinite(lo) && std::isfinite(hi) && lo <= hi)) {
      h.fail(fmt::format("bounds on axis {} are {} .. {}, expected finite min <= max (or +inf .. -inf: no particle)",
                         "xyz"[axis], lo, hi));
    }
  }
  header.tables_offset = h.get<std::uint64_t>("tables_offset");
  header.tables_size = h.get<std::uint64_t>("tables_size");
  header.tables_checksum = h.get<std::uint64_t>("tables_checksum");
  if (m.version >= 2) {
    const auto codec = h.get<std::uint32_t>("frame_codec");
    if (find_frame_codec(static_cast<FrameCodec>(codec)) == nullptr) {
      std::string known;
      for (const FrameCodecDecoding& c : frame_codec_decoders())
        known += fmt::format("{}{} {}", known.empty() ? "" : ", ", static_cast<int>(c.id), c.name);
      h.fail(fmt::format("unknown frame codec {} (this build knows {})", codec, known));
    }
    m.codec.codec = static_cast<FrameCodec>(codec);
    const auto order = h.get<std::uint8_t>("frame_order");
    if (order > static_cast<std::uint8_t>(FrameOrder::Matched)) h.fail(fmt::format("unknown frame order {}", order));
    m.codec.order = static_cast<FrameOrder>(order);
    const auto lossless = h.get<std::uint8_t>("lossless");
    if (lossless > 1) h.fail(fmt::format("lossless is {}, expected 0 or 1", lossless));
    m.codec.lossless = lossless == 1;
    if (h.get<std::uint16_t>("reserved") != 0) h.fail("reserved header bytes are not 0");
    m.codec.keyframe_interval = h.get<std::uint32_t>("keyframe_interval");
    if (h.get<std::uint32_t>("reserved") != 0) h.fail("reserved header bytes are not 0");
    m.codec.error = h.get<double>("error");
    if (h.get<std::uint64_t>("reserved") != 0) h.fail("reserved header bytes are not 0");
    const bool particle = m.codec.codec == FrameCodec::Particle;
    if (particle ? (m.codec.keyframe_interval < 1 || m.codec.keyframe_interval > kMaxKeyframeInterval)
                 : m.codec.keyframe_interval != 1) {
      h.fail(fmt::format("keyframe_interval is {}, expected {}", m.codec.keyframe_interval,
                         particle ? fmt::format("1 to {}", kMaxKeyframeInterval) : std::string("1")));
    }
    if (!(m.codec.error >= 0.0) || !std::isfinite(m.codec.error))
      h.fail(fmt::format("error bound is {}, expected a finite number >= 0", m.codec.error));
  }
  if (header.tables_offset < expected_header_size || header.tables_offset > file_size ||
      header.tables_size > file_size - header.tables_offset) {
    h.fail(fmt::format("the tables at bytes {}..{} lie outside the file of {} bytes (truncated or corrupted)",
                       header.tables_offset, header.tables_offset + header.tables_size, file_size));
  }
  return header;
}

Metadata parse_tables(const Header& header, std::span<const std::byte> tables, std::string_view name) {
  Metadata m = header.meta;
  const std::uint64_t frame_count = header.frame_count, chunk_count = header.chunk_count;
  const std::uint64_t stream_size = header.stream_size, attribute_count = header.attribute_count;
  const std::uint64_t tables_size = tables.size();
  if (tables_size != header.tables_size) {
    throw Error(fmt::format("{}: {} table bytes given, the header says {}", name, tables_size, header.tables_size));
  }
  // Counts must fit in the tables before anything is allocated for them.
  const std::size_t frame_entry = frame_entry_size(m.version);
  const bool particle = m.codec.codec == FrameCodec::Particle;
  const std::uint64_t word_entries = particle ? m.record_size / 4 : 0;
  const std::uint64_t fixed = attribute_count * kAttributeEntrySize + word_entries * kWordCodingEntrySize;
  if (frame_count > tables_size / frame_entry || chunk_count > tables_size / kChunkEntrySize ||
      fixed + frame_count * frame_entry + chunk_count * kChunkEntrySize > tables_size) {
    throw Error(
        fmt::format("{}: tables of {} bytes cannot hold {} attributes, {} frames and {} chunks (corrupted counts)",
                    name, tables_size, attribute_count, frame_count, chunk_count));
  }
  if (!checksum_matches(tables, header.tables_checksum)) {
    throw Error(fmt::format("{}: at offset {}: tables checksum mismatch (the frame index or chunk table is corrupted)",
                            name, header.tables_offset));
  }

  In t(tables, header.tables_offset, name);
  m.source_file = t.str("source file name");
  m.source_object = t.str("source object name");
  m.cooked_with = t.str("cook command");
  for (std::uint32_t i = 0; i < attribute_count; ++i) {
    Attribute a;
    char raw_name[kAttributeNameSize];
    for (char& c : raw_name) c = static_cast<char>(t.get<std::uint8_t>("attribute name"));
    a.name.assign(raw_name, strnlen(raw_name, kAttributeNameSize));
    const auto type = t.get<std::uint8_t>("attribute type");
    if (type > static_cast<std::uint8_t>(AttributeType::Uint64))
      t.fail(fmt::format("attribute {} has unknown type {}", i, type));
    a.type = static_cast<AttributeType>(type);
    a.components = t.get<std::uint8_t>("attribute components");
    t.skip(2, "attribute reserved");
    a.offset = t.get<std::uint32_t>("attribute offset");
    if (a.components == 0 || a.components > 16 || a.offset % 4 != 0 || a.offset + a.size() > m.record_size) {
      t.fail(fmt::format("attribute '{}' ({} x {} at offset {}) does not fit a {}-byte record", a.name, a.components,
                         attribute_type_name(a.type), a.offset, m.record_size));
    }
    m.layout.push_back(std::move(a));
  }
  // Names: unique, and text every tool can print and write (valid UTF-8 without control
  // characters); attributes in record order covering it exactly, each at the 4-byte-aligned end
  // of the one before.
  std::uint32_t expected_offset_in_record = 0;
  for (std::size_t i = 0; i < m.layout.size(); ++i) {
    const Attribute& a = m.layout[i];
    if (!is_valid_name(a.name)) {
      t.fail(fmt::format("attribute {} has the name \"{}\", expected non-empty UTF-8 text without control characters",
                         i, escaped_name(a.name)));
    }
    for (std::size_t j = 0; j < i; ++j) {
      if (m.layout[j].name == a.name) t.fail(fmt::format("attributes {} and {} are both named '{}'", j, i, a.name));
    }
    if (a.offset != expected_offset_in_record) {
      t.fail(fmt::format("attribute '{}' is at offset {} of the record, expected {} (the end of the one before)",
                         a.name, a.offset, expected_offset_in_record));
    }
    expected_offset_in_record = (a.offset + a.size() + 3) / 4 * 4;
  }
  if (expected_offset_in_record != m.record_size) {
    t.fail(fmt::format("the attributes cover {} bytes of the {}-byte record, expected all of it",
                       expected_offset_in_record, m.record_size));
  }
  const auto& L = m.layout;
  const std::vector<Attribute> head = default_layout();
  if (L[0].name != head[0].name || L[0].type != head[0].type || L[0].components != head[0].components ||
      L[0].offset != head[0].offset || L[1].name != head[1].name || L[1].type != head[1].type ||
      L[1].components != head[1].components || L[1].offset != head[1].offset) {
    t.fail(fmt::format("the record layout must start with position float32x3 at {} and scale float32 at {}",
                       head[0].offset, head[1].offset));
  }
  if (particle) {
    m.codec.words.resize(word_entries);
    for (std::uint64_t w = 0; w < word_entries; ++w) {
      WordCodingEntry& e = m.codec.words[w];
      const auto coding = t.get<std::uint8_t>("word coding");
      t.skip(3, "word coding reserved");
      e.step = t.get<float>("word step");
      e.error = t.get<float>("word error");
      e.base = t.get<std::uint32_t>("word base");
      if (find_word_coding(static_cast<WordCoding>(coding)) == nullptr)
        t.fail(fmt::format("record word {} has unknown coding {}", w, coding));
      e.coding = static_cast<WordCoding>(coding);
    }
    validate_word_codings(m, [&](const std::string& what) { t.fail(what); });
  }
  std::uint64_t expected_offset = 0, expected_packet = 0, min_count = UINT64_MAX, max_count = 0, since_key = 0;
  for (std::uint64_t i = 0; i < frame_count; ++i) {
    FrameEntry f;
    f.count = t.get<std::uint64_t>("frame count");
    f.byte_offset = t.get<std::uint64_t>("frame byte_offset");
    f.time = t.get<double>("frame time");
    for (float& b : f.bounds) b = t.get<float>("frame bounds");
    if (m.version >= 2) {
      f.packet_offset = t.get<std::uint64_t>("frame packet_offset");
      f.packet_size = t.get<std::uint32_t>("frame packet_size");
      const auto flags = t.get<std::uint32_t>("frame flags");
      if (flags > kFrameFlagKeyframe) t.fail(fmt::format("frame {} has unknown flags {:#x}", i, flags));
      f.keyframe = (flags & kFrameFlagKeyframe) != 0;
    }
    if (f.byte_offset != expected_offset) {
      t.fail(fmt::format("frame {} starts at byte {} of the record stream, expected {} (frame index inconsistent)", i,
                         f.byte_offset, expected_offset));
    }
    if (!std::isfinite(f.time) || (i > 0 && !(f.time > m.frames.back().time))) {
      t.fail(fmt::format("frame {} has time {}, expected a finite time after the previous frame's", i, f.time));
    }
    // Frames lie on the clip's grid, time_of_frame0 + i / fps (playback finds frames by it): within
    // 1 % of a frame.
    const double on_grid = m.time_of_frame0 + double(i) / m.fps;
    if (!(std::abs(f.time - on_grid) <= 0.01 / m.fps)) {
      t.fail(fmt::format("frame {} has time {}, expected {} (time_of_frame0 {} + {} / {} fps)", i, f.time, on_grid,
                         m.time_of_frame0, i, m.fps));
    }
    if (particle) {
      if (f.count > kMaxFrameParticles) {
        t.fail(fmt::format("frame {} claims {} particles, more than the particle codec's limit of {}", i, f.count,
                           kMaxFrameParticles));
      }
      since_key = f.keyframe ? 0 : since_key + 1;
      if (since_key >= m.codec.keyframe_interval || (i == 0 && !f.keyframe)) {
        t.fail(fmt::format("frame {} is {} frames past its keyframe; keyframe_interval is {}", i, since_key,
                           m.codec.keyframe_interval));
      }
    } else {
      if (f.count > stream_size / m.record_size) {
        t.fail(fmt::format("frame {} claims {} particles, more than the whole stream holds", i, f.count));
      }
      if (m.version == 1) {
        f.packet_offset = f.byte_offset;
        f.packet_size = f.count * m.record_size;
      } else if (f.packet_size != f.count * m.record_size || !f.keyframe) {
        t.fail(
            fmt::format("frame {}: with the records codec a packet is the frame's {} bytes of records and a "
                        "keyframe, not {} bytes{}",
                        i, f.count * m.record_size, f.packet_size, f.keyframe ? "" : " and a predicted frame"));
      }
    }
    if (f.packet_offset != expected_packet) {
      t.fail(
          fmt::format("frame {}'s packet starts at byte {} of the chunked stream, expected {} (frame index "
                      "inconsistent)",
                      i, f.packet_offset, expected_packet));
    }
    expected_packet += f.packet_size;
    expected_offset += f.count * m.record_size;
    min_count = std::min(min_count, f.count);
    max_count = std::max(max_count, f.count);
    m.frames.push_back(f);
  }
  if (expected_packet != stream_size) {
    throw Error(fmt::format("{}: the frame index covers {} bytes but stream_size is {} (frame index inconsistent)",
                            name, expected_packet, stream_size));
  }
  if (frame_count > 0 && (min_count != m.min_count || max_count != m.max_count)) {
    throw Error(fmt::format("{}: header says {}..{} particles per frame, the frame index says {}..{}", name,
                            m.min_count, m.max_count, min_count, max_count));
  }
  const std::uint64_t expected_chunks = (stream_size + m.chunk_size - 1) / m.chunk_size;
  if (chunk_count != expected_chunks) {
    throw Error(fmt::format("{}: chunk_count is {}, but {} bytes in {}-byte chunks need {}", name, chunk_count,
                            stream_size, m.chunk_size, expected_chunks));
  }
  const std::uint64_t payload_start = header_size_of(m.version), payload_end = header.tables_offset;
  for (std::uint64_t i = 0; i < chunk_count; ++i) {
    ChunkEntry c;
    const std::uint64_t at = t.offset();
    c.file_offset = t.get<std::uint64_t>("chunk file_offset");
    c.stored_size = t.get<std::uint64_t>("chunk stored_size");
    c.checksum = t.get<std::uint64_t>("chunk checksum");
    const auto codec = t.get<std::uint16_t>("chunk codec");
    t.skip(2, "chunk reserved");
    c.codec_param = t.get<std::uint32_t>("chunk codec_param");
    if (codec > static_cast<std::uint16_t>(Codec::Zstd)) {
      throw Error(fmt::format("{}: at offset {}: chunk {} has unknown codec {}", name, at, i, codec));
    }
    c.codec = static_cast<Codec>(codec);
    if (c.file_offset < payload_start || c.file_offset > payload_end || c.stored_size > payload_end - c.file_offset) {
      throw Error(
          fmt::format("{}: at offset {}: chunk {} lies at bytes {}..{} but the payload is {}..{} (chunk table "
                      "points past the end or into the tables)",
                      name, at, i, c.file_offset, c.file_offset + c.stored_size, payload_start, payload_end));
    }
    // Chunks follow each other: none shares bytes with the one before (a table that repeats a
    // chunk's bytes could claim a huge stream from a tiny file).
    const std::uint64_t previous_end =
        m.chunks.empty() ? payload_start : m.chunks.back().file_offset + m.chunks.back().stored_size;
    if (c.file_offset < previous_end) {
      throw Error(
          fmt::format("{}: at offset {}: chunk {} starts at byte {}, inside the chunk before it (which ends "
                      "at byte {}); chunks must be disjoint and in order",
                      name, at, i, c.file_offset, previous_end));
    }
    const std::uint64_t raw_size = std::min(m.chunk_size, stream_size - i * m.chunk_size);
    if (raw_size > max_decoded_size(c.codec, c.stored_size)) {
      throw Error(fmt::format(
          "{}: at offset {}: chunk {} claims {} bytes of stream from {} stored bytes, expected "
          "at most {} from {} data of that size",
          name, at, i, raw_size, c.stored_size, max_decoded_size(c.codec, c.stored_size), codec_name(c.codec)));
    }
    m.chunks.push_back(c);
  }
  if (t.pos() != tables.size()) {
    throw Error(fmt::format("{}: the tables hold {} bytes beyond their last entry", name, tables.size() - t.pos()));
  }
  return m;
}

}  // namespace pstream::format
