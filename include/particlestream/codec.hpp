// Frame codecs: how a frame's particle records are stored in a .pstream (docs/format.md, version 2).
//
// A frame codec is a pluggable unit that sees its context: the record layout, the clip's coding
// parameters (CodecInfo), frame boundaries and the decoder's reference frames. Each frame is one
// *packet* in the file's chunked stream. Two codecs exist:
//
//   records   the packet is the frame's records as they are (version 1's layout); every frame
//             decodes alone. The chunk codec (raw, LZ4, zstd) compresses chunks of packets.
//   particle  error-bounded quantisation and temporal prediction. Each frame is ordered so that
//             particles that persist from the previous frame are predicted from it (by id, or,
//             without ids, matched by position); new particles are coded spatially;
//             residuals go to byte planes compressed by zstd. A keyframe every K frames decodes
//             alone; the others need the frame before them. In lossless mode the source order and
//             the exact bytes are kept.
//
// Decoding is allocation-free after construction (the streaming runtime's rule): a FrameDecoder
// sizes every buffer from the clip's largest frame once.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "particlestream/format.hpp"

namespace pstream::format {

class FrameUnit;  // a frame codec's decoding half (src/format/frame_unit.hpp)

// ---- Encoding ----------------------------------------------------------------------------------

// What the cook asks of the particle codec.
struct ParticleCodecOptions {
  bool lossless = false;
  // The bound on every decoded position coordinate: absolute (scene units), or relative to the
  // clip's bounds diagonal. Colours, ids and integer attributes are always exact.
  double error = 1e-4;
  bool error_relative = true;
  // Velocity and other float attributes: within this fraction of their own range (per
  // component); 1e-3 keeps a speed ramp's 256 colours and a streak's length. A velocity is also
  // kept within 4 × the position bound × fps, so that it moves a Hermite curve between frames by
  // no more than the position bound (the tangents' weights sum to at most 1/4).
  double attribute_error = 1e-3;
  // Scale (the particle's radius): within this fraction of each particle's own scale, whatever
  // the clip's extent (a relative grid: WordCoding::Relative).
  double scale_error = 0.01;
  // In a clip ordered by id, a float32x3 `velocity` in the layout is not stored but derived by
  // the decoder from each particle's positions (WordCoding::Derived; the source's values only seed
  // new particles' first step). Off, or without ids: stored within `attribute_error`, about 2.3
  // bytes per particle more.
  bool derive_velocity = true;
  std::uint32_t keyframe_interval = kDefaultKeyframeInterval;
  int zstd_level = 0;  // 0: default_particle_zstd_level() of the clip's order
};

// Facts about a whole clip that the encoder needs before its first frame: gathered by a pass
// over the source (ClipStats::add for every frame).
class ClipStats {
 public:
  explicit ClipStats(const std::vector<Attribute>& layout);
  // One frame's records (count × record size bytes).
  void add(std::span<const std::byte> records, std::uint64_t count);
  std::span<const float> min() const { return min_; }  // per float component, in layout order
  std::span<const float> max() const { return max_; }
  // Whether every particle of every frame has the same bytes for attribute `a`.
  bool constant(std::size_t a) const { return constant_[a] != 0; }
  std::span<const std::byte> constant_value(std::size_t a) const;
  double diagonal() const;  // of the positions' bounds; 0 when there are none
  std::uint64_t particles() const { return particles_; }

