// Cooking: an Alembic point cache or a PLY sequence -> a .pstream of fixed-size chunks.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "particlestream/codec.hpp"
#include "particlestream/format.hpp"

namespace pstream::cook {

enum class ScaleFrom { Widths, Constant, Attribute };

// Over an hour at 24 fps: far more than any effect, far less than a mistyped frame rate plans.
inline constexpr std::uint64_t kDefaultMaxFrames = 100'000;

struct Options {
  std::filesystem::path input;   // .abc, or one file of a numbered PLY sequence (frame.0001.ply)
  std::filesystem::path output;  // .pstream
  std::string object;            // full name of the object to cook; empty: the only points object
  bool merge = false;            // cook every points object into one stream
  bool bake_xforms = true;       // apply the object's world transform to positions
  double fps = 0.0;              // output frame rate; 0: the source's
  bool interpolate = false;      // blend between samples (needs stable ids) instead of nearest
  // The source's velocities, whenever it has them, even when `attributes` does not name them:
  // speed colours, motion blur, stretched sprites and Hermite interpolation need them.
  bool keep_velocity = true;
  ScaleFrom scale_from = ScaleFrom::Widths;
  float scale_constant = 0.0f;
  std::string scale_attribute;
  std::string color_from = "auto";      // "Cd", "none", or "auto" (Cd when present)
  std::vector<std::string> attributes;  // "velocity", "id", "id32", or a float attribute name
  std::uint64_t chunk_size = format::kDefaultChunkSize;
  // How frames are stored: records (cut into chunks compressed by `codec`) or the particle codec
  // (`particle`; its chunks are raw: the packets are already compressed).
  format::FrameCodec frame_codec = format::FrameCodec::Particle;  // the default: error-bounded, ~10x smaller
  format::ParticleCodecOptions particle;
  format::Codec codec = format::Codec::Raw;
  int codec_level = 0;                           // zstd level (default 3 when 0), lz4: 0 fast, > 0 HC
  std::int64_t frame_begin = 0, frame_end = -1;  // output frames [begin, end); -1: to the end
  bool drop_invalid = false;                     // drop NaN/Inf positions instead of failing
  // Records codec: frames with ids are written in ascending id order (so that players match
  // particles across frames by a linear merge) unless this keeps the source's order. The particle
  // codec orders frames itself (by id, matched, or source order in lossless mode).
  bool keep_source_order = false;
  std::uint64_t max_particles = 64ull << 20;     // per frame; a larger frame is refused before it is read
  std::uint64_t max_frames = kDefaultMaxFrames;  // a plan of more output frames is refused (a wrong fps?)
  unsigned threads = 0;                          // chunk encoders; 0: one per core
  // The particle codec encodes a keyframe group at a time, one a thread, each holding its frames'
  // records and ids: no more groups at once than fit in this many bytes (one at least). 0: half
  // the machine's memory.
  std::uint64_t group_memory = 0;
};

// Sets how frames are stored from a spec: "particle[:LEVEL]" or "particle-lossless[:LEVEL]" (the
// particle codec and its zstd level, 1..22), "raw", "lz4[:LEVEL]" or "zstd[:LEVEL]" (records in
// chunks of that codec, level 0..22). Throws pstream::Error naming `codec` and what is expected.
void set_codec(Options& options, std::string_view spec);

// The particle codec's bounds from text, one rule for the CLI, the C API and Python:
// set_error_bound: "1e-4" or "rel:1e-4" (a fraction of the clip's bounds diagonal, below 1) or
// "abs:0.001" (scene units), for positions; set_scale_error: "1%" or "0.01", the bound on each particle's
// scale relative to itself (above 0, below 50 %). Throw pstream::Error naming `what` (the flag or
// argument) and what is expected.
void set_error_bound(Options& options, std::string_view spec, std::string_view what = "error");
void set_scale_error(Options& options, std::string_view spec, std::string_view what = "scale_error");
// set_attribute_error: "1e-3", the bound on velocity and other float attributes as a fraction of
// their own range (above 0, below 1).
void set_attribute_error(Options& options, std::string_view spec, std::string_view what = "attribute_error");

// set_scale_from: "widths", "constant:X" (X > 0, the radius) or "attr:NAME"; set_frames: "A:B"
// (output frames from A up to but not including B; either may be left out).
void set_scale_from(Options& options, std::string_view spec, std::string_view what = "scale_from");
void set_frames(Options& options, std::string_view spec, std::string_view what = "frames");
// Appends the names of a comma-separated list ("velocity,id,age"; empty names skipped) to
// options.attributes: the command line's --attributes and the C API's `attributes`.
void add_attributes(Options& options, std::string_view list);

// What the file records about how it was made (its "cooked with" string): every setting that
// changes the bytes, as key=value words, and the input's name and content hash. No paths, so
// the same input and settings give the same file wherever either is. `has_ids`: whether frames
// are ordered and matched by id, on which the particle codec's default zstd level depends.
std::string describe_settings(const Options& options, std::uint64_t content_hash, bool has_ids);

// Where a cook is: the particle codec reads its source twice (a scan for the ranges its grids
// need, then the encoding), each stage counting frames_done from 1 to frame_count (the clip's
// frames); the records codec has the writing stage alone. An Alembic cache at a URL is fetched
// first (Fetch: bytes_in of bytes_total, no frames yet).
enum class Stage { Scan, Write, Fetch };
struct Progress {
  std::uint64_t frames_done = 0, frame_count = 0;
  std::uint64_t bytes_out = 0;
  Stage stage = Stage::Write;
  std::uint64_t bytes_in = 0, bytes_total = 0;  // Fetch
};

struct Report {
  std::uint64_t frames = 0, chunks = 0, particles = 0, dropped_invalid = 0;
  std::uint64_t input_bytes = 0, stream_bytes = 0, file_bytes = 0;
  double seconds = 0.0;
  // Set when the source had no widths: the scale every particle got, half the median
  // nearest-neighbour spacing of the middle frame (0.01 when that cannot be measured).
  double default_scale = 0.0;
  std::string object;
  // An object cooked is a mesh, whose vertices became the particles: the one named by
  // Options::object, or the archive's only mesh where it holds no points objects.
  bool mesh_vertices = false;
  // The particle codec: the positions' bound (absolute), keyframes, and how many particles were
  // predicted from the frame before out of how many could have been.
  double error = 0.0;
  std::uint64_t keyframes = 0, matched = 0, predictable = 0;
  format::FrameOrder order = format::FrameOrder::Source;
  // Keyframe groups encoded at once: one a thread, fewer where their frames would take more than
  // half the machine's memory (each holds keyframe_interval frames of records and ids).
  unsigned groups_in_flight = 0;
};

// Cooks `options.input` into `options.output`. Throws pstream::Error naming the input, the
// frame and what was wrong; the output is only created when everything succeeded.
Report cook(const Options& options, const std::function<void(const Progress&)>& progress = {});

// One frame of a source as cook() packs it, handed to read_frames()'s visitor.
struct CookedFrame {
  std::uint64_t index = 0, frame_count = 0;  // this output frame, of how many
  double time = 0.0;                         // seconds
  std::uint64_t count = 0;                   // particles
  std::span<const std::byte> records;        // count records in the clip's layout; valid during the call
};
// Called once a frame with the clip's header (layout, record size, fps, time of frame 0, flags,
// source; no frame table, and no "cooked with", which would hash every byte of the source first)
// and the frame. Returns false to stop.
using FrameVisitor = std::function<bool(const format::Metadata& clip, const CookedFrame& frame)>;
// Reads `options.input` as cook() does (the same plan, frames, transforms, particle order, checks
// and errors) and hands each frame's records, packed as a records cook stores them, to `visit` in
// time order, writing nothing: options.output, the codecs and chunk sizes are not used. Memory is
// one frame's. Returns how many frames were visited. verify() compares a clip with its source
// this way.
std::uint64_t read_frames(const Options& options, const FrameVisitor& visit);

// Particles handed over in memory instead of read from a file: a script's simulation, or a DCC's
// evaluated particles (the Blender add-on, blender/). Each array holds `count` entries per
// particle's components (3 for position and velocity, 4 for colour), or is empty where the clip
// has none of that attribute; an attribute is in every frame or in none. The caller keeps the
// arrays alive during cook(); nothing is copied.
// A float attribute handed over with a frame (an age, a temperature): `values` holds count x
// components numbers. The clip stores it when Options::attributes names it, as it stores an
// Alembic cache's.
struct MemoryFloats {
  std::string name;
  std::uint32_t components = 1;  // 1 to 16
  std::span<const float> values;
};
struct MemoryFrame {
  double time = 0.0;  // seconds; frames in increasing time, on the clip's frame grid
  std::uint64_t count = 0;
  std::span<const float> position;    // required
  std::span<const float> width;       // diameters, as Alembic's widths (the record's scale is half)
  std::span<const float> velocity;    // scene units per second
  std::span<const std::uint64_t> id;  // stable across frames: what the codec and interpolation match
  std::span<const float> color;       // linear RGBA in [0, 1]
  std::vector<MemoryFloats> floats;   // the same names and components in every frame with particles
};
struct MemoryClip {
  std::string name;    // for messages and the header's source (say where the particles came from)
  std::string object;  // the header's source object
  double fps = 24.0;   // the frames' rate (Options::fps 0 keeps it)
  std::vector<MemoryFrame> frames;
};
// Cooks `clip` into `options.output` as cook() cooks a file (every option but input, object,
// merge and interpolate applies). Throws pstream::Error naming the clip, the frame and the array
// that is wrong (a size that is not count × components, a NaN, an attribute in some frames only).
Report cook(const Options& options, const MemoryClip& clip, const std::function<void(const Progress&)>& progress = {});

// Frames handed over one at a time and kept on disk, not in memory, until they are cooked: for a
// clip larger than memory (the Blender add-on exports through one). Each frame's arrays go to an
// unnamed temporary file in `folder` (O_TMPFILE; on a file system without it, a file removed as
// soon as it is made), which the system reclaims when the spool ends, even when the process is
// killed: nothing is left behind. The spool holds 24 bytes a frame in memory; clip() maps the file.
//
//   cook::FrameSpool spool("my sim", output.parent_path());
//   for (...) spool.add(frame);      // the frame's arrays are free again once add() returns
//   cook::cook(options, spool.clip("particles", 24.0));
class FrameSpool {
 public:
  // `name` names the frames in add()'s errors and the clip; `folder` empty: the system's temporary
  // folder ($TMPDIR, else /tmp). Throws pstream::Error naming the folder when no file can be made
  // there.
  explicit FrameSpool(std::string name = "particles", const std::filesystem::path& folder = {});
  ~FrameSpool();
  FrameSpool(FrameSpool&& other) noexcept;
  FrameSpool& operator=(FrameSpool&& other) noexcept;
  FrameSpool(const FrameSpool&) = delete;
  FrameSpool& operator=(const FrameSpool&) = delete;

