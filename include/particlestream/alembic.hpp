// Native reader of Alembic (Ogawa backend) point caches.
//
// Layers, as in the official library:
//   Ogawa   — the container: groups and data blocks in a memory-mapped file (src/alembic/ogawa.*)
//   Abc     — archive, time samplings, objects, compound/scalar/array properties (this header)
//   AbcGeom — Points, Xform, PolyMesh schemas and geometry parameters (this header)
//
// Handles (Object, Property, Points, Xform, PolyMesh) are cheap to copy and point into their
// Archive, which must outlive them. Sample data is read lazily from the mapping; an Archive is
// safe to read from several threads at once.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "particlestream/error.hpp"

namespace pstream::io {
class ByteSource;
}

namespace pstream::alembic {

namespace detail {
struct ArchiveData;
struct ObjectNode;
struct PropertyNode;
struct Access;  // the reader's own way to make handles (src/alembic/archive_data.hpp)
}  // namespace detail

// ---------------------------------------------------------------------------------------------
// Plain old data types, in Alembic's numbering.
enum class Pod : std::uint8_t {
  Bool = 0,
  Uint8,
  Int8,
  Uint16,
  Int16,
  Uint32,
  Int32,
  Uint64,
  Int64,
  Float16,
  Float32,
  Float64,
  String,
  WString
};
std::size_t pod_size(Pod pod);       // bytes of one scalar (string: 1, wstring: 4)
std::string_view pod_name(Pod pod);  // "float32", "uint64", ...
bool pod_is_integer(Pod pod);        // bool and the integer types
bool pod_is_float(Pod pod);          // float16/32/64

// ---------------------------------------------------------------------------------------------
// "key=value;key=value" metadata, kept sorted by key as the official library does.
class MetaData {
 public:
  static MetaData parse(std::string_view serialized);
  std::string get(std::string_view key) const;  // "" when absent
  bool has(std::string_view key) const;
  std::string serialize() const;
  const std::map<std::string, std::string, std::less<>>& entries() const { return entries_; }
  void set(std::string key, std::string value) { entries_[std::move(key)] = std::move(value); }

 private:
  std::map<std::string, std::string, std::less<>> entries_;
};

// ---------------------------------------------------------------------------------------------
enum class TimeSamplingType { Uniform, Cyclic, Acyclic };

struct TimeSampling {
  static constexpr double kAcyclicTimePerCycle = 1.7976931348623157e308 / 32.0;  // DBL_MAX / 32
  static constexpr std::uint32_t kAcyclicSamplesPerCycle = 0xFFFFFFFFu;

  TimeSamplingType type = TimeSamplingType::Uniform;
  std::uint32_t samples_per_cycle = 1;
  double time_per_cycle = 1.0;
  std::vector<double> stored_times{0.0};
  std::uint32_t max_num_samples = 0;  // most samples any property using it has

  // Time of sample `index` (uniform: start + index * time_per_cycle, exactly as Alembic computes it).
  double sample_time(std::uint64_t index) const;
  // Sample index whose time is <= / >= / nearest to `time`, for a property with `num_samples`
  // samples; the same tolerances and tie rules as Alembic's TimeSampling.
  std::pair<std::uint64_t, double> floor_index(double time, std::uint64_t num_samples) const;
  std::pair<std::uint64_t, double> ceil_index(double time, std::uint64_t num_samples) const;
  std::pair<std::uint64_t, double> near_index(double time, std::uint64_t num_samples) const;
};

// ---------------------------------------------------------------------------------------------
enum class PropertyKind { Compound, Scalar, Array };
std::string_view property_kind_name(PropertyKind kind);  // "compound", "scalar", "array"

struct PropertyHeader {
  std::string name;
  PropertyKind kind = PropertyKind::Compound;
  Pod pod = Pod::Uint8;
  std::uint8_t extent = 0;
  MetaData metadata;
  std::uint32_t time_sampling_index = 0;
  std::uint32_t num_samples = 0;    // samples written, repeats included
  std::uint32_t first_changed = 0;  // first sample that differs from sample 0
  std::uint32_t last_changed = 0;   // last sample that was stored; later ones repeat it
  bool scalar_like = false;         // an array property whose samples hold one element
  bool homogeneous = false;         // as flagged by the writer; not reliable for extent > 1

