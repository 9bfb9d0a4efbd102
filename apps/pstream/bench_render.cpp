// `pstream bench render`: per-frame cost of drawing 100k and 1M particles (1280x720 unless
// --size): instanced quads (additive sprites) against GL points and against the screen-space
// liquid, as ratios to the sprites measured in the same run; the liquid with and without its
// shadow on a ground, and alpha-blended sprites with and without self-shadowing (32 half-angle
// slices, the ground's shadow), each as the ratio of the two.
// With the GL renderer's name (llvmpipe here, a GPU where there is one).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <random>
#include <string_view>

#include <epoxy/gl.h>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "commands.hpp"
#include "particlestream/render.hpp"
#include "particlestream/sort.hpp"

namespace pstream::app {

int bench_render(const BenchRenderOptions& o) {
  using Clock = std::chrono::steady_clock;
  int width = 1280, height = 720;
  parse_size(o.size, width, height);
  render::HeadlessContext context(width, height);
  nlohmann::ordered_json results = nlohmann::ordered_json::array();
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> uni(-1.0f, 1.0f);
  for (std::uint64_t n : {std::uint64_t{100000}, std::uint64_t{1} << 20}) {
    std::vector<float> records(n * 4);
    for (std::uint64_t i = 0; i < n; ++i) {
      records[i * 4] = uni(rng), records[i * 4 + 1] = uni(rng), records[i * 4 + 2] = uni(rng),
                  records[i * 4 + 3] = 0.004f;
    }
    double sprites_ms = 0, alpha_ms = 0, liquid_ms = 0;
    sort::DepthSorter sorter(n);
    for (const char* method : {"instanced_quads", "points", "liquid", "liquid_shadowed", "alpha", "alpha_shadowed"}) {
      const std::string_view m = method;
      const bool points = m == "points", liquid = m.starts_with("liquid"), alpha = m.starts_with("alpha");
      const bool shadowed = m.ends_with("_shadowed");
      render::RendererOptions ro;
      ro.max_bytes_per_frame = n * 16;
      ro.points = points;
      render::Renderer renderer(ro);
      render::Camera camera;
      camera.eye = {0, 0, 3.5f};
      render::ParticleBatch b;
      b.first = std::as_bytes(std::span(records));
      b.count = n;
      b.blend = alpha ? render::BlendMode::Alpha : render::BlendMode::Additive;
      render::SpriteStyle style;
      style.shadows = shadowed;
      style.bounds = {-1, -1, -1, 1, 1, 1};
      style.ground_height = -1.0f;
      render::LiquidStyle liquid_style;  // its shadow needs a ground, as the sprites' does
      liquid_style.bounds = style.bounds;
      if (shadowed) liquid_style.ground_height = style.ground_height;
      if (alpha) {  // sorted once, outside the timing: this measures drawing
        const render::Mat4 view =
            shadowed ? render::half_angle(camera.view(), ro.light_direction).sort_view : camera.view();
        b.order = sorter.sort(reinterpret_cast<const std::byte*>(records.data()), n, 16, view,
                              shadowed ? sort::SortMode::FrontToBack : sort::SortMode::BackToFront);
      }
      std::vector<double> ms;
      for (int r = 0; r < o.repetitions + 1; ++r) {
        const auto t0 = Clock::now();
        context.bind();
        renderer.begin_frame(width, height, camera, {0, 0, 0, 1});
        if (liquid) {
          renderer.draw_liquid({&b, 1}, liquid_style);
        } else {
          renderer.draw(b, style);
        }
        renderer.end_frame();
        glFinish();
        if (r > 0)
          ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());  // first warms up
      }
      std::sort(ms.begin(), ms.end());
      const double median = ms[ms.size() / 2];
      if (!points && !liquid && !alpha) sprites_ms = median;
      if (alpha && !shadowed) alpha_ms = median;
      if (liquid && !shadowed) liquid_ms = median;
      const double unshadowed_ms = liquid ? liquid_ms : alpha_ms;
      nlohmann::ordered_json r{{"particles", n},
                               {"method", method},
                               {"frame_ms_median", median},
                               {"ratio_to_sprites", sprites_ms > 0 ? median / sprites_ms : 0.0}};
      if (shadowed) {
        r["ratio_to_unshadowed"] = unshadowed_ms > 0 ? median / unshadowed_ms : 0.0;
        r["shadow_overhead_ms"] = median - unshadowed_ms;
      }
      results.push_back(r);
    }
  }
  nlohmann::ordered_json j{
      {"gl_renderer", render::Renderer::gl_renderer()}, {"width", width}, {"height", height}, {"results", results}};
  if (o.json) {
    fmt::print("{}\n", j.dump());
  } else {
    fmt::print("{} at {}x{}\n", j["gl_renderer"].get<std::string>(), width, height);
    for (const auto& r : results) {
      fmt::print("  {:>8} particles  {:<16} {:9.2f} ms a frame  {:5.2f}x sprites{}\n",
                 r["particles"].get<std::uint64_t>(), r["method"].get<std::string>(),
                 r["frame_ms_median"].get<double>(), r["ratio_to_sprites"].get<double>(),
                 r.contains("ratio_to_unshadowed")
                     ? fmt::format("  {:5.2f}x without shadows", r["ratio_to_unshadowed"].get<double>())
                     : "");
    }
  }
  return 0;
}

}  // namespace pstream::app
