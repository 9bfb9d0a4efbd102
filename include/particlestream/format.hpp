// The .pstream file: a cooked particle clip cut into fixed-size chunks that decode alone.
// docs/format.md is the normative description; this header mirrors it.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "particlestream/error.hpp"
#include "particlestream/io.hpp"

namespace pstream::format {

inline constexpr std::uint32_t kVersion = 6;  // what the writer writes; the reader takes 1 to 6
inline constexpr std::size_t kHeaderSizeV1 = 160;
inline constexpr std::size_t kHeaderSize = 192;  // versions 2 to 6
inline constexpr std::uint32_t kDefaultKeyframeInterval = 64;
inline constexpr int kDefaultParticleZstdLevel = 16;         // lossy, with ids: the optimal parser pays off
inline constexpr int kDefaultMatchedParticleZstdLevel = 12;  // lossy, without ids: see default_particle_zstd_level
inline constexpr int kDefaultLosslessParticleZstdLevel = 3;  // lossless: float bits gain little from it
inline constexpr std::uint32_t kMaxKeyframeInterval = 1024;
// The most particles one frame of the particle codec may hold: decoders size their state from
// the largest frame at open, so a file cannot ask for more memory than this bounds.
inline constexpr std::uint64_t kMaxFrameParticles = 64ull << 20;
inline constexpr std::uint64_t kMinChunkSize = 64ull << 10;
inline constexpr std::uint64_t kMaxChunkSize = 64ull << 20;
inline constexpr std::uint64_t kDefaultChunkSize = 2ull << 20;
inline constexpr std::uint32_t kMaxAttributes = 64;
inline constexpr std::size_t kAttributeNameSize = 32;
inline constexpr std::uint64_t kChunkAlignment = 64;
// Times (header and frame index) lie within +-kMaxTime seconds (about 31 years): far beyond any
// cache, and where a double still resolves a frame of 1 MHz.
inline constexpr double kMaxTime = 1e9;

inline constexpr std::uint64_t kFlagXformsBaked = 1u << 0;   // positions are in the source's world space
inline constexpr std::uint64_t kFlagInterpolated = 1u << 1;  // frames between samples were blended, not picked

enum class AttributeType : std::uint8_t { Float32 = 0, Unorm8 = 1, Uint32 = 2, Uint64 = 3 };
std::string_view attribute_type_name(AttributeType type);
std::size_t attribute_type_size(AttributeType type);

struct Attribute {
  std::string name;  // "position", "scale", "color", "velocity", "id" or a source attribute
  AttributeType type = AttributeType::Float32;
  std::uint8_t components = 1;
  std::uint32_t offset = 0;  // within the record
  std::size_t size() const { return attribute_type_size(type) * components; }
};

enum class Codec : std::uint16_t { Raw = 0, Lz4 = 1, Zstd = 2 };
std::string_view codec_name(Codec codec);

struct ChunkEntry {
  std::uint64_t file_offset = 0;
  std::uint64_t stored_size = 0;
  std::uint64_t checksum = 0;  // XXH3-64 of the stored bytes
  Codec codec = Codec::Raw;
  std::uint32_t codec_param = 0;  // zstd: level; lz4: 0 fast, > 0 HC level
};

struct FrameEntry {
  std::uint64_t count = 0;        // particles
  std::uint64_t byte_offset = 0;  // of the frame's first record in the decoded record stream
  double time = 0.0;              // seconds
  std::array<float, 6> bounds{};  // min xyz, max xyz of the positions (empty frame: +inf/-inf)
  // Where the frame's packet lies in the chunked stream, and whether it decodes alone. With the
  // records codec (and in version 1 files) the packet is the records: packet_offset ==
  // byte_offset, packet_size == count × record_size, every frame a keyframe.
  std::uint64_t packet_offset = 0;
  std::uint64_t packet_size = 0;
  bool keyframe = true;
};

// How frames are stored (docs/format.md, "Frame codecs"); include/particlestream/codec.hpp.
enum class FrameCodec : std::uint32_t { Records = 0, Particle = 1 };
std::string_view frame_codec_name(FrameCodec codec);

// The particle codec's coding of each 32-bit word of a record.
enum class WordCoding : std::uint8_t {
  Quantized = 0,  // a float32 on a grid: origin + q × step, |q| < 2^24
  Exact = 1,      // the 32 bits as they are
  Constant = 2,   // the same bits for every particle of the clip; not stored per particle
  Id = 3,         // the two words of the uint64 id: survivors inherit it, new particles code it
  // (Version 3.) A float32 within a bound relative to its own value: its bits with the lowest
  // `base` (the shift, 0..23) mantissa bits rounded off; q = bits >> shift after rounding. For
  // sizes, which span orders of magnitude within a clip.
  Relative = 4,
  // (Version 3.) A velocity component not stored but derived from the steps of position word
  // `base` (a Quantized word) over the codec's matching: value = float(s) × step, with s the
  // second-order backward difference 3·d0 − d1 of the particle's last two grid steps, 2·d0 when it
  // has one, 0 when it has none (docs/format.md, "Derived velocity"). `step` is the position
  // step × fps / 2, so the value is in position units per second.
  Derived = 5,
};
// The bits a Relative word keeps of a float (its sign, exponent and 23 - shift mantissa bits, the
// magnitude rounded half up) and the float they decode to: exact integer operations, the same
// everywhere. |decoded - x| <= 2^-(24 - shift) |x| for normal x.
inline std::uint32_t relative_code(std::uint32_t bits, std::uint32_t shift) {
  if (shift == 0) return bits;
  const std::uint32_t sign = bits & 0x80000000u, magnitude = bits & 0x7FFFFFFFu;
  return (sign >> shift) | ((magnitude + (1u << (shift - 1))) >> shift);
}
inline std::uint32_t relative_decode(std::uint32_t q, std::uint32_t shift) { return q << shift; }
// The most mantissa bits a Relative word may round off and keep `error` (relative): 23 - k for
// the fewest k kept bits with 2^-(k+1) <= error; 0 when the bound is finer than a float's own
// precision (the word is then exact).
std::uint32_t relative_shift_for(double error);
// How the particle codec orders each frame.
enum class FrameOrder : std::uint8_t {
  Source = 0,   // as the source wrote it; particle i is predicted from particle i of the last frame
  Id = 1,       // ascending id; particles are matched by id
  Matched = 2,  // the encoder's: persisting particles in the last frame's order, matched by position
                // (closest first; along a stored velocity where that finds them nearer), then new
                // particles in Morton order
};

// How the particle codec orders a clip's frames: the source's order when lossless, else by id
// where particles have ids, else matched by position.
constexpr FrameOrder particle_frame_order(bool has_ids, bool lossless) {
  return lossless ? FrameOrder::Source : has_ids ? FrameOrder::Id : FrameOrder::Matched;
}

// The particle codec's zstd level when none is asked for. With ids (and in the source order), a
// particle's residuals recur from frame to frame and zstd's optimal parser (level 16) finds 9 %
// more than level 12 on Blender's sparks. Without ids they are a solver's re-sampling noise: on the
// FLIP pour level 16 is 0.9 % smaller than 12 and cooks 1.4x as long.
constexpr int default_particle_zstd_level(FrameOrder order, bool lossless) {
  if (lossless) return kDefaultLosslessParticleZstdLevel;
  return order == FrameOrder::Matched ? kDefaultMatchedParticleZstdLevel : kDefaultParticleZstdLevel;
}

struct WordCodingEntry {
  WordCoding coding = WordCoding::Exact;
  float step = 0.0f;       // Quantized: the grid step; Derived: grid units to velocity
  float error = 0.0f;      // Quantized: the bound the encoder guarantees, |decoded - source| <= error;
                           // Relative: |decoded - source| <= error × |source|
  std::uint32_t base = 0;  // Quantized: the grid origin's float bits; Constant: the word's bits;
                           // Relative: the mantissa bits rounded off (1..23); Derived: the position
                           // word it is derived from
};

struct CodecInfo {
  FrameCodec codec = FrameCodec::Records;
  FrameOrder order = FrameOrder::Source;
  bool lossless = false;
  std::uint32_t keyframe_interval = 1;
  int zstd_level = kDefaultParticleZstdLevel;  // encoder only; not stored
  bool nibbles = true;                 // encoder only: false packs no word as nibbles, as versions before 5 read
  bool keyframe_links = true;          // encoder only: false links no keyframe to the frame before (before 6)
  double error = 0.0;                  // the positions' bound, absolute; 0 when lossless
  std::vector<WordCodingEntry> words;  // record_size / 4 entries (particle codec only)
  // Encoder only, for frames matched by position: the record word of a stored velocity's x (y and
  // z follow), -1 when there is none, and the seconds between frames (docs/compression-experiments.md,
  // "A cache whose particles persist but has no ids").
  std::int32_t velocity_word = -1;
  double frame_seconds = 0.0;
};

struct Metadata {
  std::uint32_t version = kVersion;
  std::uint64_t flags = 0;
  double fps = 24.0;
  double time_of_frame0 = 0.0;
  std::uint64_t chunk_size = kDefaultChunkSize;
  std::uint32_t record_size = 16;
  std::uint64_t min_count = 0, max_count = 0;
  double avg_count = 0.0;
  std::array<float, 6> bounds{};
  std::string source_file, source_object, cooked_with;
  std::vector<Attribute> layout;
  CodecInfo codec;  // how frames are stored
  std::vector<FrameEntry> frames;
  std::vector<ChunkEntry> chunks;

