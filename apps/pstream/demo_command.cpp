// `pstream demo`: the whole pipeline on a built-in simulation — simulate, write Alembic, cook,
// stream in real time (as a game would), sort, render headless — with a report of every stage.
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <sstream>
#include <thread>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "base/output_file.hpp"
#include "commands.hpp"
#include "particlestream/alembic_writer.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/demo.hpp"
#include "particlestream/playback.hpp"
#include "particlestream/render.hpp"
#include "particlestream/sort.hpp"
#include "particlestream/stream.hpp"
#include "process.hpp"
#include "progress.hpp"

namespace pstream::app {

namespace {

using Clock = std::chrono::steady_clock;
using json = nlohmann::ordered_json;

double ms_since(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

json percentiles(std::vector<double> v) {
  if (v.empty()) return json{{"median", nullptr}, {"p99", nullptr}};
  std::sort(v.begin(), v.end());
  return json{{"median", v[v.size() / 2]}, {"p99", v[std::min(v.size() - 1, v.size() * 99 / 100)]}};
}

// The contact sheet: one image of each preset at the moment that shows it best, side by side,
// each shrunk by averaging 2x2 pixel blocks.
void contact_sheet(const std::vector<std::filesystem::path>& tiles, const std::filesystem::path& out) {
  constexpr int kShrink = 2;
  int w = 0, h = 0;
  render::read_png(tiles.front(), w, h);
  const int tw = w / kShrink, th = h / kShrink, columns = int(tiles.size());
  std::vector<std::uint8_t> sheet(std::size_t(tw) * columns * th * 4, 255);
  for (int k = 0; k < columns; ++k) {
    int fw = 0, fh = 0;
    const auto img = render::read_png(tiles[std::size_t(k)], fw, fh);
    if (fw != w || fh != h)
      throw Error(fmt::format("{}: {}x{}, expected {}x{}", tiles[std::size_t(k)].string(), fw, fh, w, h));
    for (int y = 0; y < th; ++y) {
      for (int x = 0; x < tw; ++x) {
        for (int c = 0; c < 4; ++c) {
          int sum = 0;
          for (int dy = 0; dy < kShrink; ++dy) {
            for (int dx = 0; dx < kShrink; ++dx)
              sum += img[(std::size_t(y * kShrink + dy) * fw + x * kShrink + dx) * 4 + c];
          }
          sheet[(std::size_t(y) * tw * columns + k * tw + x) * 4 + c] = std::uint8_t(sum / (kShrink * kShrink));
        }
      }
    }
  }
  render::write_png(out, tw * columns, th, sheet);
}

// Each simulation in the look that reads as what it is, and what its render adds to the look.
// `peak`: the clip's peak particle count.
void preset_render(const std::string& preset, std::uint64_t peak, RenderCli& rc) {
  LookCli look;
  if (preset == "explosion") {
    look.preset = "sparks";  // additive, glowing streaks
  } else if (preset == "smoke") {
    look.preset = "smoke";  // self-shadowed, shadows on the ground
  } else {
    look.preset = "sprites";  // small droplets streaked along their arcs, over a ground
    look.sprites.shutter = 1.0f / 30;
    look.given = {"--shutter"};
    // Droplets thinner as there are more of them, so that the spray's cover stays about the same:
    // at 250,000 the fountain's curtain of drops would read as a solid sheet at 20,000's size.
    rc.size_multiplier = 0.45f * std::clamp(std::cbrt(20000.0f / float(std::max<std::uint64_t>(peak, 1))), 0.4f, 1.0f);
    rc.backdrop = "ground";
  }
  rc.sprite_look = look;
}

// One image of `preset`'s `clip` (its frame `frame`, framed alone) in the preset's look, rendered
// into DIR/PRESET/; the image's path.
std::filesystem::path showcase_image(const DemoCli& cli, const std::string& preset, std::uint64_t peak,
                                     const std::filesystem::path& clip, std::uint64_t frame,
                                     const std::filesystem::path& dir) {
  RenderCli rc;
  preset_render(preset, peak, rc);
  rc.files = {clip.string()};
  rc.frames = fmt::format("{}:{}", frame, frame + 1);
  rc.out = (dir / preset).string();
  rc.size = cli.size;
  rc.quiet = true;
  rc.playback = cli.playback;
  RenderStats rs;
  run_render(rc, &rs);
  return dir / preset / fmt::format("frame_{:05d}.png", rs.first_number);
}

// `preset` at `seconds` of its simulation (at most `particles` of them), simulated up to that frame,
// that frame cooked from memory into DIR/PRESET.pstream, and its image.
std::filesystem::path showcase(const DemoCli& cli, const std::string& preset, std::uint64_t particles, double seconds,
                               const std::filesystem::path& dir) {
  const double frames = std::floor(seconds * cli.fps + 0.5) + 1;
  demo::Simulator sim({preset, particles, frames / cli.fps, cli.fps, cli.seed, 0});
  std::uint64_t peak = 0;
  for (std::uint64_t f = 0; f < sim.frame_count(); ++f) {
    sim.step();
    peak = std::max<std::uint64_t>(peak, sim.state().size());
  }
  const demo::ParticleState& s = sim.state();
  cook::MemoryClip clip;
  clip.name = fmt::format("pstream demo --preset {}", preset);
  clip.object = preset;
  clip.fps = cli.fps;
  clip.frames.push_back({sim.time(), s.size(), s.position, s.width, s.velocity, s.id, s.color, {}});
  cook::Options co;
  co.output = dir / (preset + ".pstream");
  cook::cook(co, clip);
  return showcase_image(cli, preset, peak, co.output, 0, dir);
}

}  // namespace

int run_demo(const DemoCli& cli) {
  namespace fs = std::filesystem;
  const fs::path dir = cli.out;
  fs::create_directories(dir);
  json report{{"preset", cli.preset}, {"particles_target", cli.particles}, {"seconds", cli.seconds}, {"fps", cli.fps}};
  const auto say = [&](const std::string& s) {
    if (!cli.quiet) fmt::print("{}\n", s);
  };

  // 1. Simulate, writing every frame to Alembic as a studio's exporter would.
  demo::Simulator sim({cli.preset, cli.particles, cli.seconds, cli.fps, cli.seed, 0});
  const fs::path abc = dir / "demo.abc";
  double sim_ms = 0, write_ms = 0;
  std::uint64_t peak = 0;
  {
    alembic::PointsWriterOptions po;
    po.name = cli.preset;
    po.velocities = true;  // as a studio's exporter writes them: motion blur and speed colours need them
    po.float_params = {{"Cd", 4}};
    alembic::ArchiveWriter writer(abc, "pstream demo", fmt::format("pstream demo --preset {}", cli.preset), cli.fps,
                                  1.0 / cli.fps, po);
    ProgressBar bar("simulate", !cli.quiet);
    const std::uint64_t frames = sim.frame_count();
    for (std::uint64_t f = 0; f < frames; ++f) {
      auto t0 = Clock::now();
      sim.step();
      sim_ms += ms_since(t0);
      const demo::ParticleState& s = sim.state();
      peak = std::max<std::uint64_t>(peak, s.size());
      alembic::PointsSample sample;
      sample.positions = s.position;
      sample.ids = s.id;
      sample.widths = s.width;
      sample.velocities = s.velocity;
      sample.params = {s.color};
      t0 = Clock::now();
      writer.write_sample(sample);
      write_ms += ms_since(t0);
      bar.update(f + 1, frames, fmt::format("frames, {} particles", s.size()));
    }
    const auto t0 = Clock::now();
    writer.close();
    write_ms += ms_since(t0);
  }
  report["simulation"] = {{"frames", sim.frame_count()},
                          {"peak_particles", peak},
                          {"sim_ms", sim_ms},
                          {"abc_write_ms", write_ms},
                          {"abc_bytes", fs::file_size(abc)}};
  say(fmt::format("simulated {} frames, peak {} particles: {:.1f} s; {} ({:.1f} MiB) in {:.1f} s", sim.frame_count(),
                  peak, sim_ms / 1000, abc.string(), fs::file_size(abc) / 1048576.0, write_ms / 1000));

  // 2. Cook.
  cook::Options co;
  co.input = abc;
  co.output = dir / "demo.pstream";
  co.frame_codec = format::FrameCodec::Particle;  // error-bounded, predicted over time
  co.particle.zstd_level = 9;  // the demo's time budget: ~5x faster cook than the default 16, ~9% larger
  const cook::Report cr = cook::cook(co, CookProgress("cook", !cli.quiet));
  const double per_particle = cr.particles ? double(cr.file_bytes) / double(cr.particles) : 0.0;
  report["cook"] = {{"ms", cr.seconds * 1000},
                    {"codec", "particle"},
                    {"pstream_bytes", cr.file_bytes},
                    {"record_stream_bytes", cr.stream_bytes},
                    {"compression_ratio", double(cr.stream_bytes) / double(cr.file_bytes)},
                    {"bytes_per_particle", per_particle},
                    {"error_bound", cr.error},
                    {"keyframes", cr.keyframes},
                    {"chunks", cr.chunks}};
  say(
      fmt::format("cooked {} ({:.1f} MiB, {:.2f}x, {:.2f} bytes per particle per frame, positions within {:.3g}) in "
                  "{:.1f} s",
                  co.output.string(), cr.file_bytes / 1048576.0, double(cr.stream_bytes) / double(cr.file_bytes),
                  per_particle, cr.error, cr.seconds));

  // Each simulation in the look that reads as what it is.
  RenderCli rc;
  preset_render(cli.preset, peak, rc);
  const bool window = cli.window || (!cli.headless && std::getenv("DISPLAY") != nullptr);
  if (window) {
    say("opening the viewer (use --headless to render frames instead)");
    ViewerCli viewer;
    viewer.files = {co.output.string()};
    viewer.sprite_look = rc.sprite_look;
    viewer.playback = cli.playback;
    return run_viewer(viewer);
  }

  // 3. Stream in real time, as a game would (never blocking), and sort every frame.
  std::vector<double> stream_ms, sort_ms;
  std::uint64_t stalls = 0, cache_bytes = 0;
  {
    // The library's playback layer, as a game would use it: never blocking, sorted every frame.
    const std::filesystem::path files[] = {co.output};
    const auto player = playback::Player::open(files);
    const format::Metadata& m = player->clip(0).metadata();
    const render::Camera camera = playback::framing_camera(files, 16.0f / 9.0f);
    player->set_loop(false);
    player->play();
    const double dt = 1.0 / m.fps;
    auto tick = Clock::now();
    ProgressBar bar("stream + sort (real time)", !cli.quiet);
    for (std::uint64_t k = 0; k < m.frame_count(); ++k) {
      tick += std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(dt));
      std::this_thread::sleep_until(tick);
      const playback::FrameStats& s = player->advance(k == 0 ? 0.0 : dt, camera.view(), sort::SortMode::BackToFront);
      player->check();
      stream_ms.push_back(s.stream_ms);
      sort_ms.push_back(s.sort_ms);
      bar.update(k + 1, m.frame_count(), "frames");
    }
    stalls = player->clip(0).debug().stalls;
    cache_bytes = player->clip(0).debug().cache_bytes;
  }
  report["stream"] = {{"frame_ms", percentiles(stream_ms)}, {"stalls", stalls}, {"cache_bytes", cache_bytes}};
  report["sort"] = {{"frame_ms", percentiles(sort_ms)}};

