// pstream: the ParticleStream command-line tool.
#include <algorithm>
#include <cctype>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <new>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include <fmt/format.h>
#include <CLI/CLI.hpp>

#include "base/mapped_file.hpp"
#include "base/names.hpp"
#include "cli_terms.hpp"
#include "commands.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/error.hpp"
#include "particlestream/io.hpp"

namespace {

// A local file that exists, or an http(s):// URL (the command's open says if its server fails).
CLI::Validator file_or_url() {
  return CLI::Validator(
      [](std::string& value) { return pstream::io::is_url(value) ? std::string() : CLI::ExistingFile(value); },
      "FILE|URL", "file or URL");
}

// The sprite look's flags, the same on render and play (apps/pstream/commands.hpp: LookCli).
void add_look_flags(CLI::App& cmd, pstream::app::LookCli& look) {
  const pstream::render::SpriteStyle defaults;
  cmd.add_option("--preset", look.preset,
                 "A look: sprites, smoke (self-shadowed), sparks (additive, motion-blurred), liquid-sprites "
                 "(coloured by speed), liquid, debug (flat, stored colours). Flags given with it override its parts")
      ->check(pstream::app::one_of({"sprites", "smoke", "sparks", "liquid-sprites", "liquid", "debug"}));
  cmd.add_flag("--shadows", look.sprites.shadows,
               "Volumetric self-shadowing (half-angle slices) and shadows on the ground");
  cmd.add_option("--slices", look.sprites.slices, "Shadow slices: more is smoother and slower")
      ->default_val(defaults.slices)
      ->check(CLI::Range(1, pstream::render::kMaxSlices));
  cmd.add_option("--shadow-density", look.sprites.shadow_density, "How much light a particle stops, x its alpha")
      ->default_val(defaults.shadow_density)
      ->check(CLI::NonNegativeNumber);
  cmd.add_option("--color-by", look.color_by,
                 "stored (the cache's colours), speed (a ramp over |velocity|) or attribute (--ramp-attribute)")
      ->check(pstream::app::one_of({"stored", "speed", "attribute"}));
  cmd.add_option("--ramp", look.ramp, "The ramp's colours: fire, ice, viridis or grey")
      ->check(pstream::app::one_of({"fire", "ice", "viridis", "grey"}));
  cmd.add_option("--ramp-range", look.ramp_range,
                 "LOW,HIGH: the values the ramp spans (speeds in units/s); by default what the clip holds: speeds "
                 "from 0 to their 99th percentile, an attribute from its 1st to 99th percentile");
  cmd.add_option("--ramp-attribute", look.ramp_attribute, "A float attribute the ramp colours by (age, temperature)");
  cmd.add_option("--tint", look.tint, "r,g,b multiplying every colour");
  cmd.add_option("--opacity", look.sprites.opacity, "Multiplies every particle's alpha")
      ->default_val(defaults.opacity)
      ->check(CLI::Range(0.0, 1.0));
  cmd.add_flag("--flat", look.flat, "No lighting: each sprite in its colour");
  cmd.add_flag("--tint-clips", look.tint_clips, "Tint each clip after the first differently, to tell them apart");
  cmd.add_flag("--bounds-box", look.bounds_box, "Draw the clips' bounds as a box");
  cmd.add_option("--shutter", look.sprites.shutter,
                 "Motion blur: seconds of motion each sprite is stretched along (1/48 is half a 24 fps frame); 0: off")
      ->default_val(defaults.shutter)
      ->check(CLI::NonNegativeNumber);
  cmd.add_option("--min-pixels", look.sprites.min_pixels,
                 "Smaller sprites are drawn this size and fainter, keeping their brightness; 0: off")
      ->default_val(defaults.min_pixels)
      ->check(CLI::NonNegativeNumber);
  cmd.add_option("--exposure", look.sprites.exposure, "Brightness before the tone map")
      ->default_val(defaults.exposure)
      ->check(CLI::PositiveNumber);
  cmd.add_option("--bloom", look.sprites.bloom,
                 "Glow: this share of the light spreads into a blur around it before the tone map (the total is "
                 "kept); 0: off")
      ->default_val(defaults.bloom)
      ->check(CLI::Range(0.0, 1.0));
  cmd.add_option("--bloom-radius", look.sprites.bloom_radius, "The glow's size: its Gaussian sigma in image heights")
      ->default_val(defaults.bloom_radius)
      ->check(CLI::Range(0.001, 0.25));
  cmd.add_option("--tone-map", look.tone_map, "filmic (bright light keeps its hue) or linear (clamps)")
      ->check(pstream::app::one_of({"filmic", "linear"}));
}

// Which flags the command line gave (a preset's parts they override).
std::vector<std::string> given_flags(const CLI::App& cmd) {
  std::vector<std::string> names;
  for (const CLI::Option* o : cmd.get_options()) {
    if (o->count() > 0) names.push_back(o->get_name());
  }
  return names;
}

}  // namespace

