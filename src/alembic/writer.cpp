// The Ogawa writer. Sample data is appended as it comes; the groups that point at it (property,
// compound, object, root) are written at close, children before parents, as Ogawa requires.
#include "particlestream/alembic_writer.hpp"

#include <xxhash.h>

#include <cerrno>
#include <cfloat>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <ctime>

#include <fmt/format.h>

#include "alembic/layout.hpp"
#include "base/output_file.hpp"
#include "particlestream/alembic.hpp"

namespace pstream::alembic {
namespace {

using namespace layout;

// Appends through an OutputFile: the archive appears at its path, complete, only at close.
class OgawaOut {
 public:
  explicit OgawaOut(const std::filesystem::path& path) : file_(OutputFile::create(path)) {
    const unsigned char header[kHeaderSize] = {'O', 'g', 'a', 'w', 'a', kNotFrozen, 0, 1};  // root offset set at close
    put(header, sizeof header);
  }
  std::uint64_t data(const void* bytes, std::uint64_t size) {  // a data block: size, then bytes
    if (size == 0) return kDataBit;
    const std::uint64_t at = position_;
    put(&size, 8);
    put(bytes, size);
    return at | kDataBit;
  }
  std::uint64_t data(const std::string& s) { return data(s.data(), s.size()); }
  std::uint64_t group(const std::vector<std::uint64_t>& children) {
    if (children.empty()) return 0;
    const std::uint64_t at = position_, n = children.size();
    put(&n, 8);
    put(children.data(), n * 8);
    return at;
  }
  void finish(std::uint64_t root) {  // the root offset, then the frozen byte: the file is complete
    file_.write_at(8, std::as_bytes(std::span(&root, 1)));
    const auto frozen = static_cast<std::byte>(kFrozen);
    file_.write_at(5, std::span(&frozen, 1));
    file_.commit();
  }
  std::uint64_t position() const { return position_; }

 private:
  void put(const void* p, std::uint64_t n) {
    file_.append(p, n);
    position_ += n;
  }
  OutputFile file_;
  std::uint64_t position_ = 0;
};

// A scalar or array property: keeps the sample bookkeeping Alembic's reader expects
// (first/last changed index; repeats of the previous sample are not stored again).
struct PropertyOut {
  PropertyOut() = default;
  PropertyOut(std::string n, std::string md, PropertyKind k, Pod p, std::uint8_t e, std::uint32_t ts = 1)
      : name(std::move(n)), metadata(std::move(md)), kind(k), pod(p), extent(e), time_sampling(ts) {}
  std::string name, metadata;
  PropertyKind kind = PropertyKind::Array;
  Pod pod = Pod::Float32;
  std::uint8_t extent = 1;
  std::uint32_t time_sampling = 1;
  std::uint32_t num_samples = 0, first_changed = 0, last_changed = 0;
  std::vector<std::uint64_t> stored;  // group children: (data, dims) per stored array sample
  XXH128_hash_t last_key{};
  std::uint64_t last_data = 0;