  bool is_constant() const { return first_changed == 0; }
  std::string interpretation() const { return metadata.get("interpretation"); }
  // Index of the stored sample that holds sample `index` (Alembic repeats are not stored).
  std::uint32_t stored_index(std::uint32_t index) const;
};

// One sample of a scalar or array property: a view of its values in the mapped file.
class SampleView {
 public:
  SampleView() = default;
  SampleView(Pod pod, std::uint8_t extent, std::uint64_t element_count, std::span<const std::byte> bytes)
      : pod_(pod), extent_(extent), count_(element_count), bytes_(bytes) {}

  Pod pod() const { return pod_; }
  std::uint8_t extent() const { return extent_; }
  std::uint64_t size() const { return count_; }                    // elements (extent values each)
  std::uint64_t scalar_count() const { return count_ * extent_; }  // values
  bool empty() const { return count_ == 0; }
  std::span<const std::byte> bytes() const { return bytes_; }

  // The values as a typed span over the file, when T is the stored type and the bytes are
  // aligned for T (no copy); std::nullopt otherwise — use copy_to then.
  template <class T>
  std::optional<std::span<const T>> as_span() const {
    if (sizeof(T) != pod_size(pod_) || reinterpret_cast<std::uintptr_t>(bytes_.data()) % alignof(T) != 0) {
      return std::nullopt;
    }
    return std::span<const T>(reinterpret_cast<const T*>(bytes_.data()), scalar_count());
  }
  // Copies the raw stored values into `out` (which must hold scalar_count() values of the stored
  // pod's size); returns the number of values copied. Never reads more than it writes.
  std::size_t copy_raw(std::span<std::byte> out) const;
  // Value `i` (0 <= i < scalar_count()) converted to double / to a 64-bit integer.
  double value_f64(std::uint64_t i) const;
  std::int64_t value_i64(std::uint64_t i) const;
  std::uint64_t value_u64(std::uint64_t i) const;
  // String and wstring samples: every element as UTF-8 (wstrings are stored as UTF-32 code
  // points), empty strings included; scalar_count() of them. Throws pstream::Error when the
  // bytes hold fewer terminated strings than that, or a code point that is not Unicode.
  std::vector<std::string> strings() const;

 private:
  Pod pod_ = Pod::Uint8;
  std::uint8_t extent_ = 0;
  std::uint64_t count_ = 0;
  std::span<const std::byte> bytes_;
};

class Archive;

class Property {
 public:
  Property() = default;
  bool valid() const { return node_ != nullptr; }
  const PropertyHeader& header() const;
  const std::string& name() const { return header().name; }
  PropertyKind kind() const { return header().kind; }
  bool is_compound() const { return kind() == PropertyKind::Compound; }
  const TimeSampling& time_sampling() const;

  // Compound properties.
  std::size_t child_count() const;
  Property child(std::size_t i) const;
  std::optional<Property> find(std::string_view name) const;

  // Scalar and array properties: sample `index` (0 <= index < num_samples).
  SampleView sample(std::uint32_t index) const;
  // The sample nearest to `time`, and which index that was.
  std::pair<SampleView, std::uint32_t> sample_at(double time) const;

 private:
  friend class Archive;
  friend class Object;
  friend struct detail::Access;
  Property(const detail::ArchiveData* archive, const detail::PropertyNode* node) : archive_(archive), node_(node) {}
  const detail::ArchiveData* archive_ = nullptr;
  const detail::PropertyNode* node_ = nullptr;
};

class Object {
 public:
  Object() = default;
  bool valid() const { return node_ != nullptr; }
  const std::string& name() const;
  const std::string& full_name() const;
  const MetaData& metadata() const;
  std::string schema() const { return metadata().get("schema"); }
  std::optional<Object> parent() const;  // nullopt for the top object "/"
  std::size_t child_count() const;
  Object child(std::size_t i) const;
  Property properties() const;  // the object's top compound property
  // Instances (OObject::addChildInstance): an instance root is presented as its target, with its
  // own name, path and parent and the target's metadata, properties and children; the objects
  // below it have instanced paths. As IObject::isInstanceRoot, isInstanceDescendant,
  // instanceSourcePath ("" unless a root) and getHeader().getFullName() (the stored object).
  bool is_instance_root() const;
  bool is_instance_descendant() const;
  const std::string& instance_source_path() const;
  const std::string& stored_full_name() const;

