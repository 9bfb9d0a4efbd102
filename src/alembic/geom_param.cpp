#include <fmt/format.h>

#include "particlestream/alembic.hpp"

namespace pstream::alembic {
namespace {

GeomScope parse_scope(const MetaData& md) {
  if (!md.has("geoScope")) return GeomScope::Constant;  // what the official reader assumes
  const std::string s = md.get("geoScope");
  if (s == "con") return GeomScope::Constant;
  if (s == "uni") return GeomScope::Uniform;
  if (s == "var") return GeomScope::Varying;
  if (s == "vtx") return GeomScope::Vertex;
  if (s == "fvr") return GeomScope::FaceVarying;
  return GeomScope::Unknown;
}

}  // namespace

std::string_view geom_scope_name(GeomScope scope) {
  switch (scope) {
    case GeomScope::Constant: return "constant";
    case GeomScope::Uniform: return "uniform";
    case GeomScope::Varying: return "varying";
    case GeomScope::Vertex: return "vertex";
    case GeomScope::FaceVarying: return "facevarying";
    case GeomScope::Unknown: return "unknown";
  }
  return "unknown";
}

GeomParam GeomParam::from(const Property& property) {
  GeomParam p;
  p.property_ = property;
  p.scope_ = parse_scope(property.header().metadata);
  if (property.is_compound()) {
    auto vals = property.find(".vals");
    auto indices = property.find(".indices");
    if (!vals || !indices || vals->is_compound() || indices->is_compound()) {
      throw Error(fmt::format("indexed geometry parameter '{}' lacks its .vals or .indices property", property.name()));
    }
    p.values_ = *vals;
    p.indices_ = *indices;
  } else {
    p.values_ = property;
  }
  return p;
}

std::uint32_t GeomParam::num_samples() const {
  const std::uint32_t n = values_.header().num_samples;
  return indexed() ? std::max(n, indices_.header().num_samples) : n;
}

std::uint32_t GeomParam::sample_index_at(double time) const {
  return static_cast<std::uint32_t>(time_sampling().near_index(time, values_.header().num_samples).first);
}

std::string_view object_kind(const Object& object) {
  const std::string schema = object.schema();
  if (schema == "AbcGeom_Points_v1") return "points";
  if (schema == "AbcGeom_Xform_v3") return "xform";
  if (schema == "AbcGeom_PolyMesh_v1") return "polymesh";
  return "other";
}

std::optional<int> visibility(const Object& object, double time) {
  const auto visible = object.properties().find("visible");
  if (!visible || visible->is_compound() || visible->header().num_samples == 0) return std::nullopt;
  const SampleView v = visible->sample_at(time).first;
  if (v.scalar_count() == 0) return std::nullopt;
  return static_cast<int>(v.value_i64(0));
}

}  // namespace pstream::alembic
