// Xform schema and world matrices, in Imath's row-vector convention (p' = p * M).
#include <cmath>
#include <numbers>

#include <fmt/format.h>

#include "particlestream/alembic.hpp"

namespace pstream::alembic {
namespace {

Matrix44 axis_angle(double x, double y, double z, double degrees) {
  const double len = std::sqrt(x * x + y * y + z * z);
  if (len > 0.0) {
    x /= len;
    y /= len;
    z /= len;
  }
  const double radians = degrees * std::numbers::pi / 180.0;
  const double s = std::sin(radians), c = std::cos(radians), t = 1.0 - c;
  return Matrix44{{{x * x * t + c, x * y * t + z * s, x * z * t - y * s, 0.0},
                   {x * y * t - z * s, y * y * t + c, y * z * t + x * s, 0.0},
                   {x * z * t + y * s, y * z * t - x * s, z * z * t + c, 0.0},
                   {0.0, 0.0, 0.0, 1.0}}};
}

std::uint32_t near(const Property& p, double time) {
  return static_cast<std::uint32_t>(p.time_sampling().near_index(time, p.header().num_samples).first);
}

std::uint32_t clamp(const Property& p, std::uint32_t index) { return std::min(index, p.header().num_samples - 1); }

}  // namespace

Matrix44 identity_matrix() { return Matrix44{{{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}}}; }

Matrix44 multiply(const Matrix44& a, const Matrix44& b) {
  Matrix44 r{};
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < 4; ++j) {
      r[i][j] = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j] + a[i][3] * b[3][j];
    }
  }
  return r;
}

std::string_view xform_op_name(XformOpType type) {
  static constexpr std::string_view names[] = {"scale",   "translate", "rotate", "matrix",
                                               "rotateX", "rotateY",   "rotateZ"};
  return names[static_cast<std::size_t>(type)];
}

std::size_t xform_op_channel_count(XformOpType type) {
  static constexpr std::size_t counts[] = {3, 3, 4, 16, 1, 1, 1};
  return counts[static_cast<std::size_t>(type)];
}

Matrix44 XformOp::matrix() const {
  Matrix44 m = identity_matrix();
  const auto& c = channels;
  switch (type) {
    case XformOpType::Scale:
      m[0][0] = c[0];
      m[1][1] = c[1];
      m[2][2] = c[2];
      break;
    case XformOpType::Translate:
      m[3][0] = c[0];
      m[3][1] = c[1];
      m[3][2] = c[2];
      break;
    case XformOpType::Rotate: m = axis_angle(c[0], c[1], c[2], c[3]); break;
    case XformOpType::RotateX: m = axis_angle(1, 0, 0, c[0]); break;
    case XformOpType::RotateY: m = axis_angle(0, 1, 0, c[0]); break;
    case XformOpType::RotateZ: m = axis_angle(0, 0, 1, c[0]); break;
    case XformOpType::Matrix:
      for (int i = 0; i < 16; ++i) m[i / 4][i % 4] = c[i];
      break;
  }
  return m;
}

Matrix44 XformSample::matrix() const {
  Matrix44 m = identity_matrix();
  for (const XformOp& op : ops) m = multiply(op.matrix(), m);  // the first op is applied last
  return m;
}

bool Xform::matches(const Object& object) { return object.schema() == "AbcGeom_Xform_v3"; }

Xform::Xform(const Object& object) : object_(object) {
  const auto xform = object.properties().find(".xform");
  if (!xform || !xform->is_compound())
    throw Error(fmt::format("'{}' is not an Xform object (no .xform compound)", object.full_name()));
  if (auto inherits = xform->find(".inherits"); inherits && inherits->kind() == PropertyKind::Scalar)
    inherits_ = *inherits;
  if (auto vals = xform->find(".vals"); vals && !vals->is_compound()) {
    if (vals->header().pod != Pod::Float64)
      throw Error(fmt::format("Xform '{}': .vals is not float64", object.full_name()));
    vals_ = *vals;
  }
  constant_identity_ = !xform->find("isNotConstantIdentity").has_value();
  const auto ops = xform->find(".ops");
  if (ops && ops->kind() == PropertyKind::Scalar && ops->header().num_samples > 0) {
    const SampleView codes = ops->sample(0);
    for (std::uint64_t i = 0; i < codes.scalar_count(); ++i) {
      const auto code = static_cast<std::uint8_t>(codes.value_i64(i));
      if ((code >> 4) > static_cast<int>(XformOpType::RotateZ)) {
        throw Error(fmt::format("Xform '{}': op {} has unknown type {}", object.full_name(), i, code >> 4));
      }
      XformOp op;
      op.type = static_cast<XformOpType>(code >> 4);
      op.hint = code & 0xf;
      ops_.push_back(op);
    }
  }
}

std::uint32_t Xform::num_samples() const { return inherits_.valid() ? inherits_.header().num_samples : 0; }
std::uint32_t Xform::time_sampling_index() const {
  return inherits_.valid() ? inherits_.header().time_sampling_index : 0;
}
const TimeSampling& Xform::time_sampling() const {
  return inherits_.valid() ? inherits_.time_sampling() : object_.properties().time_sampling();
}
bool Xform::is_constant() const {
  return (!vals_.valid() || vals_.header().is_constant()) && (!inherits_.valid() || inherits_.header().is_constant());
}
bool Xform::is_constant_identity() const { return constant_identity_; }

namespace {

XformSample read_sample(const Object& object, const std::vector<XformOp>& ops, const Property& inherits,
                        const Property& vals, auto pick_index) {
  XformSample s;
  s.ops = ops;
  if (inherits.valid() && inherits.header().num_samples > 0) {
    s.inherits = inherits.sample(pick_index(inherits)).value_i64(0) != 0;
  }
  if (!vals.valid() || vals.header().num_samples == 0) return s;
  const SampleView v = vals.sample(pick_index(vals));
  std::uint64_t needed = 0;
  for (const XformOp& op : ops) needed += op.channel_count();
  if (v.scalar_count() < needed) {
    throw Error(fmt::format("Xform '{}': its ops need {} channel values, the sample holds {}", object.full_name(),
                            needed, v.scalar_count()));
  }
  std::uint64_t k = 0;
  for (XformOp& op : s.ops) {
    for (std::size_t c = 0; c < op.channel_count(); ++c) op.channels[c] = v.value_f64(k++);
  }
  return s;
}

}  // namespace

XformSample Xform::sample(std::uint32_t index) const {
  return read_sample(object_, ops_, inherits_, vals_, [index](const Property& p) { return clamp(p, index); });
}

XformSample Xform::sample_at(double time) const {
  return read_sample(object_, ops_, inherits_, vals_, [time](const Property& p) { return near(p, time); });
}

Matrix44 world_matrix(const Object& object, double time) {
  Matrix44 m = identity_matrix();
  std::optional<Object> node = object;
  while (node) {
    if (Xform::matches(*node)) {
      const XformSample s = Xform(*node).sample_at(time);
      m = multiply(m, s.matrix());
      if (!s.inherits) break;
    }
    node = node->parent();
  }
  return m;
}

Matrix44 parent_world_matrix(const Object& object, double time) {
  const auto parent = object.parent();
  return parent ? world_matrix(*parent, time) : identity_matrix();
}

}  // namespace pstream::alembic
