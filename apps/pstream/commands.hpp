// The pstream subcommands; each returns the process exit code.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "particlestream/playback.hpp"
#include "particlestream/render.hpp"

namespace pstream::app {

struct InfoOptions {
  std::string file;
  bool json = false;
};
int info_alembic(const InfoOptions& options);
int info_ply(const InfoOptions& options);  // a PLY sequence, from any of its files

struct InfoPstreamOptions {
  std::string file;
  bool json = false;
  bool frames = false;  // with json: per-frame sums
};
int info_pstream(const InfoPstreamOptions& options);
// Checks every checksum and index entry and decodes every frame; with `against` (the source it
// was cooked from), also compares every decoded value with the source's, per attribute, against
// the bounds the codec states (exact attributes must be equal).
int verify_pstream(const std::string& file, bool json, const std::string& against = {});

// True when the file starts with the .pstream magic.
bool is_pstream_file(const std::string& file);
// Throws pstream::Error saying "cook it first" when `file` is an Alembic archive or a PLY file
// given where a cooked .pstream is wanted.
void require_cooked(const std::string& file);

struct BenchReadOptions {
  std::string file;
  std::string object;  // empty: the points object with the most data
  int repetitions = 15;
  bool json = false;
};
int bench_read(const BenchReadOptions& options);

// `pstream cook`: options as typed on the command line, converted by run_cook.
struct CookCli {
  std::string input, output, object, scale_from = "widths", color_from = "auto", attributes, chunk_size = "2MiB",
                                     codec = "particle", frames, error = "1e-4", scale_error = "1%",
                                     attribute_error = "1e-3";
  bool no_velocity = false;
  bool store_velocity = false;
  bool merge = false, no_xforms = false, interpolate = false, drop_invalid = false, keep_order = false, quiet = false,
       json = false;
  double fps = 0.0;
  std::uint64_t max_particles = 64ull << 20;
  unsigned threads = 0;
  std::uint32_t keyframe_interval = 64;
  std::uint64_t max_frames = 100'000;
};
int run_cook(const CookCli& cli);

struct BenchCookOptions {
  std::string file;
  int repetitions = 7;
  bool json = false;
};
int bench_cook(const BenchCookOptions& options);

struct BenchSortOptions {
  std::size_t n = 0;  // 0: the whole table (1k .. 4M, three inputs)
  int repetitions = 7;
  bool json = false;
  std::string svg, markdown;  // optional plot and table files
};
int bench_sort(const BenchSortOptions& options);

struct BenchStreamOptions {
  std::string file;  // empty: generate a clip in a temporary folder
  std::uint64_t particles = 1u << 20, frames = 60;
  double fps = 30.0, cache_seconds = 0.5, laps = 2.0;
  std::string codec = "records";  // of the generated clip: records (raw chunks) or particle
  bool json = false;
};
int bench_stream(const BenchStreamOptions& options);

struct BenchPlaybackOptions {
  std::string file;                      // empty: generate clips with velocities and ids in a temporary folder
  std::vector<std::uint64_t> particles;  // generated clips' sizes; empty: 100k, 1M and 4M
  std::vector<std::string> paths;        // "gpu", "cpu"; empty: both
  std::uint64_t frames = 3;
  double host_hz = 120.0;
  bool json = false;
};
int bench_playback(const BenchPlaybackOptions& options);

// The sprite look's flags, shared by render and play, in the CLI's words: --preset first, then
// each flag given on the command line over it (look_style()).
struct LookCli {
  std::string preset, color_by, ramp, ramp_range, ramp_attribute, tone_map, tint;
  bool flat = false, tint_clips = false, bounds_box = false;
  render::SpriteStyle sprites;     // the numbers and switches, bound to their flags
  std::vector<std::string> given;  // the flags on the command line
  bool has(std::string_view flag) const;
};
// The style `cli` asks for over `base` (a preset's, or the defaults); checks every value.
void apply_look(const LookCli& cli, playback::DrawStyle& style);
// Without --ramp-range, a speed or attribute ramp spans what the clips hold (playback::ramp_range).
void auto_ramp_range(const LookCli& cli, playback::DrawStyle& style, std::span<const std::filesystem::path> files);

struct RenderCli {
  std::vector<std::string> files;  // drawn together (merged depth order; one liquid surface)
  std::string out = "frames", frames, size = "1280x720", camera = "auto", video, blend = "alpha", sort = "back",
              texture, interpolation = "hermite", look = "sprites", backdrop = "auto";
  std::string playback = "gpu";  // where interpolation and sorting run: gpu (compute shaders) or cpu
  std::string liquid_filter, liquid_output, liquid_color;  // empty: the library's defaults
  render::LiquidStyle liquid;                              // the numbers, bound to their flags
  LookCli sprite_look;
  double fps = 0.0, speed = 1.0;
  float size_multiplier = 1.0f;
  bool quiet = false, no_clobber = false;
  bool json = false;  // print {"frames", "frame_ms": {median, p95}, "gl_renderer", ...} instead of the summary
  std::uint64_t max_frames = 100'000;  // more images than this are refused (a mistyped --fps)
};
struct RenderStats {
  std::vector<double> frame_ms;  // each frame's draw + read-back (PNG writing excluded)
  std::string gl_renderer;
  std::uint64_t first_number = 0;  // the first image's number (frame_NNNNN.png): its source frame
};
int run_render(const RenderCli& cli, RenderStats* stats = nullptr);

struct ViewerCli {
  std::vector<std::string> files;
  int width = 1280, height = 720;
  int frames_to_run = 0;   // > 0: quit after that many frames (scripted runs, tests)
  std::string screenshot;  // with frames_to_run: save the last frame (PNG)
  bool hide_ui = false;    // no panel and no timeline (clean screenshots; H toggles them)
  std::string look;        // sprites or liquid; empty: sprites
  std::string playback = "gpu";
  LookCli sprite_look;
};
int run_viewer(const ViewerCli& cli);

struct DemoCli {
  std::string preset = "fountain", out = "demo", size = "960x540", playback = "gpu";
  std::uint64_t particles = 250000;
  double seconds = 10.0, fps = 30.0;
  std::uint64_t seed = 1;
  bool window = false, headless = false, quiet = false;
};
int run_demo(const DemoCli& cli);

struct BenchCodecOptions {
  std::string file, object;
  std::vector<std::string> codecs;  // empty: all
  int zstd_level = 0;               // the particle codec's; 0: its default
  std::string error = "1e-4";       // the position bound (cook --error's syntax), for every lossy codec
  std::string scale_error = "1%";   // the scale's bound, relative to each particle's own (cook --scale-error)
  std::string svg;                  // optional plot: bytes per particle against decode speed
  std::uint64_t frames = 0;         // 0: all
  int repetitions = 5;
  bool json = false;
};
int bench_codec(const BenchCodecOptions& options);

// `pstream export`: a cooked clip as a PLY sequence (out) or an Alembic file (output).
struct ExportCli {
  std::string file, out, output, frames;
  bool quiet = false, json = false;
};
int run_export(const ExportCli& cli);

struct BenchRenderOptions {
  int repetitions = 3;
  bool json = false;
  std::string size = "1280x720";
};
// "WIDTHxHEIGHT" (render_command.cpp); throws pstream::Error naming --size.
void parse_size(const std::string& text, int& width, int& height);
int bench_render(const BenchRenderOptions& options);

struct BenchAllOptions {
  std::string out = "docs/benchmarks.md";
};
int bench_all(const BenchAllOptions& options);

}  // namespace pstream::app