namespace {

// The closest of `names` (owned strings, as CLI11 gives them), by the library's one rule.
std::string closest(std::string_view word, const std::vector<std::string>& names) {
  const std::vector<std::string_view> views(names.begin(), names.end());
  return pstream::closest_name(word, views);
}

// An unknown subcommand or --flag on the command line, with the nearest real one; empty when the
// words are all known (CLI11 then parses and checks them).
std::string typo_message(CLI::App& app, int argc, char** argv) {
  CLI::App* at = &app;
  std::vector<CLI::App*> chain{at};
  bool expect_subcommand = true;
  for (int i = 1; i < argc; ++i) {
    const std::string_view word = argv[i];
    if (word == "--") break;
    if (word.starts_with("--")) {
      const std::string_view name =
          word.substr(2, word.find('=') == std::string_view::npos ? std::string_view::npos : word.find('=') - 2);
      std::vector<std::string> names;
      bool known = false;
      for (const CLI::App* a : chain) {
        for (const CLI::Option* o : a->get_options()) {
          for (const std::string& l : o->get_lnames()) {
            names.push_back(l);
            known = known || l == name;
          }
        }
      }
      if (known || name.empty()) continue;
      const std::string guess = closest(name, names);
      return guess.empty() ? fmt::format("unknown option --{} for `{}` (see its --help)", name, at->get_name())
                           : fmt::format("unknown option --{}; did you mean --{}?", name, guess);
    }
    // A short option (a letter after one dash; "-0.5" and "-3,2,1" are values) that no command on
    // the way has: CLI11 would otherwise report the positional argument after it.
    if (word.size() >= 2 && word[0] == '-' && word[1] != '-' && std::isalpha(static_cast<unsigned char>(word[1]))) {
      const char letter = word[1];
      bool known = false;
      std::vector<std::string> starting;  // the long options that start with that letter
      for (const CLI::App* a : chain) {
        for (const CLI::Option* o : a->get_options()) {
          for (const std::string& s : o->get_snames()) known = known || s == std::string(1, letter);
          for (const std::string& l : o->get_lnames())
            if (l.front() == letter && std::find(starting.begin(), starting.end(), l) == starting.end())
              starting.push_back(l);
        }
      }
      if (known) continue;
      std::string guess;
      for (std::size_t k = 0; k < starting.size(); ++k)
        guess += fmt::format("{}--{}", k == 0 ? "" : k + 1 == starting.size() ? " or " : ", ", starting[k]);
      const std::string_view shown = word.substr(0, 2);
      return starting.empty() || starting.size() > 3
                 ? fmt::format("unknown option {} for `{}` (see its --help)", shown, at->get_name())
                 : fmt::format("unknown option {}; did you mean {}?", shown, guess);
    }
    if (word.starts_with("-") || !expect_subcommand) continue;
    const std::vector<CLI::App*> subs = at->get_subcommands([](CLI::App*) { return true; });
    if (subs.empty()) {
      expect_subcommand = false;
      continue;
    }
    std::vector<std::string> names;
    CLI::App* next = nullptr;
    for (CLI::App* sub : subs) {
      names.push_back(sub->get_name());
      if (sub->get_name() == word) next = sub;
    }
    if (next == nullptr) {
      const std::string guess = closest(word, names);
      if (guess.empty()) return {};  // a positional argument or a real mistake: CLI11 says which
      return fmt::format("unknown command `{}`; did you mean `{}`?", word, guess);
    }
    at = next;
    chain.push_back(at);
  }
  return {};
}

}  // namespace