  std::uint64_t frame_count() const { return frames.size(); }
  std::uint64_t chunk_count() const { return chunks.size(); }
  // Bytes of the chunked stream (the frames' packets, back to back); with the records codec this
  // is also the decoded record stream.
  std::uint64_t stream_size() const;
  std::uint64_t decoded_size() const;  // bytes of every frame's records, decoded
  std::uint64_t chunk_raw_size(std::uint64_t chunk) const;
  // Chunk indices [first, last] holding frame f's packet (an empty packet: first == last).
  std::pair<std::uint64_t, std::uint64_t> frame_chunks(std::uint64_t frame) const;
  // Particles a chunk holds on average: chunk_size over the stored bytes per particle.
  double particles_per_chunk() const;
  std::uint64_t total_particles() const;
  // The frame nearest `time` (seconds), clamped to the clip: the one rounding of time to frames.
  std::uint64_t frame_at(double time) const;
  // The frame at or before `time` and how far `time` is towards the next one, in [0, 1): what
  // interpolation blends. A time within 1e-6 of a frame's is that frame (fraction 0); before the
  // clip: frame 0, after it: the last frame, both with fraction 0.
  std::pair<std::uint64_t, double> frame_between(double time) const;
  const Attribute* find(std::string_view name) const;
};

// Attribute names are text every tool can print and write: non-empty valid UTF-8 (no overlong
// forms, surrogates or code points past U+10FFFF) without control characters (C0, DEL, C1).
// The reader refuses other names; the cook refuses to make them.
bool is_valid_name(std::string_view name);
// `name` as printable ASCII for messages: other bytes, quotes and backslashes as \xNN.
std::string escaped_name(std::string_view name);

// The default record: position float32x3 at 0, scale float32 at 12.
std::vector<Attribute> default_layout();
// Appends an attribute at the end of the record (4-byte aligned); returns the new record size.
std::uint32_t append_attribute(std::vector<Attribute>& layout, std::string name, AttributeType type,
                               std::uint8_t components);
std::uint32_t record_size_of(const std::vector<Attribute>& layout);
// The attribute named `name` in `layout`, or null (Metadata::find on a clip's layout).
const Attribute* find_attribute(const std::vector<Attribute>& layout, std::string_view name);

// ---- Memory a clip may claim ----------------------------------------------------------------

// A clip's header can claim far more particles than its bytes hold (a particle-codec frame of
// identical particles is a few bytes whatever its count). Without a budget from the host, a
// reader spends on decoded frames and decoder state at most what the stored bytes justify:
// kMemoryPerStoredByte bytes for each stored byte, and never less than kUnbudgetedMemoryFloor.
inline constexpr std::uint64_t kUnbudgetedMemoryFloor = 256ull << 20;
inline constexpr std::uint64_t kMemoryPerStoredByte = 64;
std::uint64_t unbudgeted_memory_limit(const Metadata& meta);
// A buffer for the clip's largest decoded frame (max_count × record_size bytes), refused with an
// OptionError("budget") naming `name`, max_count and the bytes when the clip's stored bytes do not
// justify it: what every reader of whole frames allocates them with.
std::vector<std::byte> frame_buffer(const Metadata& meta, std::string_view name);

// ---- Chunks -----------------------------------------------------------------------------------

struct EncodedChunk {
  std::vector<std::byte> stored;
  Codec codec = Codec::Raw;
  std::uint32_t codec_param = 0;
  std::uint64_t checksum = 0;
};
EncodedChunk encode_chunk(std::span<const std::byte> raw, Codec codec, int level);
// The most raw bytes `stored` bytes of a chunk in `codec` can decode to (raw: exactly `stored`;
// lz4: 255 per byte; zstd: 32,768 per byte, an RLE block's 4 bytes for a 128 KiB block). The
// reader refuses a chunk table that claims more, before anything is allocated for it.
std::uint64_t max_decoded_size(Codec codec, std::uint64_t stored);
// Checks the checksum, then decodes into `out`, which must be exactly the chunk's raw size.
// `where` names the file and chunk in errors.
std::uint64_t checksum(std::span<const std::byte> bytes);
// Whether a stored checksum matches `bytes`. Fuzzing builds (PSTREAM_FUZZ) accept any, so that
// mutated files reach the parsers and decoders behind the checksums.
bool checksum_matches(std::span<const std::byte> bytes, std::uint64_t stored);

class EntropyDecoder;  // zstd and lz4, behind one door (src/format/entropy.hpp)

// A reusable decoder that owns its codec state, so decoding allocates nothing (for the streaming
// runtime, whose playback must not allocate). decode() checks the checksum, then decodes into
// `out`, which must be exactly the chunk's raw size; it throws pstream::Error naming `file` and
// `chunk` on a checksum or codec failure; only that error path allocates.
class ChunkDecoder {
 public:
  ChunkDecoder();
  ~ChunkDecoder();
  ChunkDecoder(const ChunkDecoder&) = delete;
  ChunkDecoder& operator=(const ChunkDecoder&) = delete;
  void decode(const ChunkEntry& entry, std::span<const std::byte> stored, std::span<std::byte> out,
              std::string_view file, std::uint64_t chunk);

