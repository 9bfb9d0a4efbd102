#include "particlestream/alembic_describe.hpp"

#include <algorithm>
#include <filesystem>
#include <vector>

#include <nlohmann/json.hpp>

namespace pstream::alembic {
namespace {

using json = nlohmann::ordered_json;

// Running statistics of `count` elements of `extent` values each, read through `value(i)`
// (a json number) and `number(i)` (the same as double), as the fixtures' STATS object.
template <class Value, class Number>
json stats(std::uint64_t count, std::size_t extent, bool integer, Value value, Number number) {
  json out;
  out["count"] = count;
  const std::uint64_t shown = std::min<std::uint64_t>(count, extent == 1 ? 5 : 3);
  auto element = [&](std::uint64_t e) {
    if (extent == 1) return value(e);
    json a = json::array();
    for (std::size_t c = 0; c < extent; ++c) a.push_back(value(e * extent + c));
    return a;
  };
  json first = json::array();
  for (std::uint64_t e = 0; e < shown; ++e) first.push_back(element(e));
  out["first"] = first;
  out["last"] = count ? element(count - 1) : json();

  json sum = json::array(), min = json::array(), max = json::array();
  for (std::size_t c = 0; c < extent; ++c) {
    if (integer) {
      // Exact integer sums, wrapping like the official dumper's 64-bit accumulator.
      std::uint64_t s = 0;
      for (std::uint64_t e = 0; e < count; ++e) s += value(e * extent + c).template get<std::uint64_t>();
      const bool is_signed = count > 0 && value(c).is_number_integer() && !value(c).is_number_unsigned();
      sum.push_back(is_signed ? json(static_cast<std::int64_t>(s)) : json(s));
    } else {
      double s = 0.0;
      for (std::uint64_t e = 0; e < count; ++e) s += number(e * extent + c);
      sum.push_back(s);
    }
    if (count == 0) {
      min.push_back(nullptr);
      max.push_back(nullptr);
      continue;
    }
    std::uint64_t lo = c, hi = c;
    for (std::uint64_t e = 1; e < count; ++e) {
      const std::uint64_t i = e * extent + c;
      if (number(i) < number(lo)) lo = i;
      if (number(i) > number(hi)) hi = i;
    }
    min.push_back(value(lo));
    max.push_back(value(hi));
  }
  out["sum"] = extent == 1 ? sum[0] : sum;
  out["min"] = extent == 1 ? min[0] : min;
  out["max"] = extent == 1 ? max[0] : max;
  return out;
}

// String STATS: count, the first five, the last; no sum, min or max.
json string_stats(const std::vector<std::string>& strings) {
  json first = json::array();
  for (std::size_t i = 0; i < std::min<std::size_t>(strings.size(), 5); ++i) first.push_back(strings[i]);
  return json{{"count", strings.size()}, {"first", first}, {"last", strings.empty() ? json() : json(strings.back())},
              {"sum", nullptr},          {"min", nullptr}, {"max", nullptr}};
}

json sample_stats(const SampleView& v) {
  if (v.pod() == Pod::String || v.pod() == Pod::WString) return string_stats(v.strings());
  const bool integer = pod_is_integer(v.pod());
  auto value = [&](std::uint64_t i) -> json {
    if (!integer) return v.value_f64(i);
    if (v.pod() == Pod::Uint64) return v.value_u64(i);
    return v.value_i64(i);
  };
  auto number = [&](std::uint64_t i) { return v.value_f64(i); };
  return stats(v.size(), v.extent(), integer, value, number);
}

json box_json(const Box3& b) {
  return json{
      {"min", {b.min[0], b.min[1], b.min[2]}}, {"max", {b.max[0], b.max[1], b.max[2]}}, {"is_empty", b.is_empty()}};
}

json positions_json(const SampleView& v) {
  json out = sample_stats(v);
  out["bbox"] = v.empty() ? json() : json{{"min", out["min"]}, {"max", out["max"]}, {"is_empty", false}};
  return out;
}

json matrix_json(const Matrix44& m) {
  json out = json::array();
  for (const auto& row : m) out.push_back({row[0], row[1], row[2], row[3]});
  return out;
}

json param_json(const GeomParam& p, double time) {
  const PropertyHeader& vh = p.values().header();
  const std::uint32_t index = p.sample_index_at(time);
  json out{{"name", p.name()},
           {"scope", geom_scope_name(p.scope())},
           {"indexed", p.indexed()},
           {"property_kind", property_kind_name(p.property().kind())},
           {"pod", pod_name(vh.pod)},
           {"extent", vh.extent},
           {"interpretation", vh.interpretation()},
           {"num_samples", p.num_samples()},
           {"sample_index", index}};
  const SampleView vals = vh.num_samples ? p.values().sample(index) : SampleView(vh.pod, vh.extent, 0, {});
  out["vals"] = sample_stats(vals);
  if (p.indexed()) {
    const PropertyHeader& ih = p.indices().header();
    const SampleView idx = ih.num_samples ? p.indices().sample_at(time).first : SampleView(ih.pod, 1, 0, {});
    out["indices"] = sample_stats(idx);
    if (vals.pod() == Pod::String || vals.pod() == Pod::WString) {
      const std::vector<std::string> values = vals.strings();
      std::vector<std::string> expanded;
      for (std::uint64_t i = 0; i < idx.scalar_count(); ++i) {
        const std::uint64_t k = idx.value_u64(i);
        expanded.push_back(k < values.size() ? values[k] : std::string());
      }
      out["expanded"] = string_stats(expanded);
      return out;
    }
    std::vector<double> expanded;
    expanded.reserve(
        std::min<std::uint64_t>(idx.scalar_count() * vals.extent(), vals.bytes().size() + idx.bytes().size()));
    for (std::uint64_t i = 0; i < idx.scalar_count(); ++i) {
      const std::uint64_t k = idx.value_u64(i);
      for (std::size_t c = 0; c < vals.extent(); ++c) {
        expanded.push_back(k < vals.size() ? vals.value_f64(k * vals.extent() + c) : 0.0);
      }
    }
    out["expanded"] = stats(
        idx.scalar_count(), vals.extent(), false, [&](std::uint64_t i) { return json(expanded[i]); },
        [&](std::uint64_t i) { return expanded[i]; });
  }
  return out;
}

json properties_json(const Property& compound) {
  json out = json::array();
  for (std::size_t i = 0; i < compound.child_count(); ++i) {
    const Property p = compound.child(i);
    const PropertyHeader& h = p.header();
    json j{{"name", h.name}, {"kind", property_kind_name(h.kind)}, {"metadata", h.metadata.serialize()}};
    if (h.kind == PropertyKind::Compound) {
      j["children"] = properties_json(p);
    } else {
      j["pod"] = pod_name(h.pod);
      j["extent"] = h.extent;
      j["interpretation"] = h.interpretation();
      j["time_sampling_index"] = h.time_sampling_index;
      j["num_samples"] = h.num_samples;
      j["is_constant"] = h.is_constant();
    }
    out.push_back(std::move(j));
  }
  return out;
}

json visibility_chain(const Object& object, double time) {
  json out = json::array();
  for (std::optional<Object> o = object; o; o = o->parent()) {
    if (auto v = visibility(*o, time)) out.push_back({{"object", o->full_name()}, {"value", *v}});
  }
  return out;
}

json points_json(const Object& object, const DescribeOptions& options) {
  const Points points(object);
  json out{{"full_name", object.full_name()},           {"time_sampling_index", points.time_sampling_index()},
           {"num_samples", points.num_samples()},       {"is_constant", points.is_constant()},
           {"has_velocities", points.has_velocities()}, {"has_widths", points.widths().has_value()}};
  json names = json::array();
  for (const GeomParam& p : points.arb_geom_params()) names.push_back(p.name());
  out["arb_geom_param_names"] = names;
  json samples = json::array();
  const std::uint32_t n = std::min(points.num_samples(), options.max_samples);
  for (std::uint32_t i = 0; i < n; ++i) {
    const double time = points.sample_time(i);
    const SampleView P = points.positions(i);
    json s{{"index", i}, {"time", time}, {"count", P.size()}, {"positions", positions_json(P)}};
    s["self_bounds"] = box_json(points.self_bounds(i));
    s["ids"] = sample_stats(points.ids(i));
    s["velocities"] = points.has_velocities() ? sample_stats(points.velocities(i)) : json();
    s["widths"] = points.widths() ? param_json(*points.widths(), time) : json();
    json arb = json::array();
    for (const GeomParam& p : points.arb_geom_params()) arb.push_back(param_json(p, time));
    s["arb_geom_params"] = arb;
    s["world_matrix"] = matrix_json(parent_world_matrix(object, time));
    s["visibility_chain"] = visibility_chain(object, time);
    samples.push_back(std::move(s));
  }
  out["samples"] = samples;
  return out;
}

json polymesh_json(const Object& object, const DescribeOptions& options) {
  const PolyMesh mesh(object);
  json out{{"full_name", object.full_name()},
           {"time_sampling_index", mesh.time_sampling_index()},
           {"num_samples", mesh.num_samples()},
           {"topology_variance", mesh.topology_variance()},
           {"topology_variance_meaning", "0=constant 1=homogeneous(positions change) 2=heterogeneous"}};
  json samples = json::array();
  const std::uint32_t n = std::min(mesh.num_samples(), options.max_samples);
  for (std::uint32_t i = 0; i < n; ++i) {
    const double time = mesh.time_sampling().sample_time(i);
    const SampleView P = mesh.positions(i);
    json s{{"index", i}, {"time", time}, {"count", P.size()}, {"positions", positions_json(P)}};
    s["self_bounds"] = box_json(mesh.self_bounds(i));
    s["face_counts"] = sample_stats(mesh.face_counts(i));
    s["face_indices"] = sample_stats(mesh.face_indices(i));
    s["velocities"] = mesh.has_velocities() ? sample_stats(mesh.velocities(i)) : json();
    json arb = json::array();
    for (const GeomParam& p : mesh.arb_geom_params()) arb.push_back(param_json(p, time));
    s["arb_geom_params"] = arb;
    s["world_matrix"] = matrix_json(parent_world_matrix(object, time));
    samples.push_back(std::move(s));
  }
  out["samples"] = samples;
  return out;
}

json xform_json(const Object& object, const DescribeOptions& options) {
  const Xform xform(object);
  json out{{"full_name", object.full_name()},
           {"time_sampling_index", xform.time_sampling_index()},
           {"num_samples", xform.num_samples()},
           {"is_constant", xform.is_constant()},
           {"is_constant_identity", xform.is_constant_identity()}};
  json samples = json::array();
  const std::uint32_t n = std::min(xform.num_samples(), options.max_samples);
  for (std::uint32_t i = 0; i < n; ++i) {
    const double time = xform.time_sampling().sample_time(i);
    const XformSample x = xform.sample(i);
    json ops = json::array();
    for (const XformOp& op : x.ops) {
      json channels = json::array();
      for (std::size_t c = 0; c < op.channel_count(); ++c) channels.push_back(op.channels[c]);
      ops.push_back({{"type", xform_op_name(op.type)}, {"hint", op.hint}, {"channels", channels}});
    }
    const Matrix44 local = x.matrix();
    const Matrix44 world = x.inherits ? multiply(local, parent_world_matrix(object, time)) : local;
    samples.push_back({{"index", i},
                       {"time", time},
                       {"inherits_xforms", x.inherits},
                       {"ops", ops},
                       {"local_matrix", matrix_json(local)},
                       {"world_matrix", matrix_json(world)}});
  }
  out["samples"] = samples;
  return out;
}

json archive_json(const Archive& archive) {
  const ArchiveInfo info = archive.info();
  const auto [start, end] = archive.start_end_time();
  json samplings = json::array();
  for (std::size_t i = 0; i < archive.time_samplings().size(); ++i) {
    const TimeSampling& ts = archive.time_samplings()[i];
    const char* type = ts.type == TimeSamplingType::Uniform  ? "uniform"
                       : ts.type == TimeSamplingType::Cyclic ? "cyclic"
                                                             : "acyclic";
    samplings.push_back({{"index", i},
                         {"type", type},
                         {"samples_per_cycle", ts.samples_per_cycle},
                         {"time_per_cycle", ts.time_per_cycle},
                         {"stored_times", ts.stored_times},
                         {"max_num_samples", ts.max_num_samples}});
  }
  return json{{"core", "Ogawa"},
              {"archive_version", archive.archive_version()},
              {"app_name", info.app_name},
              {"alembic_version_string", info.alembic_version_string},
              {"alembic_api_version", info.alembic_api_version},
              {"date_written", info.date_written},
              {"user_description", info.user_description},
              {"dcc_fps", info.dcc_fps},
              {"top_metadata", archive.metadata().serialize()},
              {"start_time", start},
              {"end_time", end},
              {"time_samplings", samplings}};
}

}  // namespace

std::string describe_json(const Archive& archive, const DescribeOptions& options) {
  json doc{{"format", "alembic-fixture-expected/1"},
           {"file", std::filesystem::path(archive.name()).filename().string()},
           {"reader", "ParticleStream native Ogawa reader"}};
  doc["archive"] = archive_json(archive);
  json objects = json::array(), points = json::array(), meshes = json::array(), xforms = json::array();
  for (const Object& o : archive.objects()) {
    json children = json::array();
    for (std::size_t i = 0; i < o.child_count(); ++i) children.push_back(o.child(i).name());
    objects.push_back({{"full_name", o.full_name()},
                       {"name", o.name()},
                       {"parent", o.parent()->full_name()},
                       {"schema", o.schema()},
                       {"kind", object_kind(o)},
                       {"metadata", o.metadata().serialize()},
                       {"children", children}});
    if (o.is_instance_descendant()) {
      objects.back()["is_instance_root"] = o.is_instance_root();
      objects.back()["is_instance_descendant"] = true;
      objects.back()["instance_source_path"] = o.instance_source_path();
      objects.back()["header_full_name"] = o.stored_full_name();
    }
    objects.back()["properties"] = properties_json(o.properties());
    const std::string_view kind = object_kind(o);
    if (kind == "points") points.push_back(points_json(o, options));
    if (kind == "polymesh") meshes.push_back(polymesh_json(o, options));
    if (kind == "xform") xforms.push_back(xform_json(o, options));
  }
  doc["objects"] = objects;
  doc["points"] = points;
  doc["polymeshes"] = meshes;
  doc["xforms"] = xforms;
  // Metadata may hold bytes that are not UTF-8: replace them rather than fail.
  return doc.dump(options.indent, ' ', false, json::error_handler_t::replace);
}

}  // namespace pstream::alembic
