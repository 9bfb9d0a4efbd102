#include <algorithm>
#include <cstring>

#include <fmt/format.h>

#include "particlestream/alembic.hpp"

namespace pstream::alembic {
namespace {

std::uint32_t clamp_index(std::uint32_t index, const Property& p) {
  const std::uint32_t n = p.header().num_samples;
  return n == 0 ? 0 : std::min(index, n - 1);
}

void check_capacity(const Object& object, std::string_view what, std::uint32_t sample, std::size_t need,
                    std::size_t have) {
  if (have < need) {
    throw Error(fmt::format("{} of '{}' sample {}: buffer holds {} values, {} are needed", what, object.full_name(),
                            sample, have, need));
  }
}

}  // namespace

Box3 Box3::empty() {
  constexpr double big = 1.7976931348623157e308;
  return Box3{{big, big, big}, {-big, -big, -big}};
}

bool Points::matches(const Object& object) { return object.schema() == "AbcGeom_Points_v1"; }

Points::Points(const Object& object) : object_(object) {
  if (!matches(object)) {
    throw Error(fmt::format("'{}' is not a Points object (schema '{}')", object.full_name(), object.schema()));
  }
  const auto geom = object.properties().find(".geom");
  if (!geom || !geom->is_compound())
    throw Error(fmt::format("'{}' is not a Points object (no .geom compound)", object.full_name()));
  geom_ = *geom;
  const auto P = geom_.find("P");
  if (!P || P->kind() != PropertyKind::Array || P->header().pod != Pod::Float32 || P->header().extent != 3) {
    throw Error(fmt::format("Points '{}' has no P property of float32 x3 arrays", object.full_name()));
  }
  P_ = *P;
  if (auto ids = geom_.find(".pointIds"); ids && ids->kind() == PropertyKind::Array) {
    if (ids->header().pod != Pod::Uint64 || ids->header().extent != 1) {
      throw Error(fmt::format("Points '{}': .pointIds is {} x {}, expected uint64", object.full_name(),
                              pod_name(ids->header().pod), int(ids->header().extent)));
    }
    ids_ = *ids;
  }
  if (auto v = geom_.find(".velocities"); v && v->kind() == PropertyKind::Array) {
    if (v->header().pod != Pod::Float32 || v->header().extent != 3) {
      throw Error(fmt::format("Points '{}': .velocities is not float32 x3", object.full_name()));
    }
    velocities_ = *v;
  }
  if (auto b = geom_.find(".selfBnds");
      b && b->kind() == PropertyKind::Scalar && b->header().pod == Pod::Float64 && b->header().extent == 6) {
    self_bounds_ = *b;
  }
  if (auto w = geom_.find(".widths")) widths_ = GeomParam::from(*w);
  if (auto arb = geom_.find(".arbGeomParams"); arb && arb->is_compound()) {
    for (std::size_t i = 0; i < arb->child_count(); ++i) arb_.push_back(GeomParam::from(arb->child(i)));
  }
}

std::uint32_t Points::num_samples() const {
  return std::max(P_.header().num_samples, ids_.valid() ? ids_.header().num_samples : 0u);
}
std::uint32_t Points::time_sampling_index() const { return P_.header().time_sampling_index; }
const TimeSampling& Points::time_sampling() const { return P_.time_sampling(); }
bool Points::is_constant() const { return P_.header().is_constant() && (!ids_.valid() || ids_.header().is_constant()); }

SampleView Points::positions(std::uint32_t sample) const {
  if (P_.header().num_samples == 0) return SampleView(Pod::Float32, 3, 0, {});
  return P_.sample(clamp_index(sample, P_));
}

std::uint64_t Points::count(std::uint32_t sample) const { return positions(sample).size(); }

SampleView Points::ids(std::uint32_t sample) const {
  if (!ids_.valid() || ids_.header().num_samples == 0) return SampleView(Pod::Uint64, 1, 0, {});
  return ids_.sample(clamp_index(sample, ids_));
}

SampleView Points::velocities(std::uint32_t sample) const {
  if (!velocities_.valid() || velocities_.header().num_samples == 0) return SampleView(Pod::Float32, 3, 0, {});
  return velocities_.sample_at(sample_time(sample)).first;
}

Box3 Points::self_bounds(std::uint32_t sample) const {
  if (!self_bounds_.valid() || self_bounds_.header().num_samples == 0) return Box3::empty();
  const SampleView v = self_bounds_.sample(clamp_index(sample, self_bounds_));
  return Box3{{v.value_f64(0), v.value_f64(1), v.value_f64(2)}, {v.value_f64(3), v.value_f64(4), v.value_f64(5)}};
}

const GeomParam* Points::find_param(std::string_view name) const {
  if (widths_ && (name == "widths" || name == ".widths")) return &*widths_;
  for (const GeomParam& p : arb_) {
    if (p.name() == name) return &p;
  }
  return nullptr;
}

std::size_t Points::read_positions(std::uint32_t sample, std::span<float> out) const {
  const SampleView v = positions(sample);
  check_capacity(object_, "positions", sample, v.scalar_count(), out.size());
  return v.copy_raw(std::as_writable_bytes(out));
}

std::size_t Points::read_ids(std::uint32_t sample, std::span<std::uint64_t> out) const {
  const SampleView v = ids(sample);
  check_capacity(object_, "ids", sample, v.scalar_count(), out.size());
  return v.copy_raw(std::as_writable_bytes(out));
}

std::size_t Points::read_velocities(std::uint32_t sample, std::span<float> out) const {
  const SampleView v = velocities(sample);
  check_capacity(object_, "velocities", sample, v.scalar_count(), out.size());
  return v.copy_raw(std::as_writable_bytes(out));
}

std::size_t Points::read_param(std::string_view name, std::uint32_t sample, std::span<float> out) const {
  const GeomParam* p = find_param(name);
  if (p == nullptr) throw Error(fmt::format("Points '{}' has no parameter '{}'", object_.full_name(), name));
  if (p->values().header().num_samples == 0) return 0;
  const double time = sample_time(sample);
  const SampleView vals = p->values().sample_at(time).first;
  const std::size_t extent = vals.extent();
  if (!p->indexed()) {
    check_capacity(object_, name, sample, vals.scalar_count(), out.size());
    if (vals.pod() == Pod::Float32) return vals.copy_raw(std::as_writable_bytes(out));
    for (std::uint64_t i = 0; i < vals.scalar_count(); ++i) out[i] = static_cast<float>(vals.value_f64(i));
    return vals.scalar_count();
  }
  const SampleView idx = p->indices().sample_at(time).first;
  check_capacity(object_, name, sample, idx.scalar_count() * extent, out.size());
  for (std::uint64_t i = 0; i < idx.scalar_count(); ++i) {
    const std::uint64_t k = idx.value_u64(i);
    if (k >= vals.size()) {
      throw Error(fmt::format("parameter '{}' of '{}' sample {}: index {} at position {} is past its {} values", name,
                              object_.full_name(), sample, k, i, vals.size()));
    }
    for (std::size_t c = 0; c < extent; ++c) out[i * extent + c] = static_cast<float>(vals.value_f64(k * extent + c));
  }
  return idx.scalar_count() * extent;
}

}  // namespace pstream::alembic
