// `pstream info frame.0001.ply`: a PLY sequence as the cook will read it.
#include <algorithm>
#include <numeric>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "cli_terms.hpp"
#include "commands.hpp"
#include "particlestream/cook.hpp"

namespace pstream::app {

int info_ply(const InfoOptions& options) {
  const cook::PlySequenceInfo s = cook::describe_ply_sequence(options.file);
  const std::uint64_t total = std::accumulate(s.counts.begin(), s.counts.end(), std::uint64_t{0});
  const std::uint64_t min = *std::min_element(s.counts.begin(), s.counts.end());
  const std::uint64_t max = *std::max_element(s.counts.begin(), s.counts.end());
  const double avg = double(total) / double(s.counts.size());
  const std::string scale = s.scale_property.empty() ? std::string("none: a constant (--scale-from constant:X)")
                            : s.scale_is_diameter    ? fmt::format("'{}', halved (a diameter)", s.scale_property)
                                                     : fmt::format("'{}'", s.scale_property);
  if (options.json) {
    nlohmann::ordered_json properties = nlohmann::ordered_json::array();
    for (const auto& p : s.properties) properties.push_back({{"name", p.name}, {"type", p.type}});
    nlohmann::ordered_json files = nlohmann::ordered_json::array();
    for (std::size_t i = 0; i < s.files.size(); ++i)
      files.push_back({{"file", s.files[i].string()}, {"count", s.counts[i]}});
    const nlohmann::ordered_json j{{"format", "ply"},
                                   {"file", options.file},
                                   {"encoding", s.format},
                                   {"first_number", s.first_number},
                                   {"file_count", s.files.size()},
                                   {"bytes", s.bytes},
                                   {"particles", {{"min", min}, {"avg", avg}, {"max", max}, {"total", total}}},
                                   {"properties", properties},
                                   {"cook",
                                    {{"scale_from", s.scale_property},
                                     {"scale_is_diameter", s.scale_is_diameter},
                                     {"color", s.has_color},
                                     {"velocity", s.has_velocity},
                                     {"ids", s.has_ids}}},
                                   {"files", files}};
    fmt::print("{}\n", j.dump(1));
    return 0;
  }
  fmt::print("{}: PLY sequence ({}), {}, {}\n", options.file, s.format, count_of(s.files.size(), "file"),
             human_bytes(double(s.bytes)));
  if (s.files.size() == 1)
    fmt::print("  files         {} (one frame)\n", s.files.front().filename().string());
  else
    fmt::print("  files         {} .. {} (frames {} .. {})\n", s.files.front().filename().string(),
               s.files.back().filename().string(), s.first_number,
               s.first_number + static_cast<std::int64_t>(s.files.size()) - 1);
  fmt::print("  particles     min {} / avg {:.1f} / max {} per file\n", min, avg, max);
  fmt::print("  vertex properties:\n");
  for (const auto& p : s.properties) fmt::print("      {:<14} {}\n", p.name, p.type);
  fmt::print("  a cook takes  positions from x y z; scale from {}; {}; {}; {}\n", scale,
             s.has_color ? "colours from red green blue" : "no colours",
             s.has_velocity ? "velocities from vx vy vz" : "no velocities (derived where ids match)",
             s.has_ids ? "ids from 'id' (particles matched by id)" : "no ids (particles matched by position)");
  fmt::print("  frame rate    not in PLY: --fps (24 by default)\n");
  return 0;
}

}  // namespace pstream::app