  void add(OgawaOut& out, const void* values, std::size_t bytes) {
    const XXH128_hash_t key = XXH3_128bits(values, bytes);
    if (num_samples > 0 && XXH128_isEqual(key, last_key)) {  // a repeat: stored by reference, if ever
      ++num_samples;
      return;
    }
    std::uint64_t data_ref = kDataBit;
    if (bytes > 0 || kind == PropertyKind::Scalar) {
      std::vector<unsigned char> block(kSampleKeyBytes + bytes);
      std::memcpy(block.data(), &key, kSampleKeyBytes);
      if (bytes) std::memcpy(block.data() + kSampleKeyBytes, values, bytes);
      data_ref = out.data(block.data(), block.size());
    }
    const std::uint32_t n = num_samples;
    if (n > 0) {
      if (first_changed == 0) {
        first_changed = n;  // samples 1 .. n-1 repeat sample 0, which stays in slot 0
      } else {
        for (std::uint32_t i = last_changed + 1; i < n; ++i) push(last_data);  // repeats in the middle share a block
      }
      last_changed = n;
    }
    push(data_ref);
    last_key = key;
    last_data = data_ref;
    ++num_samples;
  }
  void push(std::uint64_t data_ref) {
    stored.push_back(data_ref);
    if (kind == PropertyKind::Array) stored.push_back(kDataBit);  // rank-1 arrays: empty dimensions
  }
};

struct CompoundOut {
  CompoundOut(std::string n, std::string md) : name(std::move(n)), metadata(std::move(md)) {}
  std::string name, metadata;
  std::vector<PropertyOut*> properties;  // in header order; compounds below are kept apart
  std::vector<CompoundOut*> compounds;
  std::vector<bool> is_compound;  // per child, in order
};

void put_sized(std::string& out, std::uint32_t v, unsigned hint) {
  if (hint == 0) {
    out.push_back(static_cast<char>(v));
  } else if (hint == 1) {
    const auto s = static_cast<std::uint16_t>(v);
    out.append(reinterpret_cast<const char*>(&s), 2);
  } else {
    out.append(reinterpret_cast<const char*>(&v), 4);
  }
}

unsigned size_hint(std::initializer_list<std::uint64_t> values) {
  std::uint64_t m = 0;
  for (auto v : values) m = std::max(m, v);
  return m < 256 ? 0 : m < 65536 ? 1 : 2;
}

void header_for(std::string& out, const std::string& name, const std::string& md, PropertyKind kind,
                const PropertyOut* p) {
  using namespace layout::info;
  const std::uint32_t md_index = md.empty() ? 0 : kMetadataInline;
  std::uint32_t info = kind == PropertyKind::Compound ? 0 : kind == PropertyKind::Scalar ? 1 : 2;
  unsigned hint = size_hint({name.size(), md.size()});
  bool explicit_first_last = false;
  if (p != nullptr) {
    hint = size_hint({name.size(), md.size(), p->num_samples, p->first_changed, p->last_changed, p->time_sampling});
    info |= static_cast<std::uint32_t>(p->pod) << kPodShift;
    if (p->time_sampling != 0) info |= kHasTimeSampling;
    if (p->first_changed == 0 && p->last_changed == 0) {
      info |= kConstant;
    } else if (p->first_changed != 1 || p->last_changed != p->num_samples - 1) {
      info |= kHasFirstLast;
      explicit_first_last = true;
    }
    info |= static_cast<std::uint32_t>(p->extent) << kExtentShift;
  }
  info |= hint << kSizeHintShift;
  info |= md_index << kMetadataShift;
  out.append(reinterpret_cast<const char*>(&info), 4);
  if (p != nullptr) {
    put_sized(out, p->num_samples, hint);
    if (explicit_first_last) {
      put_sized(out, p->first_changed, hint);
      put_sized(out, p->last_changed, hint);
    }
    if (p->time_sampling != 0) put_sized(out, p->time_sampling, hint);
  }
  put_sized(out, static_cast<std::uint32_t>(name.size()), hint);
  out += name;
  if (md_index == kMetadataInline) {
    put_sized(out, static_cast<std::uint32_t>(md.size()), hint);
    out += md;
  }
}

std::uint64_t write_compound(OgawaOut& out, const CompoundOut& c) {
  std::vector<std::uint64_t> children;
  std::string headers;
  std::size_t pi = 0, ci = 0;
  for (bool compound : c.is_compound) {
    if (compound) {
      const CompoundOut& sub = *c.compounds[ci++];
      children.push_back(write_compound(out, sub));
      header_for(headers, sub.name, sub.metadata, PropertyKind::Compound, nullptr);
    } else {
      const PropertyOut& p = *c.properties[pi++];
      children.push_back(out.group(p.stored));
      header_for(headers, p.name, p.metadata, p.kind, &p);
    }
  }
  if (children.empty()) return 0;
  children.push_back(out.data(headers));
  return out.group(children);
}

std::string object_headers(const std::vector<std::pair<std::string, std::string>>& children) {
  std::string s;
  for (const auto& [name, md] : children) {
    const auto name_size = static_cast<std::uint32_t>(name.size()), md_size = static_cast<std::uint32_t>(md.size());
    s.append(reinterpret_cast<const char*>(&name_size), 4);
    s += name;
    s.push_back(static_cast<char>(kMetadataInline));
    s.append(reinterpret_cast<const char*>(&md_size), 4);
    s += md;
  }
  return s + std::string(kObjectHashBytes, '\0');
}

std::string geom_param_md(int extent, const char* interpretation) {
  return fmt::format("arrayExtent=1;geoScope=vtx;{}isGeomParam=true;podExtent={};podName=float32_t",
                     *interpretation ? fmt::format("interpretation={};", interpretation) : std::string(), extent);
}

}  // namespace

struct ArchiveWriter::Impl {
  OgawaOut out;
  PointsWriterOptions options;
  double fps = 24, start = 0;
  std::string metadata;
  PropertyOut bounds, P, ids, velocities, widths;
  std::vector<PropertyOut> params;
  bool closed = false;

