// `pstream render FILE.pstream --out DIR`: headless rendering of a clip to PNG frames (and an MP4
// through ffmpeg): stream (blocking, no frame skipped) -> sort back to front -> draw.
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <sstream>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "base/names.hpp"
#include "base/output_file.hpp"
#include "cli_terms.hpp"
#include "commands.hpp"
#include "particlestream/format.hpp"
#include "particlestream/playback.hpp"
#include "particlestream/render.hpp"
#include "particlestream/sort.hpp"
#include "particlestream/stream.hpp"
#include "process.hpp"
#include "progress.hpp"
#include "stats.hpp"

namespace pstream::app {
namespace {

render::Vec3 parse_vec3(const std::string& text) {
  render::Vec3 v{};
  std::istringstream in(text);
  char comma = 0;
  if (!(in >> v[0] >> comma >> v[1] >> comma >> v[2])) throw Error(fmt::format("'{}': expected x,y,z", text));
  return v;
}

}  // namespace

// --camera: auto (the library's framing track, as the viewer and the demo use it, over the clip
// seconds rendered), fixed (the same rule's one camera for every frame) or eye:target.
playback::CameraTrack camera_for(const std::string& spec, std::span<const std::filesystem::path> files, float aspect,
                                 const std::array<double, 2>& seconds) {
  if (spec.empty() || spec == "auto") return playback::framing_track(files, aspect, {0.0f, 0.0f, 1.0f, 1.0f}, seconds);
  if (spec == "fixed") {
    playback::CameraTrack one;
    one.keys.push_back({0.0, playback::framing_camera(files, aspect, {0.0f, 0.0f, 1.0f, 1.0f}, seconds)});
    return one;
  }
  const auto colon = spec.find(':');
  if (colon == std::string::npos) {
    throw Error(fmt::format("--camera '{}': expected auto, fixed or x,y,z:tx,ty,tz{}", spec,
                            did_you_mean(spec, {"auto", "fixed"})));
  }
  playback::CameraTrack track;
  track.keys.push_back(
      {0.0, render::Camera::looking(parse_vec3(spec.substr(0, colon)), parse_vec3(spec.substr(colon + 1)))});
  return track;
}

void parse_size(const std::string& text, int& width, int& height) {
  if (std::sscanf(text.c_str(), "%dx%d", &width, &height) != 2 || width <= 0 || height <= 0) {
    throw Error(fmt::format("--size '{}': expected WIDTHxHEIGHT, e.g. 1280x720", text));
  }
}

bool LookCli::has(std::string_view flag) const { return std::find(given.begin(), given.end(), flag) != given.end(); }

void apply_look(const LookCli& cli, playback::DrawStyle& style) {
  const bool all = cli.preset.empty();  // no preset: every flag's value, given or default
  const auto set = [&](std::string_view flag) { return all || cli.has(flag); };
  render::SpriteStyle& s = style.sprites;
  const render::SpriteStyle& c = cli.sprites;
  if (set("--shadows")) s.shadows = c.shadows;
  if (set("--slices")) s.slices = c.slices;
  if (set("--shadow-density")) s.shadow_density = c.shadow_density;
  if (set("--shutter")) s.shutter = c.shutter;
  if (set("--exposure")) s.exposure = c.exposure;
  if (set("--bloom")) s.bloom = c.bloom;
  if (set("--bloom-radius")) s.bloom_radius = c.bloom_radius;
  if (set("--opacity")) s.opacity = c.opacity;
  if (set("--min-pixels")) s.min_pixels = c.min_pixels;
  if (set("--flat")) s.lit = !cli.flat;
  if (cli.tint_clips) style.clip_tints = playback::DrawStyle::distinct_tints();
  if (cli.bounds_box) style.bounds_box = true;
  playback::Colouring colouring{cli.color_by, cli.ramp, std::nullopt, cli.ramp_attribute};
  if (!cli.ramp_range.empty()) {
    float low = 0.0f, high = 0.0f;
    if (std::sscanf(cli.ramp_range.c_str(), "%f,%f", &low, &high) != 2 || !(low < high))
      throw Error(fmt::format("--ramp-range '{}': expected LOW,HIGH with LOW < HIGH", cli.ramp_range));
    colouring.range = {low, high};
  }
  playback::apply_colouring(colouring, style);
  if (!cli.tone_map.empty()) s.tone_map = render::parse_tone_map(cli.tone_map);
  if (!cli.tint.empty()) {
    const render::Vec3 t = parse_vec3(cli.tint);
    for (float v : t) {
      if (!(v >= 0.0f && v <= 4.0f)) throw Error(fmt::format("--tint '{}': expected r,g,b in [0, 4]", cli.tint));
    }
    s.tint = {t[0], t[1], t[2], 1.0f};
  }
}

void auto_ramp_range(const LookCli& cli, playback::DrawStyle& style, std::span<const std::filesystem::path> files) {
  render::SpriteStyle& s = style.sprites;
  if (!cli.ramp_range.empty() || s.color_by == render::ColorBy::Stored) return;
  const std::array<float, 2> r =
      playback::ramp_range(files, s.color_by == render::ColorBy::Attribute ? style.ramp_attribute : std::string());
  s.ramp.low = r[0];
  s.ramp.high = r[1];
}

// The look flags in the library's terms.
playback::DrawStyle draw_style(const RenderCli& cli, const std::array<float, 6>& bounds) {
  const LookCli& look = cli.sprite_look;
  playback::DrawStyle style = look.preset.empty() ? playback::DrawStyle{} : playback::look_preset(look.preset);
  if (look.preset.empty() || look.has("--look")) style.look = render::parse_look(cli.look);
  if (look.preset.empty() || look.has("--blend")) style.blend = render::parse_blend(cli.blend);
  apply_look(look, style);
  style.size_multiplier = cli.size_multiplier;
  style.texture = cli.texture;
  style.liquid = cli.liquid;
  render::LiquidStyle& l = style.liquid;
  if (!cli.liquid_filter.empty()) l.filter = render::parse_liquid_filter(cli.liquid_filter);
  if (!cli.liquid_output.empty()) l.output = render::parse_liquid_output(cli.liquid_output);
  if (!cli.liquid_color.empty()) {
    const render::Vec3 c = parse_vec3(cli.liquid_color);
    for (float v : c) {
      if (!(v > 0.0f && v <= 1.0f))
        throw Error(fmt::format("--liquid-color '{}': expected three values in (0, 1]", cli.liquid_color));
    }
    l.color = c;
  }
  style.backdrop = playback::backdrop_for(cli.backdrop, style, bounds);
  return style;
}

int run_render(const RenderCli& cli, RenderStats* stats) {
  int width = 0, height = 0;
  parse_size(cli.size, width, height);
  if (cli.files.empty()) throw Error("render: no clip given");
  playback::PlayerOptions options;
  options.stream.blocking = true;  // offline: wait for every frame instead of skipping
  options.loop = false;
  options.interpolation = playback::parse_interpolation(cli.interpolation);
  options.path = playback::parse_playback_path(cli.playback);
  const std::vector<std::filesystem::path> files(cli.files.begin(), cli.files.end());
  const auto player = playback::Player::open(files, std::move(options));
  // The first clip's frames number the render (--frames); the camera frames every clip.
  const format::Metadata& m = player->clip(0).metadata();
  if (m.frame_count() == 0) throw Error(fmt::format("{}: the clip has no frames", cli.files[0]));
  std::array<float, 6> bounds = m.bounds;
  for (std::size_t c = 1; c < player->clip_count(); ++c) {
    const auto& b = player->clip(c).metadata().bounds;
    for (int i = 0; i < 3; ++i) {
      bounds[std::size_t(i)] = std::min(bounds[std::size_t(i)], b[std::size_t(i)]);
      bounds[std::size_t(i) + 3] = std::max(bounds[std::size_t(i) + 3], b[std::size_t(i) + 3]);
    }
  }
  playback::DrawStyle style = draw_style(cli, bounds);  // flags checked before anything is written
  player->check_style(style);
  auto_ramp_range(cli.sprite_look, style, files);
  std::int64_t first = 0, last = std::int64_t(m.frame_count());
  if (!cli.frames.empty()) {
    const auto [a, b] = parse_frame_range(cli.frames);
    first = a;
    if (b >= 0) last = std::min(last, b);
  }
  if (first >= last) {
    throw Error(fmt::format("--frames {}: selects no frames; the clip has {} (0:{})", cli.frames, m.frame_count(),
                            m.frame_count()));
  }
  const double fps = cli.fps > 0 ? cli.fps : m.fps;
  const double t0 = m.frames[std::size_t(first)].time, t1 = m.frames[std::size_t(last - 1)].time;
  // Kept as a double until it is known to be in range (times are validated finite and increasing).
  const double images = std::floor((t1 - t0) / cli.speed * fps + 1e-6) + 1;
  if (!(images <= double(cli.max_frames))) {
    throw Error(
        fmt::format("{}: rendering {:g} s at {:g} fps makes {:.0f} images, more than --max-frames {}; "
                    "choose a lower --fps or --frames, or raise --max-frames",
                    cli.files[0], (t1 - t0) / cli.speed, fps, images, cli.max_frames));
  }
  const auto outputs = static_cast<std::uint64_t>(images);
  // Images are numbered by source frame: the first is the frame at its time on the output's own
  // timeline (fps / speed frames a clip second), so a Blender cache from frame 1 renders from
  // frame_00001.png and --frames 10:20 from frame_00010.png (at the clip's rate). Numbers that
  // would not fit five digits, or fall before 0, start at 0.
  const double first_at = std::round(t0 * fps / cli.speed);
  const std::uint64_t first_number =
      first_at >= 0.0 && first_at + double(outputs) <= 99999.0 ? static_cast<std::uint64_t>(first_at) : 0;
  if (stats) stats->first_number = first_number;

  // Every output checked before the first frame: the folder, its old frames, the video.
  namespace fs = std::filesystem;
  if (fs::exists(cli.out) && !fs::is_directory(cli.out))
    throw Error(fmt::format("--out {}: exists and is not a folder", cli.out));
  std::vector<fs::path> inputs(files.begin(), files.end());
  if (!cli.video.empty()) {
    check_output(cli.video, inputs);
    if (!have_program("ffmpeg")) {
      throw Error(
          fmt::format("--video {}: writing a video needs the ffmpeg program, which is not installed "
                      "(apt-get install ffmpeg)",
                      cli.video));
    }
  }
  // Frames of an earlier render in the folder (our names, frame_NNNNN.png): replaced, and those
  // past this render's last removed, so the folder holds exactly this render; --no-clobber refuses.
  std::vector<fs::path> old_frames;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(cli.out, ec)) {
    const std::string name = e.path().filename().string();
    if (name.size() == 15 && name.starts_with("frame_") && name.ends_with(".png") &&
        std::all_of(name.begin() + 6, name.begin() + 11, [](char c) { return c >= '0' && c <= '9'; }))
      old_frames.push_back(e.path());
  }
  if (!old_frames.empty() && cli.no_clobber) {
    throw Error(
        fmt::format("--out {}: holds {} frames of an earlier render (frame_NNNNN.png); without "
                    "--no-clobber they are replaced",
                    cli.out, old_frames.size()));
  }
  fs::create_directories(cli.out);
  {
    // The folder takes files (permissions): a temporary made and removed (never committed).
    const OutputFile probe = OutputFile::create(fs::path(cli.out) / "frame_probe.png");
  }
  std::uint64_t removed = 0;
  for (const fs::path& f : old_frames) {
    const std::uint64_t number = std::stoull(f.filename().string().substr(6, 5));
    const bool ours = number >= first_number && number < first_number + outputs;  // overwritten in turn
    if (!ours && fs::remove(f, ec)) ++removed;
  }
  if (removed > 0 && !cli.quiet)
    fmt::print(stderr, "removed {} frames of an earlier render from {}\n", removed, cli.out);
  render::HeadlessContext context(width, height);
  render::RendererOptions ro;
  ro.max_bytes_per_frame = std::max<std::uint64_t>(player->max_frame_bytes(), 4096);
  render::Renderer renderer(ro);
  const playback::CameraTrack track = camera_for(cli.camera, files, float(width) / float(height), {t0, t1});
  const sort::SortMode sort_mode = sort::parse_sort_mode(cli.sort);