int main(int argc, char** argv) {
  using namespace pstream::app;
  CLI::App app{
      "pstream — play back pre-simulated particle caches in real time.\n\n"
      "Typical use:\n"
      "  pstream demo                                the whole pipeline on a built-in simulation\n"
      "  pstream info sim.abc                        what is in an Alembic point cache\n"
      "  pstream cook sim.abc -o sim.pstream         cook it into fixed-size chunks for streaming\n"
      "  pstream info sim.pstream                    what the cooked clip holds\n"
      "  pstream verify sim.pstream                  check every checksum and index entry\n"
      "  pstream play sim.pstream                    watch it in a window, with the chunk cache view\n"
      "  pstream render sim.pstream --out frames     headless PNG frames (and --video out.mp4)\n"
      "  pstream bench all                           every benchmark, written to docs/benchmarks.md",
      "pstream"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "pstream 0.1.0");

  // info -------------------------------------------------------------------------------------
  std::string info_file;
  bool info_json = false, info_frames = false;
  auto* info_cmd = app.add_subcommand(
      "info", "Describe an Alembic (.abc) file, a PLY sequence (any of its .ply files) or a cooked (.pstream) clip");
  info_cmd
      ->add_option("file", info_file,
                   "An Alembic (Ogawa) or .pstream file, or its http(s):// URL (.abc: Alembic); or a file of a "
                   "numbered PLY sequence (NAME.0001.ply: the whole sequence)")
      ->required()
      ->check(file_or_url());
  info_cmd->add_flag("--json", info_json,
                     "Print JSON. For Alembic: the alembic-fixture-expected/1 schema (docs/alembic.md), comparable "
                     "value by value with the official library. For .pstream: header, layout and chunk summary");
  info_cmd->add_flag("--frames", info_frames,
                     "With --json on a .pstream: per-frame count and float64 sums of x, y, z, scale");

  // cook -------------------------------------------------------------------------------------
  CookCli cook;
  auto* cook_cmd = app.add_subcommand("cook",
                                      "Cook an Alembic point cache or a numbered PLY sequence into a .pstream\n\n"
                                      "Examples:\n"
                                      "  pstream cook splash.abc -o splash.pstream\n"
                                      "  pstream cook splash.abc -o splash.pstream --error abs:0.0005   "
                                      "(positions within 0.0005: 0.5 mm in metres)\n"
                                      "  pstream cook splash.abc -o exact.pstream --codec raw           "
                                      "(every bit as the source wrote it)\n"
                                      "  pstream cook fx.abc --object /fx/sparks -o sparks.pstream --codec zstd:5\n"
                                      "  pstream cook fx.abc --merge --fps 60 --interpolate -o fx.pstream\n"
                                      "  pstream cook render/frame.0001.ply --fps 24 -o smoke.pstream");
  cook_cmd
      ->add_option("input", cook.input,
                   "Alembic file (or its http(s):// URL: read whole into memory), or any file of a local PLY "
                   "sequence (frame.0001.ply)")
      ->required()
      ->check(file_or_url());
  cook_cmd
      ->add_option("-o,--output", cook.output,
                   "The .pstream to write (written to a temporary file, renamed on success)")
      ->required();
  cook_cmd->add_option("--object", cook.object,
                       "Full name of the points object (or a PolyMesh, cooked as its vertices)");
  cook_cmd->add_flag("--merge", cook.merge, "Cook every points object into one stream, each with its own transform");
  cook_cmd->add_flag("--no-xforms", cook.no_xforms,
                     "Keep positions in object space (default: bake the world transform)");
  cook_cmd->add_option("--fps", cook.fps, "Output frame rate (default: the source's; PLY: 24)")
      ->check(positive_number());
  cook_cmd->add_flag("--interpolate", cook.interpolate,
                     "Between source samples, blend particles matched by id (default: take the nearest sample)");
  cook_cmd
      ->add_option("--scale-from", cook.scale_from,
                   "widths (a width is a diameter; the record stores the radius), constant:X, or attr:NAME")
      ->capture_default_str();
  cook_cmd->add_option("--color-from", cook.color_from, "Cd, none, or auto (Cd when the source has it)")
      ->capture_default_str();
  cook_cmd->add_option("--attributes", cook.attributes,
                       "Extra record attributes, comma separated: velocity, id (uint64), id32, or any float attribute");
  cook_cmd->add_option("--chunk-size", cook.chunk_size, "Chunk size, a power of two from 64KiB to 64MiB")
      ->capture_default_str();
  cook_cmd
      ->add_option(
          "--codec", cook.codec,
          "particle[:LEVEL] (the default): error-bounded (--error, --scale-error), predicted over time, "
          "about 1 byte per particle per frame of [x y z scale] with ids, 2 without (LEVEL, zstd's, 1..22, "
          "default 16 with ids, 12 without: lower cooks faster, a little larger); particle-lossless: bit-exact, "
          "source order kept; raw, lz4[:HC level], zstd[:level]: the records as they are, chunk-compressed")
      ->capture_default_str();
  cook_cmd
      ->add_option("--error", cook.error,
                   "particle codec: the bound on every decoded position coordinate, as a fraction of the clip's bounds "
                   "diagonal (1e-4, or rel:1e-4) or in scene units (abs:0.001); colours and ids are exact")
      ->capture_default_str();
  cook_cmd
      ->add_option("--attribute-error", cook.attribute_error,
                   "particle codec: the bound on velocity and other float attributes, a fraction of each one's own "
                   "range")
      ->capture_default_str();
  cook_cmd
      ->add_option("--scale-error", cook.scale_error,
                   "particle codec: the bound on each particle's scale, relative to its own (1% or 0.01): sizes keep "
                   "their differences however small they are next to the scene")
      ->capture_default_str();
  cook_cmd
      ->add_option("--keyframe-interval", cook.keyframe_interval,
                   "particle codec: a frame that decodes alone every K frames; a seek decodes at most K-1 frames "
                   "past it")
      ->capture_default_str()
      ->check(CLI::Range(1, 1024));
  cook_cmd->add_flag("--no-velocity", cook.no_velocity,
                     "Give the clip no velocity. By default it has one (speed colours, motion blur, stretched "
                     "sprites and smooth slow motion need it): derived from the positions of particles with ids "
                     "(particle codec, no bytes stored), else the source's velocities when it has them");
  cook_cmd->add_flag("--store-velocity", cook.store_velocity,
                     "particle codec: store the source's velocities (within --attribute-error, about 2.3 bytes per "
                     "particle) instead of deriving them from the positions of particles with ids (docs/"
                     "compression.md: the derived one's error)");
  cook_cmd->add_option(
      "--frames", cook.frames,
      "Output frames A:B (from A up to but not including B; either may be left out), or N for frame N alone");
  cook_cmd->add_flag("--keep-order", cook.keep_order,
                     "Keep each frame's particles in the source's order (records codec). By default a clip with "
                     "ids is written in ascending id order, so players match particles between frames by a "
                     "linear merge and interpolate them");
  cook_cmd->add_flag("--drop-invalid", cook.drop_invalid,
                     "Drop particles with NaN or infinite positions instead of failing");
  cook_cmd->add_option("--max-particles", cook.max_particles, "Largest particle count a frame may have")
      ->capture_default_str();
  cook_cmd
      ->add_option("--max-frames", cook.max_frames,
                   "Largest number of frames a cook may make (a guard against a mistyped --fps or a source whose "
                   "time range is absurd)")
      ->capture_default_str();
  cook_cmd->add_option("--threads", cook.threads, "Chunk encoding threads (default: one per core)");
  cook_cmd->add_flag("-q,--quiet", cook.quiet, "No progress bar or summary");
  cook_cmd->add_flag("--json", cook.json, "Print the cook report as JSON");

  // export -----------------------------------------------------------------------------------
  ExportCli export_cli;
  auto* export_cmd = app.add_subcommand(
      "export",
      "Write a cooked clip back out for a DCC: a binary PLY sequence (x y z pscale, vx vy vz, red green blue\n"
      "alpha, id and float attributes) or an Alembic points cache (P, ids, velocities, widths = 2 x scale, Cd:\n"
      "rgb, or rgba when any particle is not opaque).\n"
      "Examples:\n"
      "  pstream export splash.pstream --out splash_ply        # splash_ply/frame.0001.ply ...\n"
      "  pstream export splash.pstream -o splash_decoded.abc\n"
      "  pstream export splash.pstream -o seq/splash.ply     # seq/splash.0001.ply ...");
  export_cmd->add_option("file", export_cli.file, "A .pstream file")->required()->check(file_or_url());
  export_cmd->add_option("--out", export_cli.out, "Folder for the PLY sequence");
  export_cmd->add_option("-o,--output", export_cli.output,
                         "The file to write; its extension chooses the format: NAME.abc (an Alembic cache) or "
                         "NAME.ply (a PLY sequence NAME.0001.ply ...)");
  export_cmd->add_option("--frames", export_cli.frames,
                         "Clip frames A:B (from A up to but not including B; either may be left out), or N for frame N "
                         "alone; a PLY file keeps its frame's number");
  export_cmd->add_flag("-q,--quiet", export_cli.quiet, "No progress or summary");
  export_cmd->add_flag("--json", export_cli.json,
                       "Print what was written as JSON (format, frames, first file, bytes_written)");

  // verify -----------------------------------------------------------------------------------
  std::string verify_file;
  bool verify_json = false;
  auto* verify_cmd = app.add_subcommand(
      "verify", "Check every checksum and index entry of a .pstream (exit code 0 only if all is right)");
  std::string verify_against;
  verify_cmd->add_option("file", verify_file, "A .pstream file")->required()->check(file_or_url());
  verify_cmd
      ->add_option("--against", verify_against,
                   "The Alembic file (or PLY sequence) the clip was cooked from: decode every frame and report the\n"
                   "largest error of each attribute against the source, pairing particles by id, or by nearest\n"
                   "position when the codec re-ordered a cache without ids. Fails above the clip's stated bound.")
      ->check(file_or_url());
  verify_cmd->add_flag("--json", verify_json, "Print the result as JSON");

  // bench ------------------------------------------------------------------------------------
  auto* bench_cmd = app.add_subcommand("bench", "Measure a stage against a baseline run side by side");
  bench_cmd->require_subcommand(1);
  BenchReadOptions bench_read_opts;
  auto* read_cmd = bench_cmd->add_subcommand(
      "read", "Read every frame's positions into a caller buffer, compared with memcpy of the same mapped bytes");
  read_cmd->add_option("file", bench_read_opts.file, "An Alembic file")->required()->check(CLI::ExistingFile);
  read_cmd->add_option("--object", bench_read_opts.object, "Full name of the points object (default: the largest)");
  read_cmd->add_option("--repetitions", bench_read_opts.repetitions, "Passes over all frames; medians are reported")
      ->check(CLI::Range(1, 10000));
  read_cmd->add_flag("--json", bench_read_opts.json, R"(Print {"read_ms":…, "memcpy_ms":…, "ratio":…})");
  BenchCookOptions bench_cook_opts;
  auto* bench_cook_cmd = bench_cmd->add_subcommand(
      "cook", "Cook with the raw codec, compared with plainly reading the source and writing as many bytes");
  bench_cook_cmd->add_option("file", bench_cook_opts.file, "An Alembic file")->required()->check(CLI::ExistingFile);
  bench_cook_cmd->add_option("--repetitions", bench_cook_opts.repetitions, "Runs of each; medians are reported")
      ->check(CLI::Range(1, 1000));
  bench_cook_cmd->add_flag("--json", bench_cook_opts.json, R"(Print {"cook_mb_s":…, "baseline_mb_s":…, "ratio":…})");

  BenchSortOptions bench_sort_opts;
  auto* bench_sort_cmd = bench_cmd->add_subcommand(
      "sort",
      "Compare depth sorts (bubble, comb, insertion, merge, quick, std::sort, std::stable_sort, vqsort, ours)\n"
      "on random, nearly sorted and reversed depths, N = 1k .. 4M");
  bench_sort_cmd->add_option("--n", bench_sort_opts.n, "One size only, random input (prints ours_ms, vqsort_ms, ...)");
  bench_sort_cmd->add_option("--repetitions", bench_sort_opts.repetitions, "Runs of each; medians are reported")
      ->check(CLI::Range(1, 1000));
  bench_sort_cmd->add_option("--svg", bench_sort_opts.svg, "Write a log-log plot of the random-input timings");
  bench_sort_cmd->add_option("--markdown", bench_sort_opts.markdown, "Write the table as Markdown");
  bench_sort_cmd->add_flag("--json", bench_sort_opts.json, "Print JSON");

  BenchCodecOptions bench_codec_opts;
  auto* bench_codec_cmd = bench_cmd->add_subcommand(
      "codec",
      "The particle codec against raw, lz4, zstd -3/-19, byte-shuffle + zstd, meshoptimizer's vertex codec + zstd\n"
      "and Draco, on the same frames of [x y z scale] records at the same error bound: bytes per particle per\n"
      "frame, max error, encode MB/s and decode GB/s (one core, thread CPU time, medians) next to a memcpy of the\n"
      "decoded bytes. Each repetition decodes with every codec in turn, so ours is compared with zstd -3 and\n"
      "meshoptimizer + zstd within repetitions. Each codec decodes the clip twice in a row: dec GB/s is the\n"
      "second pass (its data in cache), '1st pass' the first (after the other codecs' work). Every codec's\n"
      "output is held at once (--codec and --frames keep a large cache within memory).\n"
      "Examples:\n"
      "  pstream bench codec tests/data/sims/blender_sparks.abc\n"
      "  pstream bench codec out/demo/demo.abc --frames 60 --json\n"
      "  pstream bench codec tests/data/sims/blender_flip_pour_small.abc --error 4e-4   (size at a looser bound)");
  bench_codec_cmd->add_option("file", bench_codec_opts.file, "An Alembic file (or PLY sequence) to take frames from")
      ->required()
      ->check(file_or_url());
  bench_codec_cmd->add_option("--object", bench_codec_opts.object, "The points object (default: the only one)");
  bench_codec_cmd->add_option("--frames", bench_codec_opts.frames, "Use the first N frames (default: all)");
  bench_codec_cmd->add_option(
      "--codec", bench_codec_opts.codecs,
      "Only these codecs (names as in the table, e.g. 'particle (ours)', 'zstd -3'); repeatable");
  bench_codec_cmd
      ->add_option("--zstd-level", bench_codec_opts.zstd_level,
                   "The particle codec's zstd level (default 16 with ids, 12 without: its entropy stage's trade-off)")
      ->check(CLI::Range(1, 22));
  bench_codec_cmd
      ->add_option("--error", bench_codec_opts.error,
                   "The bound on every position coordinate for the particle codec, meshoptimizer's and Draco's "
                   "quantisation: a fraction of the bounds diagonal (1e-4, or rel:1e-4) or scene units (abs:0.001), "
                   "as cook --error")
      ->capture_default_str();
  bench_codec_cmd
      ->add_option("--scale-error", bench_codec_opts.scale_error,
                   "The bound on each particle's scale, relative to its own (1% or 0.01), as cook --scale-error")
      ->capture_default_str();
  bench_codec_cmd
      ->add_option("--repetitions", bench_codec_opts.repetitions,
                   "Decode runs of every codec, and encode runs up to 2 s of CPU a codec; medians are reported")
      ->capture_default_str()
      ->check(CLI::Range(1, 100));
  bench_codec_cmd->add_flag("--json", bench_codec_opts.json, "Print the results as JSON");
  bench_codec_cmd->add_option("--svg", bench_codec_opts.svg, "Also plot bytes per particle against decode speed (SVG)");

  BenchStreamOptions bench_stream_opts;
  auto* bench_stream_cmd = bench_cmd->add_subcommand(
      "stream",
      "Per-frame cost of update() + copying the frame out, against memcpy of the same bytes, in real time. Each is "
      "timed on alternate frames, where it is the first to read the frame (a copy that follows another finds the "
      "frame in the caches); update + copy in wall time and in the host thread's CPU time");
  bench_stream_cmd
      ->add_option("clip", bench_stream_opts.file,
                   "A .pstream, or its http(s):// URL: then the clip is downloaded and played from the local copy "
                   "(the file backend), from the URL with every read its own request, and from the URL as the "
                   "library reads it (neighbouring reads merged), in the same run, and the requests, bytes fetched "
                   "and stalls of each reported (default: generate 1M particles x 60 frames in a temporary folder)")
      ->check(file_or_url());
  bench_stream_cmd->add_option("--particles", bench_stream_opts.particles, "Particles per generated frame")
      ->capture_default_str();
  bench_stream_cmd->add_option("--frames", bench_stream_opts.frames, "Generated frames")->capture_default_str();
  bench_stream_cmd->add_option("--fps", bench_stream_opts.fps, "Generated frame rate")->capture_default_str();
  bench_stream_cmd->add_option("--cache-seconds", bench_stream_opts.cache_seconds, "Seconds of frames the cache holds")
      ->capture_default_str();
  bench_stream_cmd->add_option("--laps", bench_stream_opts.laps, "Times through the clip")->capture_default_str();
  bench_stream_cmd
      ->add_option("--codec", bench_stream_opts.codec,
                   "The generated clip's frames: records (raw chunks) or particle (decoded on the IO worker)")
      ->capture_default_str()
      ->check(pstream::app::one_of({"records", "particle"}));
  bench_stream_cmd->add_flag(
      "--json", bench_stream_opts.json,
      R"(Print {"frame_ms_median":…, "memcpy_ms_median":…, "ratio":…, "stalls":…, "requests":…, "bytes_fetched":…} (a URL: also "file_backend": {…} and "unmerged": {…}))");

  BenchPlaybackOptions bench_playback_opts;
  auto* bench_playback_cmd = bench_cmd->add_subcommand(
      "playback",
      "Per-host-frame cost of playback on the GPU path and the CPU path side by side, at 120 Hz on a 24 fps clip:\n"
      "the host thread's CPU time (advance, draw data, the renderer's preparation: interpolation and sort on the\n"
      "CPU path, uploads and compute dispatches on the GPU path) and the bytes uploaded per host frame and per\n"
      "cached frame. Without FILE: clips of 100k, 1M and 4M particles with velocities and ids, generated.\n"
      "  pstream bench playback --particles 1000000 --path gpu --json");
  bench_playback_cmd->add_option("file", bench_playback_opts.file, "A .pstream (default: generated)");
  bench_playback_cmd->add_option("--particles", bench_playback_opts.particles,
                                 "Particles per generated frame (repeatable)");
  bench_playback_cmd->add_option("--path", bench_playback_opts.paths, "gpu or cpu (repeatable; default both)")
      ->check(pstream::app::one_of({"gpu", "cpu"}));
  bench_playback_cmd->add_option("--frames", bench_playback_opts.frames, "Frames per generated clip")
      ->capture_default_str();
  bench_playback_cmd->add_option("--host-hz", bench_playback_opts.host_hz, "Host frame rate")
      ->capture_default_str()
      ->check(positive_number());
  bench_playback_cmd->add_flag(
      "--json", bench_playback_opts.json,
      R"(Print {"rows":[{"path","particles","host_thread_ms","upload_bytes_per_host_frame","upload_bytes_per_cached_frame",…}]})");

  RenderCli render_cli;
  auto* render_cmd = app.add_subcommand(
      "render",
      "Render a .pstream headless (no display needed) to PNG frames and, with ffmpeg, an MP4\n\n"
      "Examples:\n"
      "  pstream render splash.pstream --out frames\n"
      "  pstream render splash.pstream --out frames --frames 0:48 --size 1920x1080 --video splash.mp4\n"
      "  pstream render fx.pstream --out f --camera 4,3,6:0,1,0 --blend additive\n"
      "  pstream render fx.pstream --out slow --fps 120 --speed 0.25   (slow motion, every image interpolated)\n"
      "  pstream render pour.pstream --out water --look liquid --foam-speed 3\n"
      "  pstream render smoke.pstream --out s --preset smoke --slices 64   (self-shadowed, shadows on the ground)\n"
      "  pstream render sparks.pstream --out k --preset sparks --shutter 0.04   (glowing streaks)\n"
      "  pstream render fx.pstream --out v --color-by speed --ramp fire --ramp-range 0,8\n"
      "  pstream render a.pstream b.pstream --out both   (two clips in one picture)");
  render_cmd
      ->add_option("files", render_cli.files,
                   "One or more .pstream files, drawn together (overlapping clips blend in depth order; as a "
                   "liquid they make one surface). --frames counts the first clip's frames")
      ->required()
      ->check(file_or_url());
  render_cmd
      ->add_option(
          "--out", render_cli.out,
          "Folder for frame_NNNNN.png, numbered by source frame (a cache from frame 1 starts at frame_00001.png)")
      ->capture_default_str();
  render_cmd->add_option(
      "--frames", render_cli.frames,
      "Clip frames A:B (from A up to but not including B; either may be left out), or N for frame N alone");
  render_cmd->add_option("--size", render_cli.size, "Image size WIDTHxHEIGHT")->capture_default_str();
  render_cmd
      ->add_option("--camera", render_cli.camera,
                   "auto (follow the effect: pull back as it grows, come in slowly as it shrinks), fixed (one "
                   "camera for every frame) or x,y,z:tx,ty,tz")
      ->capture_default_str();
  render_cmd->add_option("--fps", render_cli.fps, "Output frame rate (default: the clip's)")->check(positive_number());
  render_cmd
      ->add_option("--speed", render_cli.speed,
                   "Clip seconds per output second: 0.25 renders slow motion, each image interpolated "
                   "between the cached frames")
      ->capture_default_str()
      ->check(positive_number());
  render_cmd
      ->add_option("--interpolation", render_cli.interpolation,
                   "Images between cached frames: hermite (along velocities), linear, or none (the nearest frame)")
      ->capture_default_str()
      ->check(pstream::app::one_of({"hermite", "linear", "none"}));
  render_cmd
      ->add_option(
          "--playback", render_cli.playback,
          "Where interpolation between cached frames and the depth sort run: gpu (compute shaders; each cached frame "
          "uploaded once, the host thread's cost flat at any particle count) or cpu (the reference path)")
      ->capture_default_str()
      ->check(pstream::app::one_of({"gpu", "cpu"}));
  render_cmd->add_option("--max-frames", render_cli.max_frames, "Largest number of images a render may write")
      ->capture_default_str();
  render_cmd->add_option("--video", render_cli.video, "Also write an MP4 through ffmpeg");
  render_cmd->add_option("--blend", render_cli.blend, "alpha (sorted), additive or alphatest")
      ->capture_default_str()
      ->check(pstream::app::one_of({"alpha", "additive", "alphatest"}));
  render_cmd->add_option("--sort", render_cli.sort, "back (back to front), front, or none")
      ->capture_default_str()
      ->check(pstream::app::one_of({"back", "front", "none"}));
  render_cmd->add_option("--size-multiplier", render_cli.size_multiplier, "Scale every particle")
      ->capture_default_str()
      ->check(positive_number());
  render_cmd->add_option("--texture", render_cli.texture, "A sprite image (PNG) instead of the soft round sprite");
  render_cmd
      ->add_option("--look", render_cli.look,
                   "sprites (a lit round sprite per particle) or liquid (a screen-space surface: smoothed depth, "
                   "refraction, absorption by thickness, Fresnel sky reflection, spray)")
      ->capture_default_str();
  render_cmd
      ->add_option("--backdrop", render_cli.backdrop,
                   "auto (a ground grid under the clip for the liquid and self-shadowing looks, nothing behind "
                   "other sprites), ground, sky or none")
      ->check(pstream::app::one_of({"auto", "ground", "sky", "none"}))
      ->capture_default_str();
  render_cmd
      ->add_option("--particle-radius", render_cli.liquid.particle_radius,
                   "Liquid: every particle's radius in scene units (default: the median cooked radius)")
      ->check(CLI::NonNegativeNumber);
  render_cmd
      ->add_option("--liquid-color", render_cli.liquid_color,
                   "Liquid: r,g,b in (0,1], what --liquid-color-depth of liquid lets through (deeper is darker "
                   "and more saturated)")
      ->default_str(
          fmt::format("{},{},{}", render_cli.liquid.color[0], render_cli.liquid.color[1], render_cli.liquid.color[2]));
  render_cmd
      ->add_option("--liquid-color-depth", render_cli.liquid.color_depth,
                   "Liquid: the depth, in particle radii, that tints the background to --liquid-color")
      ->check(positive_number())
      ->capture_default_str();
  render_cmd
      ->add_option("--liquid-opacity-depth", render_cli.liquid.opacity_depth,
                   "Liquid: the thickness, in particle radii (a layer of touching spheres is about 1), that hides "
                   "63 % of what is behind behind the liquid's own lit colour and blurs the rest; 0: clear as glass")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  render_cmd
      ->add_option("--liquid-shadow-depth", render_cli.liquid.shadow_depth,
                   "Liquid: its shadow on the ground (with --backdrop auto or ground) darkens the ground by 63 % of "
                   "--liquid-shadow-strength under this many particle radii of summed sphere chords along the "
                   "light; 0: no shadow")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  render_cmd
      ->add_option("--liquid-shadow-strength", render_cli.liquid.shadow_strength,
                   "Liquid: how dark its shadow gets under deep liquid, 0..1 (0.5 halves the ground's light; water "
                   "lets most light through)")
      ->check(CLI::Range(0.0f, 1.0f))
      ->capture_default_str();
  render_cmd
      ->add_option("--liquid-smoothing", render_cli.liquid.smoothing,
                   "Liquid: the depth filter's radius in particle radii (larger: calmer surface, fewer beads)")
      ->check(CLI::Range(0.0f, 20.0f))
      ->capture_default_str();
  render_cmd
      ->add_option("--liquid-iterations", render_cli.liquid.iterations,
                   "Liquid: passes of the depth filter at its full radius, after three at smaller radii; 0: the raw "
                   "sphere splats, 0..8")
      ->check(CLI::Range(0, 8))
      ->capture_default_str();
  render_cmd->add_option(
      "--liquid-filter", render_cli.liquid_filter,
      "Liquid: narrow-range (default: sharp silhouettes), bilateral, gaussian (halos; for comparison) or none");
  render_cmd
      ->add_option("--liquid-resolution", render_cli.liquid.resolution,
                   "Liquid: depth and thickness at this fraction of the image size (0.25..1; 0.5 is 4x fewer pixels)")
      ->check(CLI::Range(0.25f, 1.0f))
      ->capture_default_str();
  render_cmd->add_option("--liquid-output", render_cli.liquid_output,
                         "Liquid: shaded (default), or an inspection view: depth, normals, thickness");
  render_cmd
      ->add_option("--foam-speed", render_cli.liquid.foam_speed,
                   "Liquid: particles faster than this (scene units/s; needs velocities) are white spray; 0: off")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  render_cmd
      ->add_option("--foam-isolation", render_cli.liquid.foam_isolation,
                   "Liquid: particles where the liquid is thinner than this many radii are spray; 0: off")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  add_look_flags(*render_cmd, render_cli.sprite_look);
  render_cmd->add_flag("-q,--quiet", render_cli.quiet, "No progress or summary");
  render_cmd->add_flag(
      "--json", render_cli.json,
      "Print {\"frames\", \"size\", \"gl_renderer\", \"frame_ms\": {\"median\", \"p95\"}} (each image's "
      "draw and read-back, PNG writing excluded) instead of the summary");
  render_cmd->add_flag("--no-clobber", render_cli.no_clobber,
                       "Refuse a folder that holds frames of an earlier render (by default they are replaced, and "
                       "any past this render's last removed, so the folder holds exactly this render)");

  ViewerCli viewer;
  auto* play_cmd = app.add_subcommand(
      "play",
      "Open a window and play .pstream files: orbit camera, playback controls, statistics, chunk cache view\n\n"
      "Keys: space play/pause, left/right step a frame, F frame the clip, H hide or show the panel, Esc quit.\n"
      "Mouse: left drag orbits, right drag pans, wheel zooms.");
  play_cmd->add_option("files", viewer.files, "One or more .pstream files")->required()->check(file_or_url());
  play_cmd->add_option("--width", viewer.width, "Window width")->capture_default_str();
  play_cmd->add_option("--height", viewer.height, "Window height")->capture_default_str();
  play_cmd->add_option("--frames-to-run", viewer.frames_to_run,
                       "Quit after N frames (scripted runs: 1/30 s a frame, each decoded before it is drawn)");
  play_cmd->add_option("--screenshot", viewer.screenshot, "With --frames-to-run: save the last frame as PNG");
  play_cmd->add_flag("--hide-ui", viewer.hide_ui,
                     "Start with the panel and the timeline hidden (H shows them); scripted runs print where they "
                     "would be");
  play_cmd->add_option("--look", viewer.look, "sprites or liquid (a screen-space surface; its settings in the panel)")
      ->check(pstream::app::one_of({"sprites", "liquid"}));
  play_cmd
      ->add_option(
          "--playback", viewer.playback,
          "Where interpolation between cached frames and the depth sort run: gpu (compute shaders; each cached frame "
          "uploaded once, the host thread's cost flat at any particle count) or cpu (the reference path)")
      ->capture_default_str()
      ->check(pstream::app::one_of({"gpu", "cpu"}));
  add_look_flags(*play_cmd, viewer.sprite_look);

  DemoCli demo;
  auto* demo_cmd = app.add_subcommand(
      "demo",
      "The whole pipeline on a built-in simulation: simulate -> DIR/demo.abc -> cook DIR/demo.pstream -> stream in\n"
      "real time -> sort -> render DIR/frames/*.png, DIR/demo.mp4, DIR/report.md + .json, and DIR/contact_sheet.png:\n"
      "every preset at its best moment (the other two simulated, cooked and rendered into DIR/presets/).\n"
      "With a display (or --window) it opens the viewer instead of rendering headless.");
  demo_cmd->add_option("--preset", demo.preset, "fountain, explosion or smoke (smoke is where sorting matters)")
      ->capture_default_str();
  demo_cmd->add_option("--particles", demo.particles, "About the peak particle count")->capture_default_str();
  demo_cmd->add_option("--seconds", demo.seconds, "Length of the simulation")->capture_default_str();
  demo_cmd->add_option("--fps", demo.fps, "Frames per second")->capture_default_str();
  demo_cmd->add_option("--seed", demo.seed, "Random seed (the simulation is deterministic for a seed)")
      ->capture_default_str();
  demo_cmd->add_option("--out", demo.out, "Output folder")->capture_default_str();
  demo_cmd->add_option("--size", demo.size, "Rendered frame size")->capture_default_str();
  demo_cmd
      ->add_option(
          "--playback", demo.playback,
          "Where interpolation between cached frames and the depth sort run: gpu (compute shaders; each cached frame "
          "uploaded once, the host thread's cost flat at any particle count) or cpu (the reference path)")
      ->capture_default_str()
      ->check(pstream::app::one_of({"gpu", "cpu"}));
  demo_cmd->add_flag("--window", demo.window, "Open the viewer after cooking");
  demo_cmd->add_flag("--headless", demo.headless, "Render frames even when a display is available");
  demo_cmd->add_flag("-q,--quiet", demo.quiet, "No progress or summary");

  BenchRenderOptions bench_render_opts;
  auto* bench_render_cmd = bench_cmd->add_subcommand(
      "render",
      "Per-frame cost of 100k and 1M particles: sprites (instanced quads) vs GL points vs the screen-space liquid, "
      "as ratios to the sprites in the same run; the liquid with and without its shadow on a ground, and alpha "
      "sprites with and without self-shadowing (32 slices), each as their ratio and the overhead in ms; with "
      "GL_RENDERER");
  bench_render_cmd
      ->add_option("--size", bench_render_opts.size, "Image size WIDTHxHEIGHT (1920x1080 for the GPU target)")
      ->capture_default_str();
  bench_render_cmd->add_option("--repetitions", bench_render_opts.repetitions, "Frames timed per case")
      ->check(CLI::Range(1, 100));
  bench_render_cmd->add_flag("--json", bench_render_opts.json, "Print JSON");

  BenchAllOptions bench_all_opts;
  auto* bench_all_cmd = bench_cmd->add_subcommand(
      "all", "Run every benchmark on generated 1M-particle clips and write a Markdown page with tables and a plot");
  bench_all_cmd->add_option("--out", bench_all_opts.out, "The page to write (a plot is written beside it)")
      ->capture_default_str();

  // Typos first: an unknown subcommand or flag gets "did you mean" (CLI11 would report the file
  // that the misread arguments named, or "a subcommand is required").
  if (const std::string typo = typo_message(app, argc, argv); !typo.empty()) {
    fmt::print(stderr, "pstream: error: {}\nRun with --help for more information.\n", typo);
    return 2;
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // `pstream` or `pstream bench` alone: what it offers, rather than "a subcommand is required".
    if (dynamic_cast<const CLI::RequiredError*>(&e) != nullptr &&
        std::string_view(e.what()).find("subcommand is required") != std::string_view::npos) {
      const CLI::App* at = &app;
      while (!at->get_subcommands().empty()) at = at->get_subcommands().front();
      fmt::print(stderr, "{}", at->help());
      return 2;
    }
    return app.exit(e);
  }
  render_cli.sprite_look.given = given_flags(*render_cmd);
  viewer.sprite_look.given = given_flags(*play_cmd);
  if (play_cmd->parsed() && !viewer.screenshot.empty() && viewer.frames_to_run <= 0) {
    fmt::print(stderr,
               "pstream: error: --screenshot needs --frames-to-run N (the frame to save; the viewer otherwise "
               "runs until its window is closed)\n");
    return 1;
  }
  // Every command that plays or reads a cooked clip: an Alembic or PLY file gets "cook it first".
  const auto cooked = [](const std::string& file) {
    require_cooked(file);
    return file;
  };
  const auto dispatch = [&]() -> int {
    if (info_cmd->parsed()) {
      if (is_pstream_file(info_file) || std::filesystem::path(info_file).extension() == ".pstream")
        return info_pstream({info_file, info_json, info_frames});
      if (pstream::cook::is_ply_sequence(info_file)) return info_ply({info_file, info_json});
      return info_alembic({info_file, info_json});
    }
    if (cook_cmd->parsed()) return run_cook(cook);
    if (verify_cmd->parsed()) return verify_pstream(cooked(verify_file), verify_json, verify_against);
    if (export_cmd->parsed()) {
      cooked(export_cli.file);
      return run_export(export_cli);
    }
    if (read_cmd->parsed()) return bench_read(bench_read_opts);
    if (bench_cook_cmd->parsed()) return bench_cook(bench_cook_opts);
    if (bench_sort_cmd->parsed()) return bench_sort(bench_sort_opts);
    if (bench_stream_cmd->parsed()) {
      if (!bench_stream_opts.file.empty()) cooked(bench_stream_opts.file);
      return bench_stream(bench_stream_opts);
    }
    if (bench_codec_cmd->parsed()) return bench_codec(bench_codec_opts);
    if (bench_playback_cmd->parsed()) {
      if (!bench_playback_opts.file.empty()) cooked(bench_playback_opts.file);
      return bench_playback(bench_playback_opts);
    }
    if (render_cmd->parsed()) {
      for (const std::string& f : render_cli.files) cooked(f);
      return run_render(render_cli);
    }
    if (play_cmd->parsed()) {
      for (const std::string& f : viewer.files) cooked(f);
      return run_viewer(viewer);
    }
    if (demo_cmd->parsed()) return run_demo(demo);
    if (bench_render_cmd->parsed()) return bench_render(bench_render_opts);
    if (bench_all_cmd->parsed()) return bench_all(bench_all_opts);
    return 0;
  };
  // Which command on which input ran out of a resource: the message a user can act on.
  const auto out_of_resources = [&](const std::string& what) {
    std::string inputs;
    for (const std::string* f : {&info_file, &cook.input, &verify_file, &export_cli.file, &bench_stream_opts.file,
                                 &bench_playback_opts.file}) {
      if (!f->empty()) inputs += " " + *f;
    }
    for (const auto* files : {&render_cli.files, &viewer.files})
      for (const std::string& f : *files) inputs += " " + f;
    std::string command;
    for (const CLI::App* sub = &app; !sub->get_subcommands().empty();) {
      sub = sub->get_subcommands().front();
      command += (command.empty() ? "" : " ") + sub->get_name();
    }
    return fmt::format("{}{}: {}", command, inputs, what);
  };
  int status = 0;
  std::string error;
  try {
    status = dispatch();
  } catch (const pstream::Error& e) {
    error = in_cli_terms(e.what());
    status = 1;
  } catch (const std::bad_alloc&) {
    error = out_of_resources(
        "out of memory: the input asks for more than this machine has (see "
        "docs/reliability.md for the limits and how to raise or lower them)");
    status = 1;
  } catch (const std::filesystem::filesystem_error& e) {  // names the path and the system's reason
    error = out_of_resources(e.what());
    status = 1;
  } catch (const std::system_error& e) {  // the system refused a thread or a lock
    error =
        out_of_resources(fmt::format("the system refused a resource ({}); try again with fewer other programs "
                                     "running, or a higher limit (ulimit)",
                                     e.what()));
    status = 1;
  } catch (const std::exception& e) {
    fmt::print(stderr, "pstream: internal error: {}\n", e.what());
    status = 2;
  }
  // A file truncated under a read: whatever came of it is void, whatever the command said.
  if (const std::string truncated = pstream::MappedFile::truncated_file(); !truncated.empty()) {
    fmt::print(stderr,
               "pstream: error: {}: the file was truncated while it was being read; nothing is written from "
               "it\n",
               truncated);
    return 1;
  }
  if (!error.empty()) fmt::print(stderr, "pstream: error: {}\n", error);
  return status;
}