 private:
  std::unique_ptr<EntropyDecoder> entropy_;  // zstd and lz4 (src/format/entropy.hpp)
};

// ---- Reading ----------------------------------------------------------------------------------

struct MatchRun;  // codec.hpp

class Reader {
 public:
  // Opens and validates header and tables (every size, count, offset and checksum);
  // throws pstream::Error naming the file, the field and its value.
  // `path` may also be an http(s):// URL (io::open_url()); a local file is mapped.
  static Reader open(const std::filesystem::path& path);
  // Any byte source: the header and tables are read at open, each chunk when it is asked for
  // (stored_chunk()'s span is then valid until the next call).
  static Reader open(std::unique_ptr<io::ByteSource> source);
  static Reader from_memory(std::span<const std::byte> bytes, std::string name);
  Reader(Reader&&) noexcept;
  Reader& operator=(Reader&&) noexcept;
  ~Reader();

  const Metadata& metadata() const;
  const std::string& name() const;
  std::uint64_t file_size() const;
  std::span<const std::byte> stored_chunk(std::uint64_t chunk) const;
  void read_chunk(std::uint64_t chunk, std::span<std::byte> out) const;  // out: the chunk's raw size
  // The frame's packet (its bytes in the chunked stream) into `out` (packet_size bytes); `scratch`
  // must hold the raw size of each chunk the packet touches (chunk_size, or less for the last).
  void read_packet(std::uint64_t frame, std::span<std::byte> out, std::span<std::byte> scratch) const;
  // The frame's records, decoded, into `out` (count × record_size bytes). With a predicting codec
  // this decodes forward from the frame's keyframe, or from the last frame read when that is the
  // one before: frames read in order cost one decode each. The first read that goes back makes
  // the decoder again with 3 saved states (fewer when the clip's stored bytes do not justify their
  // memory): later reads back resume from the nearest state saved on the way, so frames read last
  // to first cost a few decodes each rather than half a keyframe group. The chunk read last is
  // kept (read, checked and decompressed once while frames in turn come from it), in a buffer of
  // one chunk made on the first call.
  // With `matching` (room for 2 × max_count + 1 runs is always enough): the codec's matching of
  // this frame's particles with the frame before's, as FrameDecoder::decode() gives it; returns
  // the number of runs, or kNoMatching (a keyframe, a clip in source order, the records codec).
  std::size_t read_frame(std::uint64_t frame, std::span<std::byte> out, std::span<MatchRun> matching = {}) const;
  // The frames read_frame() has decoded, those on the way to the frames asked for included.
  std::uint64_t frames_decoded() const;

