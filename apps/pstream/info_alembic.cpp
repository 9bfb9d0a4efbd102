// `pstream info FILE.abc`: what a technical artist wants to know before cooking a cache.
#include <algorithm>
#include <cstdio>
#include <string>

#include <fmt/format.h>

#include "cli_terms.hpp"
#include "commands.hpp"
#include "particlestream/alembic.hpp"
#include "particlestream/alembic_describe.hpp"
#include "progress.hpp"

namespace pstream::app {
namespace {

using namespace pstream::alembic;

std::string type_name(const PropertyHeader& h) {
  return h.extent == 1 ? std::string(pod_name(h.pod)) : fmt::format("{}x{}", pod_name(h.pod), int(h.extent));
}

std::string sampling_line(const TimeSampling& ts) {
  switch (ts.type) {
    case TimeSamplingType::Uniform:
      return fmt::format("uniform, {:.6g} s per sample ({:.6g} fps), starts at {:.6g} s", ts.time_per_cycle,
                         1.0 / ts.time_per_cycle, ts.stored_times[0]);
    case TimeSamplingType::Cyclic:
      return fmt::format("cyclic, {} samples every {:.6g} s, starts at {:.6g} s", ts.samples_per_cycle,
                         ts.time_per_cycle, ts.stored_times[0]);
    case TimeSamplingType::Acyclic:
      return fmt::format("acyclic, {} explicit times from {:.6g} s", ts.stored_times.size(), ts.stored_times.front());
  }
  return "";
}

void print_param(const GeomParam& p) {
  const PropertyHeader& h = p.values().header();
  std::string interp = h.interpretation();
  fmt::print("      {:<14} {:<11} {:<8}{}{}\n", p.name(), type_name(h), geom_scope_name(p.scope()),
             p.indexed() ? " indexed" : "", interp.empty() ? "" : " (" + interp + ")");
}

// "N samples, T0 s .. T1 s (time sampling K)" and the least, mean and most of count(sample), for
// points and meshes alike.
template <typename Count>
void print_samples(std::uint32_t n, const TimeSampling& ts, std::uint32_t ts_index, std::string_view suffix,
                   std::string_view what, const Count& count) {
  std::uint64_t lo = UINT64_MAX, hi = 0, total = 0;
  for (std::uint32_t i = 0; i < n; ++i) {
    const std::uint64_t c = count(i);
    lo = std::min(lo, c);
    hi = std::max(hi, c);
    total += c;
  }
  if (n == 0) lo = 0;
  fmt::print("    {}", count_of(n, "sample"));
  if (n > 0) fmt::print(", {:.6g} s .. {:.6g} s", ts.sample_time(0), ts.sample_time(n - 1));
  fmt::print(" (time sampling {}){}\n", ts_index, suffix);
  fmt::print("    {} per sample: min {} / avg {:.1f} / max {}\n", what, lo, n ? double(total) / n : 0.0, hi);
}

void print_points(const Object& o) {
  const Points points(o);
  const std::uint32_t n = points.num_samples();
  print_samples(n, points.time_sampling(), points.time_sampling_index(), points.is_constant() ? ", constant" : "",
                "particles", [&](std::uint32_t i) { return points.count(i); });
  fmt::print("    attributes:\n");
  fmt::print("      {:<14} {:<11} {:<8}\n", "P", "float32x3", "varying");
  if (points.has_ids()) {
    // Some exporters (Blender's FLIP) write the property with no ids in it: say so, since the
    // cook cannot match particles by id then.
    std::uint32_t empty = 0, with_particles = 0;
    for (std::uint32_t i = 0; i < n; ++i) {
      if (points.count(i) == 0) continue;
      ++with_particles;
      empty += points.ids(i).size() != points.count(i) ? 1 : 0;
    }
    const std::string note = empty == 0 ? ""
                             : empty == with_particles
                                 ? " empty: written without ids (no matching by id)"
                                 : fmt::format(" missing or short in {} of {} samples", empty, with_particles);
    fmt::print("      {:<14} {:<11} {:<8}{}\n", ".pointIds", "uint64", "varying", note);
  }
  if (points.has_velocities()) fmt::print("      {:<14} {:<11} {:<8}\n", ".velocities", "float32x3", "varying");
  if (points.widths()) print_param(*points.widths());
  for (const GeomParam& p : points.arb_geom_params()) print_param(p);
}

// A mesh's vertices cook as particles (`cook --object`, or on their own in an archive without
// points objects and with one mesh).
void print_mesh(const Object& o) {
  const PolyMesh mesh(o);
  print_samples(mesh.num_samples(), mesh.time_sampling(), mesh.time_sampling_index(), "", "vertices",
                [&](std::uint32_t i) { return mesh.positions(i).size(); });
  fmt::print("    attributes (its vertices cook as particles):\n");
  fmt::print("      {:<14} {:<11} {:<8}\n", "P", "float32x3", "varying");
  if (mesh.has_velocities()) fmt::print("      {:<14} {:<11} {:<8}\n", ".velocities", "float32x3", "varying");
  for (const GeomParam& p : mesh.arb_geom_params()) print_param(p);
}

}  // namespace

int info_alembic(const InfoOptions& options) {
  ProgressBar fetch("info: fetch", !options.json);  // a URL is read whole first
  const Archive archive =
      Archive::open(options.file, [&](std::uint64_t done, std::uint64_t total) { fetch.update_bytes(done, total); });
  if (options.json) {
    fmt::print("{}\n", describe_json(archive));
    return 0;
  }
  const ArchiveInfo info = archive.info();
  fmt::print("{}: Alembic archive (Ogawa), {}\n", options.file, human_bytes(double(archive.file_size())));
  if (!info.app_name.empty()) fmt::print("  written by    {}\n", info.app_name);
  if (!info.alembic_version_string.empty()) fmt::print("  library       {}\n", info.alembic_version_string);
  if (!info.date_written.empty()) fmt::print("  date          {}\n", info.date_written);
  if (!info.user_description.empty()) fmt::print("  description   {}\n", info.user_description);
  if (info.dcc_fps > 0) fmt::print("  scene fps     {:.6g}\n", info.dcc_fps);
  const auto [start, end] = archive.start_end_time();
  if (start <= end)
    fmt::print("  time range    {:.6g} s .. {:.6g} s\n", start, end);
  else
    fmt::print("  time range    none: no property has a sample\n");
  fmt::print("\nTime samplings:\n");
  for (std::size_t i = 0; i < archive.time_samplings().size(); ++i) {
    const TimeSampling& ts = archive.time_samplings()[i];
    fmt::print("  [{}] {} — up to {} samples\n", i, sampling_line(ts), ts.max_num_samples);
  }
  fmt::print("\nObjects:\n");
  for (const Object& o : archive.objects()) {
    const auto depth = std::count(o.full_name().begin(), o.full_name().end(), '/');
    const std::string schema = o.schema();
    fmt::print("  {}{}  [{}]\n", std::string(2 * (depth - 1), ' '), o.full_name(),
               schema.empty() ? "no schema" : schema);
    if (Points::matches(o)) print_points(o);
    if (PolyMesh::matches(o)) print_mesh(o);
  }
  return 0;
}

}  // namespace pstream::app