 private:
  friend class Archive;
  Object(const detail::ArchiveData* archive, const detail::ObjectNode* node) : archive_(archive), node_(node) {}
  const detail::ArchiveData* archive_ = nullptr;
  const detail::ObjectNode* node_ = nullptr;
};

struct ArchiveInfo {
  std::string app_name;
  std::string alembic_version_string;
  std::uint32_t alembic_api_version = 0;
  std::string date_written;
  std::string user_description;
  double dcc_fps = 0.0;  // 0 when the writer did not record it
};

class Archive {
 public:
  // Opens and validates an Ogawa archive. Throws pstream::Error (file, offset, what was expected)
  // for anything that is not a complete, well-formed Ogawa Alembic file — the HDF5 backend,
  // a file still being written, truncation, corrupted offsets, cycles.
  // A local file is mapped and read in place. An http(s):// URL is read whole into memory first
  // (the reader needs every offset at hand): one allocation of the size the server gives, whose
  // pages are taken as the bytes arrive, refused when it is more than the machine's memory.
  // `fetched(done, total)` is called after each 8 MiB read (long work; nothing for a local file).
  using Fetched = std::function<void(std::uint64_t done, std::uint64_t total)>;
  static Archive open(const std::filesystem::path& path, const Fetched& fetched = {});
  // The same from any byte source (particlestream/io.hpp): read in place when the source is
  // mapped, otherwise read whole into memory as a URL is.
  static Archive open(std::unique_ptr<io::ByteSource> source, const Fetched& fetched = {});
  // The same for bytes in memory, which must outlive the Archive (fuzzing, embedded data).
  static Archive from_memory(std::span<const std::byte> bytes, std::string name);

  Archive(Archive&&) noexcept;
  Archive& operator=(Archive&&) noexcept;
  ~Archive();

  const std::string& name() const;
  std::uint64_t file_size() const;
  std::span<const std::byte> bytes() const;  // the whole mapped file
  std::uint32_t ogawa_file_version() const;
  std::uint32_t archive_version() const;  // library version that wrote it, e.g. 10812
  const MetaData& metadata() const;
  ArchiveInfo info() const;
  const std::vector<TimeSampling>& time_samplings() const;
  const TimeSampling& time_sampling(std::uint32_t index) const;
  // Earliest and latest sample time of the archive, as Abc::GetArchiveStartAndEndTime: from the
  // non-default samplings with several samples; failing those, from the ones with one sample;
  // failing those, from the default sampling. When no property has a sample, start = +DBL_MAX
  // and end = -DBL_MAX.
  std::pair<double, double> start_end_time() const;
  // Throws pstream::Error when the file was truncated while this archive read it (the reads past
  // the new end saw zeros; see MappedFile). Call it before trusting what was read.
  void check_intact() const;

  Object top() const;
  std::optional<Object> find(std::string_view full_name) const;
  // Every object below the top, depth first, parents before children.
  std::vector<Object> objects() const;

 private:
  explicit Archive(std::unique_ptr<detail::ArchiveData> data);
  friend class Object;
  std::unique_ptr<detail::ArchiveData> d_;
};

// ---------------------------------------------------------------------------------------------
// AbcGeom

using Matrix44 = std::array<std::array<double, 4>, 4>;  // Imath M44d rows; p_world = p_local * M
Matrix44 identity_matrix();
Matrix44 multiply(const Matrix44& a, const Matrix44& b);  // a * b

struct Box3 {
  std::array<double, 3> min{};
  std::array<double, 3> max{};
  bool is_empty() const { return max[0] < min[0] || max[1] < min[1] || max[2] < min[2]; }
  static Box3 empty();
};

enum class GeomScope { Constant, Uniform, Varying, Vertex, FaceVarying, Unknown };
std::string_view geom_scope_name(GeomScope scope);  // "constant", "vertex", ...

// A typed geometry parameter (.widths, arbGeomParams such as Cd, age): an array or scalar
// property, or, when indexed, a compound holding .vals and .indices.
class GeomParam {
 public:
  static GeomParam from(const Property& property);
  const std::string& name() const { return property_.name(); }
  GeomScope scope() const { return scope_; }
  bool indexed() const { return indices_.valid(); }
  const Property& property() const { return property_; }
  const Property& values() const { return values_; }
  const Property& indices() const { return indices_; }  // invalid unless indexed
  std::uint32_t num_samples() const;
  const TimeSampling& time_sampling() const { return values_.time_sampling(); }
  // Index of the sample nearest to `time` (what Alembic reads for ISampleSelector(time)).
  std::uint32_t sample_index_at(double time) const;

 private:
  Property property_, values_, indices_;
  GeomScope scope_ = GeomScope::Unknown;
};

class Points {
 public:
  static bool matches(const Object& object);  // schema AbcGeom_Points_v1
  explicit Points(const Object& object);      // throws if the object is not a valid Points