  explicit Impl(const std::filesystem::path& path) : out(path) {}
};

ArchiveWriter::ArchiveWriter(const std::filesystem::path& path, const std::string& application,
                             const std::string& description, double fps, double start_time,
                             const PointsWriterOptions& points)
    : impl_(std::make_unique<Impl>(path)) {
  Impl& d = *impl_;
  if (!(fps > 0)) throw Error(fmt::format("{}: frame rate {} must be positive", path.string(), fps));
  d.options = points;
  d.fps = fps;
  d.start = start_time;
  const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  char date[64];
  std::strftime(date, sizeof date, "%a %b %e %H:%M:%S %Y", std::localtime(&now));
  MetaData md;
  md.set("_ai_AlembicVersion", "ParticleStream 0.1 Ogawa writer");
  md.set("_ai_Application", application);
  md.set("_ai_DCC_FPS", fmt::format("{:f}", fps));
  md.set("_ai_DateWritten", date);
  md.set("_ai_Description", description);
  d.metadata = md.serialize();
  d.bounds = PropertyOut(".selfBnds", "interpretation=box", PropertyKind::Scalar, Pod::Float64, 6);
  d.P = PropertyOut("P", "geoScope=var;interpretation=point", PropertyKind::Array, Pod::Float32, 3);
  d.ids = PropertyOut(".pointIds", "geoScope=var", PropertyKind::Array, Pod::Uint64, 1);
  d.velocities = PropertyOut(".velocities", "interpretation=vector", PropertyKind::Array, Pod::Float32, 3);
  d.widths = PropertyOut(".widths", geom_param_md(1, ""), PropertyKind::Array, Pod::Float32, 1);
  for (const auto& [name, extent] : points.float_params) {
    if (extent < 1 || extent > 16) throw Error(fmt::format("parameter '{}': extent {} must be 1..16", name, extent));
    d.params.emplace_back(name,
                          geom_param_md(extent, name != "Cd"  ? ""
                                                : extent == 3 ? "rgb"
                                                : extent == 4 ? "rgba"
                                                              : ""),
                          PropertyKind::Array, Pod::Float32, static_cast<std::uint8_t>(extent));
  }
}

ArchiveWriter::~ArchiveWriter() = default;  // an unclosed archive's temporary is removed

std::uint64_t ArchiveWriter::bytes_written() const { return impl_->out.position(); }

void ArchiveWriter::write_sample(const PointsSample& s) {
  Impl& d = *impl_;
  if (d.closed) throw Error("ArchiveWriter: write_sample after close");
  const std::size_t n = s.positions.size() / 3;
  const auto check = [&](std::size_t have, std::size_t want, const char* what) {
    if (have != want)
      throw Error(fmt::format("Alembic sample {}: {} values of {} for {} particles, expected {}", d.P.num_samples, have,
                              what, n, want));
  };
  check(s.positions.size(), n * 3, "P");
  check(s.ids.size(), n, ".pointIds");
  if (d.options.velocities) check(s.velocities.size(), n * 3, ".velocities");
  if (d.options.widths) check(s.widths.size(), n, ".widths");
  if (s.params.size() != d.params.size()) throw Error("Alembic sample: wrong number of parameters");
  double box[6] = {DBL_MAX, DBL_MAX, DBL_MAX, -DBL_MAX, -DBL_MAX, -DBL_MAX};
  for (std::size_t i = 0; i < n; ++i) {
    for (int c = 0; c < 3; ++c) {
      box[c] = std::min(box[c], double(s.positions[i * 3 + c]));
      box[c + 3] = std::max(box[c + 3], double(s.positions[i * 3 + c]));
    }
  }
  d.bounds.add(d.out, box, sizeof box);
  d.P.add(d.out, s.positions.data(), s.positions.size_bytes());
  d.ids.add(d.out, s.ids.data(), s.ids.size_bytes());
  if (d.options.velocities) d.velocities.add(d.out, s.velocities.data(), s.velocities.size_bytes());
  if (d.options.widths) d.widths.add(d.out, s.widths.data(), s.widths.size_bytes());
  for (std::size_t k = 0; k < d.params.size(); ++k) {
    check(s.params[k].size(), n * d.params[k].extent, d.params[k].name.c_str());
    d.params[k].add(d.out, s.params[k].data(), s.params[k].size_bytes());
  }
}

void ArchiveWriter::close() {
  Impl& d = *impl_;
  if (d.closed) return;
  d.closed = true;
  OgawaOut& out = d.out;
  // The points object: .geom holds the schema's properties and .arbGeomParams.
  CompoundOut arb{".arbGeomParams", ""}, geom{".geom", "schema=AbcGeom_Points_v1;schemaBaseType=AbcGeom_GeomBase_v1"};
  for (auto& p : d.params) {
    arb.properties.push_back(&p);
    arb.is_compound.push_back(false);
  }
  for (PropertyOut* p : {&d.bounds, &d.P, &d.ids}) {
    geom.properties.push_back(p);
    geom.is_compound.push_back(false);
  }
  if (!d.params.empty()) {
    geom.compounds.push_back(&arb);
    geom.is_compound.push_back(true);
  }
  if (d.options.velocities) geom.properties.push_back(&d.velocities), geom.is_compound.push_back(false);
  if (d.options.widths) geom.properties.push_back(&d.widths), geom.is_compound.push_back(false);
  CompoundOut points_top{"", ""};
  points_top.compounds.push_back(&geom);
  points_top.is_compound.push_back(true);
  const std::uint64_t points_props = write_compound(out, points_top);
  const std::uint64_t points_object = out.group({points_props, out.data(object_headers({}))});
  const std::string points_md =
      "schema=AbcGeom_Points_v1;schemaBaseType=AbcGeom_GeomBase_v1;schemaObjTitle=AbcGeom_Points_v1:.geom";

  std::uint64_t top_child = points_object;
  std::string top_name = d.options.name, top_md = points_md;
  std::uint32_t ts0_samples = 0;
  if (!d.options.parent_xform.empty()) {  // a constant Xform: one translate op, one sample
    PropertyOut inherits{".inherits", "", PropertyKind::Scalar, Pod::Bool, 1, 0};
    PropertyOut ops{".ops", "", PropertyKind::Scalar, Pod::Uint8, 1, 0};
    PropertyOut vals{".vals", "", PropertyKind::Scalar, Pod::Float64, 3, 0};
    PropertyOut identity{"isNotConstantIdentity", "", PropertyKind::Scalar, Pod::Bool, 1, 0};
    const std::uint8_t yes = 1, translate_op = static_cast<std::uint8_t>(XformOpType::Translate) << 4;
    inherits.add(out, &yes, 1);
    ops.add(out, &translate_op, 1);
    vals.add(out, d.options.translate.data(), 24);
    identity.add(out, &yes, 1);
    CompoundOut xform{".xform", "schema=AbcGeom_Xform_v3"};
    for (PropertyOut* p : {&inherits, &ops, &vals, &identity})
      xform.properties.push_back(p), xform.is_compound.push_back(false);
    CompoundOut xform_top{"", ""};
    xform_top.compounds.push_back(&xform);
    xform_top.is_compound.push_back(true);
    const std::uint64_t xform_props = write_compound(out, xform_top);
    top_child = out.group({xform_props, points_object, out.data(object_headers({{d.options.name, points_md}}))});
    top_name = d.options.parent_xform;
    top_md = "schema=AbcGeom_Xform_v3;schemaObjTitle=AbcGeom_Xform_v3:.xform";
    ts0_samples = 1;
  }
  const std::uint64_t top = out.group({0, top_child, out.data(object_headers({{top_name, top_md}}))});

  std::string samplings;
  const auto sampling = [&](std::uint32_t max_samples, double per_cycle, double first) {
    const std::uint32_t one = 1;
    samplings.append(reinterpret_cast<const char*>(&max_samples), 4);
    samplings.append(reinterpret_cast<const char*>(&per_cycle), 8);
    samplings.append(reinterpret_cast<const char*>(&one), 4);
    samplings.append(reinterpret_cast<const char*>(&first), 8);
  };
  sampling(ts0_samples, 1.0, 0.0);
  sampling(d.P.num_samples, 1.0 / d.fps, d.start);
  const std::uint32_t file_version = 0, library_version = 10812;  // the Ogawa layout of Alembic 1.8.12
  const std::uint64_t root = out.group({out.data(&file_version, 4), out.data(&library_version, 4), top,
                                        out.data(d.metadata), out.data(samplings), kDataBit});
  out.finish(root);
}

}  // namespace pstream::alembic