 private:
  std::vector<Attribute> layout_;
  std::uint32_t record_size_ = 0;
  std::vector<std::size_t> first_component_;  // per attribute: index into min_/max_
  std::vector<float> min_, max_;
  std::vector<std::uint8_t> constant_;
  std::vector<std::byte> value_;  // one record: the constant values
  std::uint64_t particles_ = 0;
};

// Chooses the per-attribute coding (quantisation steps, origins, constants) for a clip.
// Throws pstream::Error when the bound cannot be met in 24-bit grids (too small an error for the
// clip's extent) or is not a positive finite number.
CodecInfo plan_particle_codec(const std::vector<Attribute>& layout, const ClipStats& stats, double fps, bool has_ids,
                              const ParticleCodecOptions& options);

// One frame as the encoder takes it: the records in source order, and the ids that order and
// match particles across frames (whether or not the record keeps them).
struct SourceFrame {
  std::span<const std::byte> records;  // count × record size
  std::span<const std::uint64_t> ids;  // empty, or one per particle (required when CodecInfo::order is Id)
  std::uint64_t count = 0;
};

struct EncodedFrame {
  std::vector<std::byte> packet;
  bool keyframe = false;
  std::uint64_t count = 0;
  std::array<float, 6> bounds{};  // of the decoded positions
  std::uint64_t matched = 0;      // particles predicted from the previous frame
  std::uint64_t predictable = 0;  // particles the previous frame could have predicted (min of the counts)
};

// Encodes a keyframe group: frames[0] becomes a keyframe, the rest are predicted. The layout is
// what `info.words` codes (plan_particle_codec made them from it). `before`, the frames
// preceding the group (oldest first; empty for the clip's first group), only seed the keyframe's
// motion state: the last two are used (a derived velocity needs each particle's last two steps).
// Groups are independent, so a cook encodes them in parallel; the bytes depend on nothing else.
// `first_index` numbers frames in errors.
std::vector<EncodedFrame> encode_group(const CodecInfo& info, std::span<const SourceFrame> frames,
                                       std::span<const SourceFrame> before, std::uint64_t first_index);

// ---- Checking ---------------------------------------------------------------------------------

// The largest difference between decoded frames and their source, per record word (float words
// as values, other words as 0 when equal, +inf when not), and how many particles found no
// partner. Particles are paired by id when the layout has one, else each decoded particle with
// the unpaired source particle nearest in every float word (each difference scaled by that word's
// bound in `codec`, when given: particles may nearly coincide in position and differ in velocity),
// since the codec may re-order a frame without ids. With `in_order` set, and as many particles in
// both, particle i is paired with particle i: a clip ordered by id (FrameOrder::Id) against its
// source cooked in id order, where the nearest particle of a dense cloud may be another one.
struct FrameComparison {
  bool in_order = false;
  std::vector<double> max_error;           // per record word: |decoded - source| (float words)
  std::vector<double> max_relative_error;  // per record word: |decoded - source| / |source| (0 when both are 0)
  // Per float word, over paired particles with finite values: Σ (decoded - source)², Σ source², and
  // how many: root-mean-square errors for words without a bound (a derived velocity).
  std::vector<double> sum_squared_error, sum_squared_source;
  std::vector<std::uint64_t> compared;
  std::uint64_t particles = 0, unmatched = 0, count_mismatches = 0;
  void add(const std::vector<Attribute>& layout, std::span<const std::byte> decoded, std::uint64_t decoded_count,
           std::span<const std::byte> source, std::uint64_t source_count, const CodecInfo* codec = nullptr);
  // The same, the source's records in their own layout: each attribute is compared with the
  // source's of the same name and size, and one the source lacks (a derived velocity) with 0.
  void add(const std::vector<Attribute>& layout, std::span<const std::byte> decoded, std::uint64_t decoded_count,
           const std::vector<Attribute>& source_layout, std::span<const std::byte> source, std::uint64_t source_count,
           const CodecInfo* codec = nullptr);
};

// ---- Decoding ----------------------------------------------------------------------------------

// Where a frame's bytes lie in the chunked stream, and how it decodes.
struct FramePacket {
  std::uint64_t offset = 0, size = 0;
  bool keyframe = true;
};
FramePacket frame_packet(const Metadata& meta, std::uint64_t frame);
// The keyframe at or before `frame`: decoding frame f costs f - keyframe_of(f) extra decodes.
std::uint64_t keyframe_of(const Metadata& meta, std::uint64_t frame);
// Where decoding `frame` starts when `last_decoded` (UINT64_MAX: none) was the frame decoded
// last: on from it when it lies between frame's keyframe and frame, else at the keyframe. The
// rule of Reader::read_frame and of the browser player's decoder.
std::uint64_t decode_start(const Metadata& meta, std::uint64_t frame, std::uint64_t last_decoded);

// ---- The registry ------------------------------------------------------------------------------

// A frame codec is a unit: an id, a name, and two halves in their own files and libraries. The
// decoding half (pstream_format, which players link alone) makes the unit that decodes a clip's
// frames and says beforehand how much it allocates; the encoding half (pstream_format_encoder)
// plans a clip's coding and encodes keyframe groups. FrameDecoder, the reader, the cook and the
// tools find codecs here, never by a switch over FrameCodec. Adding a codec is one entry in each
// table (src/format/frame_codecs.cpp, frame_encoders.cpp) and its files.
struct FrameCodecDecoding {
  FrameCodec id;
  std::string_view name;  // as `info` prints it
  // The bytes make_unit() allocates for `meta`, known before anything is allocated.
  std::uint64_t (*state_bytes)(const Metadata& meta);
  std::unique_ptr<FrameUnit> (*make_unit)(const Metadata& meta, std::string_view file);
  // The bytes of one saved state of its units (what decoding a frame needs of the frame before;
  // FrameDecoder's `saved_states`): 0 when its frames need none, or it cannot save them.
  std::uint64_t (*save_bytes)(const Metadata& meta);
};
std::span<const FrameCodecDecoding> frame_codec_decoders();
const FrameCodecDecoding* find_frame_codec(FrameCodec id);  // null: no codec has that id

// The vector instructions the particle codec's decoder runs with in this process: "AVX2" where an
// x86-64 processor has them (8 values a vector), else "SSE2" (x86-64's baseline, 4 a vector), or
// "SIMD128" in the browser build; the same bits either way. PSTREAM_SIMD=baseline in the
// environment keeps an AVX2 machine on SSE2 (the tests compare the two). Benchmarks print it.
std::string_view particle_decoder_simd();

struct FrameCodecEncoding {
  FrameCodec id;
  std::string_view name;
  // A clip's coding from its layout and statistics (plan_particle_codec's contract).
  CodecInfo (*plan)(const std::vector<Attribute>& layout, const ClipStats& stats, double fps, bool has_ids,
                    const ParticleCodecOptions& options);
  // A keyframe group's packets (encode_group's contract).
  std::vector<EncodedFrame> (*encode_group)(const CodecInfo& info, std::span<const SourceFrame> frames,
                                            std::span<const SourceFrame> before, std::uint64_t first_index);
};
std::span<const FrameCodecEncoding> frame_codec_encoders();
const FrameCodecEncoding* find_frame_codec_encoder(FrameCodec id);

// Word codings are small types too: what each one is, stores and promises, and the rule a clip's
// table must keep for it (src/format/word_codings.cpp).
struct WordCodingType {
  std::string_view name;
  // Why `e` cannot code word `w` (of attribute `a`) in `m`; empty when it can.
  std::string (*check)(const Metadata& m, const Attribute& a, std::uint32_t w, const WordCodingEntry& e);
  WordCoding id;
  bool stored;   // a value per particle in the packets (the decoder keeps Q and D for it)
  bool bounded;  // `error` is a bound on |decoded − source| (relative: of the source's value)
  bool relative;
};
const WordCodingType* find_word_coding(WordCoding id);  // null: an unknown coding

// ---- Matching --------------------------------------------------------------------------------

// Which particles of a frame are the same particles as in the frame before it, as runs walked
// with i (previous frame) and j (this frame) from 0: `keep` particles pair up one to one
// (previous i+t with this j+t), then `drop` particles of the previous frame end, then `insert`
// particles of this frame begin. The runs cover both frames exactly. The particle codec's
// operations are such runs (frames ordered by id or matched, not source order); for other clips
// with ascending ids, match_by_id() makes them. Interpolating players blend kept particles and let
// dropped ones die and inserted ones be born (docs/playback.md).
struct MatchRun {
  std::uint32_t keep = 0, drop = 0, insert = 0;
};
// What decode() and match_by_id() return when they give no matching.
constexpr std::size_t kNoMatching = SIZE_MAX;

// The runs pairing `prev` (prev_count records) with `cur` (cur_count records) by the uint64 or
// uint32 attribute named `id` of `meta`'s layout, written to `out`. Returns how many, or
// kNoMatching when the layout has no id, a frame's ids do not strictly ascend, or the runs do not
// fit `out`. One linear merge, no allocation.
std::size_t match_by_id(const Metadata& meta, std::span<const std::byte> prev, std::uint64_t prev_count,
                        std::span<const std::byte> cur, std::uint64_t cur_count, std::span<MatchRun> out);

// Decodes a clip's frames in order. decode() takes a keyframe at any time; any other frame must
// directly follow the last one decoded (its reference). Errors name the file, the frame, the
// attribute and the offset in the packet; nothing is ever written outside `out`.
//
// Saved states make going back cheap. A frame codec that predicts frames from the frame before
// must otherwise decode from the keyframe to reach a frame it has passed: up to a keyframe
// group's length of decodes for each frame shown when playing backwards. With `saved_states` > 0,
// a decoder told which frame it is decoding towards (set_target(): the frame a seek or a step back
// wants) keeps the state after a few of the frames on its way there: halfway from where it
// started, then halfway from there, one for each saved state that no earlier frame would need;
// resume_frame() starts from the nearest. Forward play past the target saves nothing. Played
// backwards, a group of 64 frames then costs about 4.3 decodes a frame with 3 states (6 with 2),
// against 32 from the keyframe. The states are allocated here with the rest; saving copies them.
// Codecs whose frames need no state (records) and builds that cannot save it (the browser's,
// whose zstd stream lives in the worker) keep none.
class FrameDecoder {
 public:
  // Allocates all decoding state for the clip's largest frame (the only allocation). State that
  // would exceed `memory_limit` bytes (0: unbudgeted_memory_limit(meta), what the clip's stored
  // bytes justify) is refused before anything is allocated, with an OptionError("budget") that
  // names the file, max_count and the bytes needed.
  FrameDecoder(const Metadata& meta, std::string name, std::uint64_t memory_limit = 0, std::size_t saved_states = 0);
  ~FrameDecoder();
  FrameDecoder(const FrameDecoder&) = delete;
  FrameDecoder& operator=(const FrameDecoder&) = delete;