  // 4. Render headless (blocking stream: no frame skipped), then the MP4 and the contact sheet.
  rc.files = {co.output.string()};
  rc.out = (dir / "frames").string();
  rc.size = cli.size;
  rc.quiet = cli.quiet;
  rc.playback = cli.playback;
  const bool have_ffmpeg = have_program("ffmpeg");
  if (have_ffmpeg) rc.video = (dir / "demo.mp4").string();
  fs::remove_all(rc.out);
  RenderStats rs;
  const auto r0 = Clock::now();
  run_render(rc, &rs);
  const std::vector<double>& render_ms = rs.frame_ms;
  report["render"] = {{"frame_ms", percentiles(render_ms)},
                      {"total_ms", ms_since(r0)},
                      {"frames", render_ms.size()},
                      {"size", cli.size},
                      {"gl_renderer", rs.gl_renderer}};

  // 5. The contact sheet: each preset at the moment that shows it best (Simulator::showcase_seconds,
  // within the first three quarters of --seconds), each frame framed alone. This run's preset is
  // that frame of its clip; the others are simulated (at most 60,000 particles) up to their moment,
  // cooked from memory into DIR/presets/PRESET.pstream. Images in DIR/presets/PRESET/.
  std::vector<fs::path> tiles;
  fs::remove_all(dir / "presets");  // an earlier run's
  fs::create_directories(dir / "presets");
  {
    ProgressBar bar("contact sheet", !cli.quiet);
    const auto presets = demo::Simulator::presets();
    for (std::size_t k = 0; k < presets.size(); ++k) {
      const std::string& p = presets[k];
      const double at = std::min(demo::Simulator::showcase_seconds(p), 0.75 * cli.seconds);
      if (p == cli.preset) {  // the clip holds every simulated frame
        const auto frame = std::min<std::uint64_t>(sim.frame_count() - 1, std::uint64_t(std::llround(at * cli.fps)));
        tiles.push_back(showcase_image(cli, p, peak, co.output, frame, dir / "presets"));
      } else {
        tiles.push_back(showcase(cli, p, std::min<std::uint64_t>(cli.particles, 60000), at, dir / "presets"));
      }
      bar.update(k + 1, presets.size(), "presets");
    }
  }
  contact_sheet(tiles, dir / "contact_sheet.png");
  if (!have_ffmpeg) say("note: no demo.mp4 — the ffmpeg program is not installed (apt-get install ffmpeg)");

  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  report["peak_rss_bytes"] = std::uint64_t(usage.ru_maxrss) * 1024;
  report["outputs"] = {{"abc", abc.string()},
                       {"pstream", co.output.string()},
                       {"frames", rc.out},
                       {"video", have_ffmpeg ? rc.video : ""},
                       {"contact_sheet", (dir / "contact_sheet.png").string()},
                       {"presets", (dir / "presets").string()}};
  write_file(dir / "report.json", report.dump(2) + "\n");

