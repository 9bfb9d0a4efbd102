// What the cooker reads particles from: an Alembic archive or a PLY sequence.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "particlestream/cook.hpp"

namespace pstream::cook {

// One frame of particles, structure of arrays; only the requested arrays are filled. Arrays keep
// their size across frames (no re-zeroing each frame): only the first `count` entries are valid.
struct ParticleFrame {
  std::uint64_t count = 0;
  std::vector<float> position;            // 3 per particle
  std::vector<float> scale;               // 1 per particle
  std::vector<std::uint8_t> color;        // RGBA8, 4 per particle
  std::vector<float> velocity;            // 3 per particle
  std::vector<std::uint64_t> id;          // 1 per particle
  std::vector<std::vector<float>> extra;  // one array per requested float attribute
  void clear(std::size_t extra_count) {
    count = 0;
    extra.resize(extra_count);
  }
};

// Grows `v` to at least `n` elements; never shrinks (see ParticleFrame).
template <class T>
void ensure_size(std::vector<T>& v, std::size_t n) {
  if (v.size() < n) v.resize(n);
}

// A colour component in [0, 1] as the record's RGBA8 (NaN and below 0: 0; 1 and above: 255).
inline std::uint8_t to_unorm8(float v) {
  if (!(v > 0.0f)) return 0;
  if (v >= 1.0f) return 255;
  return static_cast<std::uint8_t>(std::lround(v * 255.0f));
}

struct Request {
  bool color = false, velocity = false, id = false;
  std::vector<std::string> floats;  // names of float attributes, in record order
  ScaleFrom scale_from = ScaleFrom::Widths;
  float scale_constant = 0.0f;
  std::string scale_attribute;
  bool bake_xforms = true;
  bool interpolate = false;
};

class Source {
 public:
  virtual ~Source() = default;
  virtual std::string name() const = 0;                 // file and object, for messages and the header
  virtual std::string object() const = 0;               // what was cooked
  virtual bool mesh_vertices() const { return false; }  // an object cooked is a mesh: its vertices
  virtual double default_fps() const = 0;
  virtual double start_time() const = 0;
  virtual double end_time() const = 0;
  virtual std::uint64_t input_bytes() const = 0;
  virtual bool has_widths() const = 0;
  virtual bool has_color() const = 0;
  virtual bool has_velocity() const = 0;
  virtual bool has_ids() const = 0;
  // Why has_ids() is false, in words for a message ("the cache has no particle ids (...)").
  virtual std::string why_no_ids() const { return "the source has no particle ids"; }
  // Whether samples can be blended (particles matched by id), and if not, why and what to do.
  virtual bool can_interpolate() const { return has_ids(); }
  virtual std::string why_no_interpolation() const {
    return why_no_ids() +
           ", and interpolation matches particles by id between samples. Cook without `interpolate`: each frame "
           "takes the nearest sample";
  }
  // The files read (an output must not be one of them).
  virtual std::vector<std::filesystem::path> files() const = 0;
  // XXH3-64 of every input byte, in files() order: what the cook was made from, without a path.
  virtual std::uint64_t content_hash() const = 0;
  // Throws pstream::Error when an input file was truncated while it was being read.
  virtual void check_intact() const = 0;
  // Components of a float attribute, 0 when the source has none by that name.
  virtual std::uint32_t float_components(const std::string& name) const = 0;
  // Appends the particles at `time` to `out` (nearest sample, or blended when interpolating).
  virtual void read(double time, const Request& request, ParticleFrame& out) = 0;

  // The frame's positions and scales as views into the source (no copies), when the source can
  // give them for this request: the default [x y z scale] record's fast path. `positions` are
  // float32 x3 (possibly unaligned); each record's scale is scale_from_width(widths[i]), or
  // `constant_scale` when `widths` is null; positions go through `matrix` unless it is identity.
  struct DirectFrame {
    std::uint64_t count = 0;
    const std::byte* positions = nullptr;
    const std::byte* widths = nullptr;
    float constant_scale = 0.0f;
    bool identity = true;
    std::array<std::array<double, 4>, 4> matrix{};
  };
  virtual bool read_direct(double /*time*/, const Request& /*request*/, DirectFrame& /*out*/) { return false; }
};

// Which of a MemoryFrame's optional arrays a clip holds: those of its frames with particles.
struct MemoryAttributes {
  bool width = false, velocity = false, id = false, color = false;
  std::vector<std::pair<std::string, std::uint32_t>> floats;  // name and components, in the frames' order
  void add(const MemoryAttributes& other);                    // the union (a float's first components kept)
};
MemoryAttributes attributes_of(const MemoryFrame& frame);  // its non-empty arrays
// The frame's float attribute named `name`, or null.
const MemoryFloats* floats_named(const MemoryFrame& frame, const std::string& name);
// Throws pstream::Error naming `name`, frame `index` and what is wrong when the frame's time is
// not finite or not after `previous_time` (NaN for the first frame), an array does not hold
// count x components values for an attribute of `has` (none for the others), or a float
// attribute is not one of `has`'s with its components (1 to 16), named once and not as a
// built-in one.
void check_memory_frame(const std::string& name, std::size_t index, const MemoryFrame& frame,
                        const MemoryAttributes& has, double previous_time);

// A read-write file in `folder` that no name refers to (the frame spool's): O_TMPFILE where the
// file system has it, else named_then_unlinked_file(). Throws pstream::Error naming the folder.
int unnamed_file(const std::filesystem::path& folder);
// The fallback for file systems without O_TMPFILE (some network and FUSE ones): a file made under
// a fresh name in `folder` and unlinked at once, so that no name is left once this returns.
int named_then_unlinked_file(const std::filesystem::path& folder);

// `progress` hears of a URL's fetch (Stage::Fetch).
std::unique_ptr<Source> open_alembic(const Options& options, const std::function<void(const Progress&)>& progress = {});
std::unique_ptr<Source> open_ply_sequence(const Options& options);
std::unique_ptr<Source> open_memory(const Options& options, const MemoryClip& clip);

}  // namespace pstream::cook
