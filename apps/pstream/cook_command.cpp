// `pstream cook IN -o OUT.pstream`: option parsing and the report printed at the end.
#include <charconv>
#include <cmath>
#include <optional>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "cli_terms.hpp"
#include "commands.hpp"
#include "particlestream/cook.hpp"
#include "progress.hpp"

namespace pstream::app {
namespace {

std::uint64_t parse_size(const std::string& text) {
  std::uint64_t value = 0;
  const auto [ptr, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  const std::string unit(ptr, text.data() + text.size());
  if (ec != std::errc() || value == 0)
    throw Error(
        fmt::format("--chunk-size '{}': expected a size such as 2MiB (a power of two from 64KiB to 64MiB)", text));
  int shift = 0;
  if (unit == "K" || unit == "KiB" || unit == "k")
    shift = 10;
  else if (unit == "M" || unit == "MiB")
    shift = 20;
  else if (!unit.empty() && unit != "B")
    throw Error(fmt::format("--chunk-size '{}': unknown unit '{}' (B, KiB, MiB)", text, unit));
  if (value > (std::uint64_t{1} << 40) >> shift)  // far past the largest chunk, and no wrap-around below
    throw Error(fmt::format("--chunk-size '{}': too large; chunks are 64KiB to 64MiB", text));
  return value << shift;
}

}  // namespace

int run_cook(const CookCli& cli) {
  cook::Options o;
  o.input = cli.input;
  o.output = cli.output;
  o.object = cli.object;
  o.merge = cli.merge;
  o.bake_xforms = !cli.no_xforms;
  o.fps = cli.fps;
  o.interpolate = cli.interpolate;
  cook::set_scale_from(o, cli.scale_from, "--scale-from");
  o.color_from = cli.color_from;
  cook::add_attributes(o, cli.attributes);
  o.chunk_size = parse_size(cli.chunk_size);
  cook::set_codec(o, cli.codec);
  o.keep_velocity = !cli.no_velocity;
  o.particle.derive_velocity = !cli.store_velocity;
  cook::set_error_bound(o, cli.error, "--error");
  cook::set_scale_error(o, cli.scale_error, "--scale-error");
  cook::set_attribute_error(o, cli.attribute_error, "--attribute-error");
  o.particle.keyframe_interval = cli.keyframe_interval;
  if (!cli.frames.empty()) cook::set_frames(o, cli.frames, "--frames");
  o.drop_invalid = cli.drop_invalid;
  o.keep_source_order = cli.keep_order;
  o.max_particles = cli.max_particles;
  o.threads = cli.threads;
  o.max_frames = cli.max_frames;

  const bool show = !cli.quiet && !cli.json;
  const cook::Report r = cook::cook(o, CookProgress("cook", show));
  const double ratio = r.file_bytes ? double(r.stream_bytes) / double(r.file_bytes) : 0.0;
  if (cli.json) {
    nlohmann::ordered_json j{{"output", cli.output},         {"object", r.object},
                             {"frames", r.frames},           {"chunks", r.chunks},
                             {"particles", r.particles},     {"dropped_invalid", r.dropped_invalid},
                             {"input_bytes", r.input_bytes}, {"stream_bytes", r.stream_bytes},
                             {"file_bytes", r.file_bytes},   {"compression_ratio", ratio},
                             {"seconds", r.seconds}};
    if (o.frame_codec == format::FrameCodec::Particle) {
      j["codec"] = o.particle.lossless ? "particle-lossless" : "particle";
      j["error"] = r.error;
      j["keyframes"] = r.keyframes;
      j["bytes_per_particle"] = r.particles ? double(r.file_bytes) / double(r.particles) : 0.0;
      j["match_rate"] = r.predictable ? double(r.matched) / double(r.predictable) : 1.0;
      j["groups_in_flight"] = r.groups_in_flight;
    }
    fmt::print("{}\n", j.dump());
    return 0;
  }
  if (!cli.quiet) {
    if (r.default_scale > 0) {
      fmt::print(stderr,
                 "note: the source has no widths; every particle got scale {:g}, half the particles' median "
                 "spacing (choose with --scale-from)\n",
                 r.default_scale);
    }
    if (r.mesh_vertices && o.object.empty()) {
      fmt::print(stderr, "note: the archive holds no points objects; cooked the vertices of its mesh {}\n", r.object);
    }
    if (r.dropped_invalid)
      fmt::print(stderr, "note: dropped {} particles with NaN or infinite positions\n", r.dropped_invalid);
    fmt::print("{} -> {}: {}, {}, {}, {:.1f} MiB ({:.2f}x of the {:.1f} MiB record stream) in {:.2f} s\n", r.object,
               cli.output, count_of(r.frames, "frame"), count_of(r.particles, "particle"), count_of(r.chunks, "chunk"),
               r.file_bytes / 1048576.0, ratio, r.stream_bytes / 1048576.0, r.seconds);
    if (o.frame_codec == format::FrameCodec::Particle) {
      const double per_particle = r.particles ? double(r.file_bytes) / double(r.particles) : 0.0;
      const double match = r.predictable ? 100.0 * double(r.matched) / double(r.predictable) : 100.0;
      if (o.particle.lossless) {
        fmt::print("  particle codec, lossless: {:.2f} bytes per particle per frame, {}\n", per_particle,
                   count_of(r.keyframes, "keyframe"));
      } else {
        fmt::print(
            "  particle codec: {:.2f} bytes per particle per frame, positions within {:.3g} ({}), {}, "
            "{:.1f}% of particles predicted from the frame before ({})\n",
            per_particle, r.error,
            o.particle.error_relative ? fmt::format("{:g} of the bounds diagonal", o.particle.error) : "absolute",
            count_of(r.keyframes, "keyframe"), match,
            r.order == format::FrameOrder::Id ? "matched by id" : "matched by position, no ids");
      }
    }
  }
  return 0;
}

}  // namespace pstream::app