 private:
  struct Impl;
  explicit Reader(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// The fixed-size header, validated; `meta` holds its fields, the tables are still to be read.
struct Header {
  Metadata meta;
  std::uint64_t frame_count = 0, chunk_count = 0, stream_size = 0, attribute_count = 0;
  std::uint64_t tables_offset = 0, tables_size = 0, tables_checksum = 0, file_size = 0;
};
// Parsing in two steps, for readers that fetch the header and then the tables (streaming IO).
// Every size, count, offset and checksum is validated; errors name the file, field and value.
// Throws unless `first_bytes` start with the .pstream magic; a source that must be cooked first
// (Alembic, PLY) gets a message that says so and gives the command.
void check_magic(std::span<const std::byte> first_bytes, std::string_view name);
Header parse_header(std::span<const std::byte> first_bytes, std::uint64_t file_size, std::string_view name);
Metadata parse_tables(const Header& header, std::span<const std::byte> tables, std::string_view name);
// Both steps over a whole file in memory.
Metadata parse_metadata(std::span<const std::byte> file, std::string_view name);
// Both steps through a byte source (two reads: the header, then the tables).
Metadata read_metadata(io::ByteSource& source);

// ---- Writing ----------------------------------------------------------------------------------

// Writes a .pstream in one pass — header placeholder, chunks, then the tables — to a temporary
// file beside `path`, renamed over `path` only by commit(): a failed or interrupted write never
// leaves a half-written file at `path`, and no temporary (src/base/output_file.hpp has the rules:
// /dev/null is written directly, directories and other special files are refused).
class Writer {
 public:
  // `meta` gives layout, record size, chunk size, fps and names; frames and chunks are appended.
  // Refuses an output that is one of `inputs` (the same file), before writing anything.
  Writer(std::filesystem::path path, Metadata meta, std::span<const std::filesystem::path> inputs = {});
  ~Writer();
  Writer(const Writer&) = delete;
  Writer& operator=(const Writer&) = delete;
  // A frame whose packet is its records (the records codec): its bytes follow in chunks.
  void append_frame(std::uint64_t count, double time, std::array<float, 6> bounds);
  // A frame whose packet of `packet_size` bytes follows in chunks (other frame codecs).
  void append_frame(std::uint64_t count, double time, std::array<float, 6> bounds, std::uint64_t packet_size,
                    bool keyframe);
  void append_chunk(const EncodedChunk& chunk);  // in order
  void append_chunk(std::span<const std::byte> stored, Codec codec, std::uint32_t codec_param, std::uint64_t checksum);
  // A raw chunk can also be written in pieces as it is produced (its checksum is streamed), so
  // the producer needs no chunk-sized buffer: append_raw_piece() until end_raw_chunk().
  void append_raw_piece(std::span<const std::byte> bytes);
  void end_raw_chunk();
  // Bytes of the chunked stream (frame packets, back to back), cut into raw chunks of chunk_size
  // as they come; commit() ends the last one.
  void append_stream(std::span<const std::byte> bytes);
  const Metadata& metadata() const { return meta_; }
  // Checks that the chunks cover the frames, fills in counts and bounds, writes the tables and
  // the header, syncs and renames. Returns the file size.
  std::uint64_t commit();

 private:
  void write_at(std::uint64_t offset, std::span<const std::byte> bytes);
  // Records the chunk just written at position_ and moves position_ past it.
  void end_chunk(std::uint64_t stored_size, Codec codec, std::uint32_t codec_param, std::uint64_t checksum);
  std::filesystem::path path_;
  Metadata meta_;
  struct Output;  // the file being written (src/base/output_file.hpp)
  std::unique_ptr<Output> out_;
  std::uint64_t position_ = 0;  // where the next chunk goes
  struct RawChunk;              // the raw chunk being written in pieces
  std::unique_ptr<RawChunk> raw_;
};

std::vector<std::byte> serialize_tables(const Metadata& meta);
std::vector<std::byte> serialize_header(const Metadata& meta, std::uint64_t tables_offset,
                                        std::span<const std::byte> tables);

}  // namespace pstream::format
