#include <algorithm>

#include <fmt/format.h>

#include "particlestream/alembic.hpp"

namespace pstream::alembic {
namespace {

SampleView sample_or_empty(const Property& p, std::uint32_t index, Pod pod, std::uint8_t extent) {
  if (!p.valid() || p.header().num_samples == 0) return SampleView(pod, extent, 0, {});
  return p.sample(std::min(index, p.header().num_samples - 1));
}

std::uint32_t samples_of(const Property& p) { return p.valid() ? p.header().num_samples : 0; }
bool constant(const Property& p) { return !p.valid() || p.header().is_constant(); }

}  // namespace

bool PolyMesh::matches(const Object& object) { return object.schema() == "AbcGeom_PolyMesh_v1"; }

PolyMesh::PolyMesh(const Object& object) : object_(object) {
  const auto geom = object.properties().find(".geom");
  if (!geom || !geom->is_compound())
    throw Error(fmt::format("'{}' is not a PolyMesh (no .geom compound)", object.full_name()));
  geom_ = *geom;
  const auto P = geom_.find("P");
  if (!P || P->kind() != PropertyKind::Array || P->header().pod != Pod::Float32 || P->header().extent != 3) {
    throw Error(fmt::format("PolyMesh '{}' has no P property of float32 x3 arrays", object.full_name()));
  }
  P_ = *P;
  if (auto p = geom_.find(".faceCounts"); p && p->kind() == PropertyKind::Array) counts_ = *p;
  if (auto p = geom_.find(".faceIndices"); p && p->kind() == PropertyKind::Array) indices_ = *p;
  if (auto p = geom_.find(".velocities"); p && p->kind() == PropertyKind::Array && p->header().pod == Pod::Float32)
    velocities_ = *p;
  if (auto p = geom_.find(".selfBnds");
      p && p->kind() == PropertyKind::Scalar && p->header().pod == Pod::Float64 && p->header().extent == 6) {
    self_bounds_ = *p;
  }
}

std::uint32_t PolyMesh::num_samples() const {
  return std::max({samples_of(P_), samples_of(counts_), samples_of(indices_)});
}
std::uint32_t PolyMesh::time_sampling_index() const { return P_.header().time_sampling_index; }
const TimeSampling& PolyMesh::time_sampling() const { return P_.time_sampling(); }

int PolyMesh::topology_variance() const {
  if (constant(P_) && constant(indices_) && constant(counts_)) return 0;
  if (constant(indices_) && constant(counts_)) return 1;
  return 2;
}

SampleView PolyMesh::positions(std::uint32_t sample) const { return sample_or_empty(P_, sample, Pod::Float32, 3); }
SampleView PolyMesh::face_counts(std::uint32_t sample) const { return sample_or_empty(counts_, sample, Pod::Int32, 1); }
SampleView PolyMesh::face_indices(std::uint32_t sample) const {
  return sample_or_empty(indices_, sample, Pod::Int32, 1);
}

SampleView PolyMesh::velocities(std::uint32_t sample) const {
  if (!velocities_.valid() || velocities_.header().num_samples == 0) return SampleView(Pod::Float32, 3, 0, {});
  return velocities_.sample_at(time_sampling().sample_time(sample)).first;
}

Box3 PolyMesh::self_bounds(std::uint32_t sample) const {
  const SampleView v = sample_or_empty(self_bounds_, sample, Pod::Float64, 6);
  if (v.scalar_count() < 6) return Box3::empty();
  return Box3{{v.value_f64(0), v.value_f64(1), v.value_f64(2)}, {v.value_f64(3), v.value_f64(4), v.value_f64(5)}};
}

std::vector<GeomParam> PolyMesh::arb_geom_params() const {
  std::vector<GeomParam> out;
  if (auto arb = geom_.find(".arbGeomParams"); arb && arb->is_compound()) {
    for (std::size_t i = 0; i < arb->child_count(); ++i) out.push_back(GeomParam::from(arb->child(i)));
  }
  return out;
}

}  // namespace pstream::alembic