  // `packet` is the frame's bytes from the chunked stream; `out` receives count × record_size bytes.
  // When the codec knows which particles continue from the frame before (a predicted frame of a
  // particle clip ordered by id or matched), it writes that matching to `matching` and returns the
  // number of runs; otherwise (a keyframe, the records codec, source order, or more runs than
  // `matching` holds) kNoMatching.
  std::size_t decode(std::uint64_t frame, std::span<const std::byte> packet, std::span<std::byte> out,
                     std::span<MatchRun> matching = {});
  // Whether decode(frame) can run now (a keyframe, the successor of the last decoded frame, or
  // the successor of a saved state).
  bool can_decode(std::uint64_t frame) const;
  void reset();  // forget the reference (after a seek); saved states stay
  // The frame whose state is held, or UINT64_MAX.
  std::uint64_t last_decoded() const { return last_; }
  // The first frame to decode on the way to `frame`: decode_start()'s (on from the last decoded
  // frame, or the keyframe), or the frame after a saved state of frame's group when that is nearer.
  std::uint64_t resume_frame(std::uint64_t frame) const;
  // The decodes that follow are on the way to `target` (decoded after them): states are saved on
  // the way. kNoTarget (the default): nothing is saved.
  static constexpr std::uint64_t kNoTarget = UINT64_MAX;
  void set_target(std::uint64_t target);
  std::size_t saved_states() const { return tags_.size(); }