  const auto med = [&](const char* stage) { return report[stage]["frame_ms"]["median"].get<double>(); };
  const auto p99 = [&](const char* stage) { return report[stage]["frame_ms"]["p99"].get<double>(); };
  std::ostringstream md;
  md << fmt::format("# pstream demo — {}\n\n![contact sheet](contact_sheet.png)\n\n", cli.preset);
  md << "| stage | figure |\n|---|---|\n";
  md << fmt::format("| simulate | {} frames at {:g} fps, peak {} particles, {:.2f} s |\n", sim.frame_count(), cli.fps,
                    peak, sim_ms / 1000);
  md << fmt::format("| write Alembic | {:.1f} MiB in {:.2f} s |\n", fs::file_size(abc) / 1048576.0, write_ms / 1000);
  md << fmt::format(
      "| cook (particle codec) | {:.1f} MiB .pstream, {:.2f}x smaller than the records ({:.2f} bytes per "
      "particle per frame, every position within {:.3g} = 1e-4 of the bounds diagonal; zstd level 9), "
      "{:.2f} s |\n",
      cr.file_bytes / 1048576.0, double(cr.stream_bytes) / double(cr.file_bytes), per_particle, cr.error, cr.seconds);
  md << fmt::format("| stream (real time) | {:.3f} ms median, {:.3f} ms p99 a frame; {} stalls; cache {:.1f} MiB |\n",
                    med("stream"), p99("stream"), stalls, cache_bytes / 1048576.0);
  md << fmt::format("| sort (back to front) | {:.3f} ms median, {:.3f} ms p99 |\n", med("sort"), p99("sort"));
  md << fmt::format("| render {} | {:.1f} ms median, {:.1f} ms p99 ({}) |\n", cli.size, med("render"), p99("render"),
                    rs.gl_renderer);
  md << fmt::format("| peak RSS | {:.0f} MiB (it counts the pages of the memory-mapped Alembic file the cook read) |\n",
                    usage.ru_maxrss / 1024.0);
  md << "\nEvery figure was measured in this run (report.json has them all).\n";
  write_file(dir / "report.md", md.str());
  say(fmt::format("report: {} and {}; frames in {}; contact sheet {}", (dir / "report.md").string(),
                  (dir / "report.json").string(), rc.out, (dir / "contact_sheet.png").string()));
  return 0;
}

}  // namespace pstream::app