  // Checks `frame` as cook() checks a MemoryClip's frames (each array count x components values,
  // the attributes of the frames before it that hold particles, a time after theirs), then writes
  // its arrays. Every write is checked: a full disk throws, naming the folder. A refused frame
  // leaves the spool as it was.
  void add(const MemoryFrame& frame);
  // Throws what add() would for this frame's contents, and writes nothing.
  void check(const MemoryFrame& frame) const;
  // Leaves the ids out of clip(): a mesh whose vertex count changes has vertex indices, not ids.
  void drop_ids();
  std::uint64_t frames() const;
  std::uint64_t bytes() const;  // written to the temporary so far
  // The frames as a MemoryClip whose arrays are views of the mapped temporary: valid until the
  // next add() or the spool's end.
  MemoryClip clip(std::string object = {}, double fps = 24.0);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Whether cook() reads `path` as a PLY sequence (its extension is .ply, in any case) rather than
// an Alembic archive.
bool is_ply_sequence(const std::filesystem::path& path);

// What a numbered PLY sequence holds, from its files' headers (`pstream info frame.0001.ply`).
struct PlySequenceInfo {
  std::vector<std::filesystem::path> files;  // in frame order, numbered without gaps
  std::int64_t first_number = 0;             // the first file's frame number
  std::string format;                        // "ascii" or "binary_little_endian"
  struct Property {
    std::string name, type;  // type: int8 ... float64
  };
  std::vector<Property> properties;   // the vertex element's, the same in every file
  std::vector<std::uint64_t> counts;  // each file's vertex count
  std::uint64_t bytes = 0;            // of all the files
  // What a default cook takes: the scale from this property ("" when none: a constant), halved
  // when it is a width; colours (red green blue [alpha]), velocities (vx vy vz) and ids.
  std::string scale_property;
  bool scale_is_diameter = false, has_color = false, has_velocity = false, has_ids = false;
};
// Throws pstream::Error naming the file and what is wrong, as cook() would (a missing frame, a
// file whose format or properties differ from the first's, a header that does not parse).
PlySequenceInfo describe_ply_sequence(const std::filesystem::path& example);

// Scale stored in a record for an Alembic width (a diameter): the radius.
inline float scale_from_width(float width) { return width * 0.5f; }

}  // namespace pstream::cook

namespace pstream::cook {

// ---- Verifying a cooked clip ------------------------------------------------------------------

// verify() counts each attribute's distinct values up to this many (a count, not a census).
inline constexpr std::uint64_t kDistinctValuesCounted = std::uint64_t{1} << 16;

// One attribute checked against the source: the largest difference found and the bound the clip
// promises for it, in the bound's own terms (`relative`: a fraction of each value; otherwise
// absolute, scene units for positions; 0 with `exact`).
struct AttributeCheck {
  std::string name;
  double max_error = 0.0;  // absolute, or relative when `relative`
  double bound = 0.0;
  bool relative = false, exact = true, ok = true;
  // Distinct values (per component, over the compared frames, every attribute's but the
  // positions': `counted`) in the source and in the clip, counted up to kDistinctValuesCounted (a
  // count that reaches it means at least that many). `kept_apart`: how many of the source's
  // values the bound must keep distinct, because their bounds do not overlap (all of them for an
  // exact attribute). A bound too coarse for the data shows as few kept apart: sizes from 4 to
  // 20 mm under an absolute bound of 3.6 mm keep 3.
  std::uint64_t distinct_source = 0, distinct_clip = 0, kept_apart = 0;
  bool counted = false;
  // A velocity the particle codec derives (no bound): its root-mean-square error against the
  // source's velocities and their root-mean-square value, per component; `in_source` is false when
  // the source has none to compare with.
  bool derived = false, in_source = true;
  double rms_error = 0.0, rms_source = 0.0;
};

struct VerifyReport {
  std::string file;
  std::uint64_t frames = 0, chunks_verified = 0;
  std::vector<std::string> errors;  // each names the chunk, frame or attribute and what was expected
  // With a source: every frame compared with the source cooked again as records.
  std::string source;
  std::uint64_t frames_compared = 0, particles_compared = 0;
  std::vector<AttributeCheck> attributes;
  bool ok() const { return errors.empty(); }
};

// Where verify() is: every chunk checked, then every frame decoded, then (with a source) every
// frame compared; `done` of `total` chunks or frames in each stage.
struct VerifyProgress {
  enum Stage { Checksums, Decode, Compare } stage = Checksums;
  std::uint64_t done = 0, total = 0;
};

// Checks every chunk's checksum and decoding and decodes every frame; with `against` (the clip's
// source: .abc or a PLY sequence), also every attribute of every frame against its bound
// (docs/format.md: each word's coding), the source read frame by frame as cook() reads it
// (read_frames(): nothing is written, not even a temporary). Errors are collected in the report,
// not thrown.
VerifyReport verify(const std::filesystem::path& file, const std::filesystem::path& against = {},
                    const std::function<void(const VerifyProgress&)>& progress = {});

// Whether `file` is the source `meta` was cooked from, by the name and content hash its "cooked
// with" string records (an Alembic source): an export must not write over it.
bool is_source_of(const format::Metadata& meta, const std::filesystem::path& file);

// ---- Export: a cooked clip back out for a DCC (`pstream export`) ----

struct ExportOptions {
  std::string input;  // a .pstream: a path or an http(s) URL
  // What to write, chosen by the extension (any other is refused before anything is read):
  // - NAME.abc: an Alembic points cache written by our Alembic writer: P, ids, velocities, widths
  //   (twice the record's scale), Cd (rgb, or rgba when any particle is not opaque) and every
  //   other float attribute under its own name. A clip that keeps no ids gets ids that follow the
  //   codec's matching: a particle it carries over from the frame before keeps its id, any other
  //   takes a new one (at a keyframe, or with no matching, every particle does);
  // - NAME.ply: a binary little-endian PLY sequence, NAME.0001.ply, NAME.0002.ply ..., one file a
  //   frame (x y z pscale, vx vy vz, red green blue alpha, id, other float attributes), in a
  //   folder created if need be.
  // Every file appears complete or not at all, and none is written over the input or the source
  // the clip was cooked from.
  std::filesystem::path output;
  // The clip's frames from frame_begin up to but not including frame_end (-1: to the end), as
  // parse_frame_range() reads "A:B". A PLY file keeps its frame's number (frame f is
  // NAME.{f+1}.ply); the Alembic cache starts at the first frame's time.
  std::int64_t frame_begin = 0, frame_end = -1;
};

struct ExportReport {
  std::uint64_t frames = 0;     // written
  bool ply = false;             // a PLY sequence (else one Alembic file)
  std::filesystem::path first;  // the Alembic file, or the sequence's first file
  std::uint64_t bytes_written = 0;
};

// Writes every frame of the clip as `options.output` says. progress(frames_done, frame_count) is
// called after each frame. Throws pstream::Error naming the file and what was wrong.
ExportReport export_clip(const ExportOptions& options,
                         const std::function<void(std::uint64_t done, std::uint64_t total)>& progress = {});

}  // namespace pstream::cook