  // The decoding state's size in bytes, saved states included (fixed at construction).
  std::uint64_t state_bytes() const { return state_bytes_; }
  // Before a decoder is made: the bytes of its state without saved states, and of one saved state
  // (0: the clip's codec keeps none).
  static std::uint64_t base_state_bytes(const Metadata& meta);
  static std::uint64_t saved_state_bytes(const Metadata& meta);
  // How many of `wanted` saved states fit in `limit` bytes beside the decoder's own state and
  // `others` bytes held elsewhere (0 when the clip's codec keeps none): fewer rather than a refusal.
  static std::size_t saved_states_that_fit(const Metadata& meta, std::size_t wanted, std::uint64_t limit,
                                           std::uint64_t others);

 private:
  struct Saved {
    std::uint64_t frame = UINT64_MAX, keyframe = 0;  // the state after `frame`, of keyframe's group
  };
  const Saved* saved_before(std::uint64_t frame) const;  // the latest saved state to resume `frame` from
  void plan_saves(std::uint64_t before);                 // where to save on the way from `before` + 1

  const Metadata& meta_;
  std::string name_;
  std::unique_ptr<FrameUnit> unit_;
  std::uint64_t state_bytes_ = 0;
  std::uint64_t last_ = UINT64_MAX;
  std::uint64_t keyframe_ = 0;  // the keyframe of the frame decoded last
  struct Planned {
    std::uint64_t frame = 0;  // save the state after this frame
    std::size_t slot = 0;     // into this one
  };
  // Saved states: `saved_` holds tags_.size() of save_bytes_ each. On the way to target_, the
  // first save_count_ of saves_ (planned_ after the first decode on the way, the last first).
  std::vector<std::byte> saved_;
  std::vector<Saved> tags_;
  std::vector<Planned> saves_;
  std::uint64_t save_bytes_ = 0, target_ = kNoTarget;
  std::size_t save_count_ = 0;
  bool planned_ = false;
};

}  // namespace pstream::format
