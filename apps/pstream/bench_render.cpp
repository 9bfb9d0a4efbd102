// `pstream bench render`: per-frame cost of drawing 100k and 1M particles at 1280x720, instanced
// quads against GL points, with the GL renderer's name (llvmpipe here, a GPU where there is one).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <random>

#include <epoxy/gl.h>
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "commands.hpp"
#include "particlestream/render.hpp"

namespace pstream::app {

int bench_render(const BenchRenderOptions& o) {
  using Clock = std::chrono::steady_clock;
  render::HeadlessContext context(1280, 720);
  nlohmann::ordered_json results = nlohmann::ordered_json::array();
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> uni(-1.0f, 1.0f);
  for (std::uint64_t n : {std::uint64_t{100000}, std::uint64_t{1} << 20}) {
    std::vector<float> records(n * 4);
    for (std::uint64_t i = 0; i < n; ++i) {
      records[i * 4] = uni(rng), records[i * 4 + 1] = uni(rng), records[i * 4 + 2] = uni(rng),
                  records[i * 4 + 3] = 0.004f;
    }
    for (bool points : {false, true}) {
      render::RendererOptions ro;
      ro.max_bytes_per_frame = n * 16;
      ro.points = points;
      render::Renderer renderer(ro);
      render::Camera camera;
      camera.eye = {0, 0, 3.5f};
      render::ParticleBatch b;
      b.first = std::as_bytes(std::span(records));
      b.count = n;
      b.blend = render::BlendMode::Additive;
      std::vector<double> ms;
      for (int r = 0; r < o.repetitions + 1; ++r) {
        const auto t0 = Clock::now();
        context.bind();
        renderer.begin_frame(1280, 720, camera, {0, 0, 0, 1});
        renderer.draw(b);
        renderer.end_frame();
        glFinish();
        if (r > 0)
          ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());  // first warms up
      }
      std::sort(ms.begin(), ms.end());
      results.push_back({{"particles", n},
                         {"method", points ? "points" : "instanced_quads"},
                         {"frame_ms_median", ms[ms.size() / 2]}});
    }
  }
  nlohmann::ordered_json j{
      {"gl_renderer", render::Renderer::gl_renderer()}, {"width", 1280}, {"height", 720}, {"results", results}};
  if (o.json) {
    fmt::print("{}\n", j.dump());
  } else {
    fmt::print("{} at 1280x720\n", j["gl_renderer"].get<std::string>());
    for (const auto& r : results) {
      fmt::print("  {:>8} particles  {:<16} {:9.2f} ms a frame\n", r["particles"].get<std::uint64_t>(),
                 r["method"].get<std::string>(), r["frame_ms_median"].get<double>());
    }
  }
  return 0;
}

}  // namespace pstream::app