  if (stats) stats->gl_renderer = render::Renderer::gl_renderer();
  player->set_range(t0, t1);
  player->seek(t0);
  player->set_speed(cli.speed);
  player->play();
  ProgressBar bar("render", !cli.quiet && !cli.json);
  std::vector<double> frame_ms;
  for (std::uint64_t k = 0; k < outputs; ++k) {
    // The camera at the time this frame shows (the playhead after the advance), and the sort
    // for it: the track only moves the camera along its view, but the plan is cheap.
    const double shown = k == 0 ? t0 : std::min(t1, t0 + double(k) / fps * cli.speed);
    const render::Camera camera = track.at(shown);
    const playback::SortPlan plan = playback::sort_plan(style, camera.view(), renderer.light_direction(), sort_mode);
    player->advance(k == 0 ? 0.0 : 1.0 / fps, plan.view, plan.mode);
    player->check();
    const auto start = std::chrono::steady_clock::now();
    context.bind();
    renderer.begin_frame(width, height, camera, render::kDefaultBackground);
    renderer.draw(player->draw_data(style));
    renderer.end_frame();
    const std::vector<std::uint8_t> pixels = context.read_rgba();
    frame_ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
    if (stats) stats->frame_ms.push_back(frame_ms.back());
    render::write_png(std::filesystem::path(cli.out) / fmt::format("frame_{:05d}.png", first_number + k), width, height,
                      pixels);
    bar.update(k + 1, outputs, fmt::format("frames ({}x{})", width, height));
  }
  if (cli.json) {
    const nlohmann::ordered_json j = {
        {"frames", outputs},
        {"out", cli.out},
        {"size", {width, height}},
        {"gl_renderer", render::Renderer::gl_renderer()},
        {"frame_ms", {{"median", percentile(frame_ms, 0.5)}, {"p95", percentile(frame_ms, 0.95)}}}};
    fmt::print("{}\n", j.dump());
  } else if (!cli.quiet) {
    const std::string files = outputs == 1 ? fmt::format("frame_{:05d}.png", first_number) : "frame_NNNNN.png";
    fmt::print("{} -> {}/{} ({})\n", count_of(outputs, "frame"), cli.out, files, render::Renderer::gl_renderer());
  }
  if (!cli.video.empty()) {
    encode_video(cli.out, first_number, outputs, fps, cli.video);  // no shell; exactly this render's frames
    if (!cli.quiet && !cli.json) fmt::print("video -> {}\n", cli.video);
  }
  return 0;
}

}  // namespace pstream::app