  const Object& object() const { return object_; }
  std::uint32_t num_samples() const;          // max of P and .pointIds
  std::uint32_t time_sampling_index() const;  // P's
  const TimeSampling& time_sampling() const;
  double sample_time(std::uint32_t index) const { return time_sampling().sample_time(index); }
  bool is_constant() const;

  std::uint64_t count(std::uint32_t sample) const;   // particles in a sample
  SampleView positions(std::uint32_t sample) const;  // float32 x3
  bool has_ids() const { return ids_.valid(); }
  SampleView ids(std::uint32_t sample) const;  // uint64 (may be empty)
  bool has_velocities() const { return velocities_.valid(); }
  SampleView velocities(std::uint32_t sample) const;  // nearest to the sample's time
  Box3 self_bounds(std::uint32_t sample) const;
  const std::optional<GeomParam>& widths() const { return widths_; }
  const std::vector<GeomParam>& arb_geom_params() const { return arb_; }
  const GeomParam* find_param(std::string_view name) const;  // "widths"/".widths" or an arbGeomParam

  // Copies into the caller's buffer; throws if it is too small. Returns values written.
  std::size_t read_positions(std::uint32_t sample, std::span<float> out) const;
  std::size_t read_ids(std::uint32_t sample, std::span<std::uint64_t> out) const;
  std::size_t read_velocities(std::uint32_t sample, std::span<float> out) const;
  // Any float parameter (widths, Cd, age...) expanded through its indices, converted to float.
  std::size_t read_param(std::string_view name, std::uint32_t sample, std::span<float> out) const;

 private:
  Object object_;
  Property geom_, P_, ids_, velocities_, self_bounds_;
  std::optional<GeomParam> widths_;
  std::vector<GeomParam> arb_;
};

enum class XformOpType : std::uint8_t { Scale = 0, Translate, Rotate, Matrix, RotateX, RotateY, RotateZ };
std::string_view xform_op_name(XformOpType type);
std::size_t xform_op_channel_count(XformOpType type);

struct XformOp {
  XformOpType type = XformOpType::Translate;
  std::uint8_t hint = 0;
  std::array<double, 16> channels{};
  std::size_t channel_count() const { return xform_op_channel_count(type); }
  Matrix44 matrix() const;
};

struct XformSample {
  bool inherits = true;
  std::vector<XformOp> ops;
  Matrix44 matrix() const;  // opN * ... * op0, as Imath's XformSample::getMatrix
};

class Xform {
 public:
  static bool matches(const Object& object);  // schema AbcGeom_Xform_v3
  explicit Xform(const Object& object);

  std::uint32_t num_samples() const;  // .inherits' count (0 when absent)
  std::uint32_t time_sampling_index() const;
  const TimeSampling& time_sampling() const;
  bool is_constant() const;
  bool is_constant_identity() const;
  XformSample sample(std::uint32_t index) const;
  XformSample sample_at(double time) const;  // nearest stored sample, no interpolation

 private:
  Object object_;
  Property inherits_, vals_;
  std::vector<XformOp> ops_;
  bool constant_identity_ = true;
};

// World matrix of `object` at `time`: the product of the local matrices of it and its xform
// ancestors (nearest samples), stopping at an xform that does not inherit.
Matrix44 world_matrix(const Object& object, double time);
// The same for the object's parent: what positions stored in the object's space need.
Matrix44 parent_world_matrix(const Object& object, double time);

class PolyMesh {
 public:
  static bool matches(const Object& object);  // schema AbcGeom_PolyMesh_v1
  explicit PolyMesh(const Object& object);
  std::uint32_t num_samples() const;
  std::uint32_t time_sampling_index() const;
  const TimeSampling& time_sampling() const;
  int topology_variance() const;  // 0 constant, 1 homogeneous, 2 heterogeneous
  SampleView positions(std::uint32_t sample) const;
  SampleView face_counts(std::uint32_t sample) const;
  SampleView face_indices(std::uint32_t sample) const;
  bool has_velocities() const { return velocities_.valid(); }
  SampleView velocities(std::uint32_t sample) const;
  Box3 self_bounds(std::uint32_t sample) const;
  std::vector<GeomParam> arb_geom_params() const;

 private:
  Object object_;
  Property geom_, P_, counts_, indices_, velocities_, self_bounds_;
};

// The "visible" property (int8: -1 deferred, 0 hidden, 1 visible) of an object at a time, if any.
std::optional<int> visibility(const Object& object, double time);

// Human-readable kind of an object's schema: "points", "xform", "polymesh" or "other".
std::string_view object_kind(const Object& object);

}  // namespace pstream::alembic
