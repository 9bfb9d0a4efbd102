// `pstream bench sort`: the seed's sorting comparison, every contender on the same key-index
// pairs, medians of several runs, plus a memcpy of the same bytes as the bandwidth yardstick.
#include <epoxy/gl.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <map>
#include <numeric>
#include <optional>
#include <random>
#include <sstream>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "base/output_file.hpp"
#include "commands.hpp"
#include "particlestream/error.hpp"
#include "particlestream/render.hpp"
#include "particlestream/sort.hpp"
#include "progress.hpp"
#include "sort_contenders.hpp"
#include "stats.hpp"

namespace pstream::app {
namespace {

using Clock = std::chrono::steady_clock;

std::vector<float> make_input(const std::string& kind, std::size_t n, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<float> d(n);
  if (kind == "random") {
    std::uniform_real_distribution<float> uni(-1000.0f, 1000.0f);
    for (auto& v : d) v = uni(rng);
  } else if (kind == "nearly_sorted") {  // the next frame of a coherent simulation
    std::normal_distribution<float> jitter(0.0f, 2.0f);
    for (std::size_t i = 0; i < n; ++i)
      d[i] = -1000.0f + 2000.0f * float(i) / float(n) + jitter(rng) * 2000.0f / float(n);
  } else {  // reversed
    for (std::size_t i = 0; i < n; ++i) d[i] = 1000.0f - 2000.0f * float(i) / float(n);
  }
  return d;
}

std::string svg_plot(const std::map<std::string, std::vector<std::pair<double, double>>>& series,
                     const std::string& title) {
  const double W = 760, H = 460, L = 70, R = 170, T = 40, B = 50;
  double xmin = 1e300, xmax = 0, ymin = 1e300, ymax = 0;
  for (const auto& [name, pts] : series) {
    for (auto [x, y] : pts) {
      xmin = std::min(xmin, x), xmax = std::max(xmax, x), ymin = std::min(ymin, std::max(y, 1e-4)),
      ymax = std::max(ymax, y);
    }
  }
  const double lx0 = std::floor(std::log10(xmin)), lx1 = std::ceil(std::log10(xmax));
  const double ly0 = std::floor(std::log10(ymin)), ly1 = std::ceil(std::log10(ymax));
  auto px = [&](double x) { return L + (std::log10(x) - lx0) / (lx1 - lx0) * (W - L - R); };
  auto py = [&](double y) { return H - B - (std::log10(std::max(y, 1e-4)) - ly0) / (ly1 - ly0) * (H - T - B); };
  std::string s = fmt::format(
      R"(<svg xmlns="http://www.w3.org/2000/svg" width="{}" height="{}" font-family="sans-serif" font-size="12">)", W,
      H);
  s += fmt::format(R"(<rect width="100%" height="100%" fill="white"/><text x="{}" y="22" font-size="15">{}</text>)", L,
                   title);
  for (int decade = int(lx0); decade <= int(lx1); ++decade) {
    const double e = decade;
    s += fmt::format(
        R"(<line x1="{0}" y1="{1}" x2="{0}" y2="{2}" stroke="#ddd"/><text x="{0}" y="{3}" text-anchor="middle">{4}</text>)",
        px(std::pow(10, e)), T, H - B, H - B + 18, fmt::format("1e{}", e));
  }
  for (int decade = int(ly0); decade <= int(ly1); ++decade) {
    const double e = decade;
    s += fmt::format(
        R"(<line x1="{0}" y1="{1}" x2="{2}" y2="{1}" stroke="#ddd"/><text x="{3}" y="{4}" text-anchor="end">{5} ms</text>)",
        L, py(std::pow(10, e)), W - R, L - 6, py(std::pow(10, e)) + 4, fmt::format("{:g}", std::pow(10, e)));
  }
  s += fmt::format(R"(<text x="{}" y="{}" text-anchor="middle">particles (N)</text>)", (L + W - R) / 2, H - 12);
  const char* colors[] = {"#999",    "#bbb",    "#8c564b", "#e377c2", "#7f7f7f", "#1f77b4",
                          "#17becf", "#ff7f0e", "#d62728", "#2ca02c", "#9467bd"};
  int k = 0;
  for (const auto& [name, pts] : series) {
    const char* c = colors[k % 11];
    std::string path;
    for (auto [x, y] : pts) path += fmt::format("{}{:.1f},{:.1f} ", path.empty() ? "M" : "L", px(x), py(y));
    const bool ours = name.rfind("ours", 0) == 0;
    s += fmt::format(R"(<path d="{}" fill="none" stroke="{}" stroke-width="{}"/>)", path, c, ours ? 3 : 1.5);
    s += fmt::format(
        R"(<line x1="{0}" y1="{1}" x2="{2}" y2="{1}" stroke="{3}" stroke-width="3"/><text x="{4}" y="{5}">{6}</text>)",
        W - R + 10, T + 10 + 18 * k, W - R + 30, c, W - R + 36, T + 14 + 18 * k, name);
    ++k;
  }
  return s + "</svg>\n";
}

// The GPU radix sort (render::GpuSorter) on whatever OpenGL the headless context finds (Mesa's
// llvmpipe on CI, the GPU where there is one): its wall time to completion (glFinish) and the
// host thread's CPU time to issue it (CLOCK_THREAD_CPUTIME_ID: the driver's own threads do not
// count). Keys are the depths' order-preserving keys, uploaded once, as a GPU path would have
// them from its key pass.
struct GpuSortBench {
  render::HeadlessContext context{16, 16};
  render::GpuSorter sorter;
  GLuint query = 0;
  explicit GpuSortBench(std::size_t n) : sorter((context.bind(), static_cast<std::uint32_t>(n))) {
    glGenQueries(1, &query);
  }
  ~GpuSortBench() { glDeleteQueries(1, &query); }
  GpuSortBench(const GpuSortBench&) = delete;
  GpuSortBench& operator=(const GpuSortBench&) = delete;
  struct Times {
    double wall_ms, host_ms, gpu_ms;  // to completion, the host thread's CPU time, the GPU's own (a timer query)
  };
  // Each repetition sorts the same random keys, uploaded before the clock starts. The order is read
  // back once, after the timed sorts: a buffer the host reads from may be moved by the driver to
  // memory the host can see, and sorts into it would then be timed over the bus.
  Times run(const std::vector<float>& depths, int reps, int key_bits) {
    const auto n = static_cast<std::uint32_t>(depths.size());
    std::vector<std::uint32_t> keys(n), values(n);
    for (std::uint32_t i = 0; i < n; ++i) keys[i] = sort::order_preserving_key(depths[i]) >> (32 - key_bits);
    std::vector<double> wall, host, gpu;
    for (int r = 0; r < reps; ++r) {
      std::iota(values.begin(), values.end(), 0u);
      glNamedBufferSubData(sorter.keys_buffer(), 0, GLsizeiptr(n) * 4, keys.data());
      glNamedBufferSubData(sorter.values_buffer(), 0, GLsizeiptr(n) * 4, values.data());
      glFinish();
      const double c0 = thread_cpu_ms();
      const auto t0 = Clock::now();
      glBeginQuery(GL_TIME_ELAPSED, query);
      sorter.sort(n, key_bits);
      glEndQuery(GL_TIME_ELAPSED);
      host.push_back(thread_cpu_ms() - c0);
      glFinish();
      wall.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
      GLuint64 ns = 0;
      glGetQueryObjectui64v(query, GL_QUERY_RESULT, &ns);
      gpu.push_back(double(ns) * 1e-6);
    }
    glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
    glGetNamedBufferSubData(sorter.values_buffer(), 0, GLsizeiptr(n) * 4, values.data());
    for (std::uint32_t i = 1; i < n; ++i) {
      if (keys[values[i]] < keys[values[i - 1]]) throw Error("bench sort: the GPU sort did not sort");
    }
    return {median(wall), median(host), median(gpu)};
  }
};

}  // namespace

int bench_sort(const BenchSortOptions& o) {
  const std::vector<std::size_t> sizes =
      o.n ? std::vector<std::size_t>{o.n} : std::vector<std::size_t>{1000, 16384, 262144, 1048576, 4194304};
  const std::vector<std::string> inputs =
      o.n ? std::vector<std::string>{"random"} : std::vector<std::string>{"random", "nearly_sorted", "reversed"};
  bench::SortBench bench(*std::max_element(sizes.begin(), sizes.end()));
  std::vector<std::byte> copy_from(sizes.back() * 8), copy_to(sizes.back() * 8);
  nlohmann::ordered_json results = nlohmann::ordered_json::array();
  std::map<std::string, std::vector<std::pair<double, double>>> series;  // random input, for the plot
  std::optional<GpuSortBench> gpu;
  std::string gpu_renderer = "none";
  try {
    gpu.emplace(*std::max_element(sizes.begin(), sizes.end()));
    gpu_renderer = render::Renderer::gl_renderer();
  } catch (const Error& e) {  // no OpenGL 4.3 here: the CPU contenders alone
    if (!o.json) fmt::print(stderr, "note: no GPU sort measured: {}\n", e.what());
  }
  ProgressBar bar("bench sort", !o.json);
  const std::size_t total = sizes.size() * inputs.size();
  std::size_t done = 0;
  for (const std::string& input : inputs) {
    for (std::size_t n : sizes) {
      const std::vector<float> depths = make_input(input, n, static_cast<std::uint32_t>(n));
      const int reps = n >= 1000000 ? std::max(3, o.repetitions / 2) : o.repetitions;
      nlohmann::ordered_json row{{"input", input}, {"n", n}};
      std::vector<double> mc;
      for (int r = 0; r < reps; ++r) {
        const auto t0 = Clock::now();
        std::memcpy(copy_to.data(), copy_from.data(), n * 8);
        mc.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
      }
      row["memcpy_pairs_ms"] = median(mc);
      for (const auto& c : bench::contenders()) {
        if (n > c.max_n) continue;
        std::vector<double> ms;
        for (int r = 0; r < reps; ++r) {
          const auto t0 = Clock::now();
          bench.run(c.name, depths);
          ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
        }
        // A contender that does not sort is not measured: check its order once.
        for (std::size_t i = 1; i < n; ++i) {
          const float a = depths[bench.result[i - 1]], b = depths[bench.result[i]];
          const float tolerance = c.name == "ours_16bit" ? 2000.0f / 65535.0f : 0.0f;
          if (b + tolerance < a)
            throw Error(fmt::format("bench sort: {} did not sort {} input of {}", c.name, input, n));
        }
        row[std::string(c.name) + "_ms"] = median(ms);
        if (input == "random") series[std::string(c.name)].emplace_back(double(n), median(ms));
      }
      if (gpu && input == "random") {
        const auto t = gpu->run(depths, reps, 32);
        row["gpu_radix_ms"] = t.wall_ms;
        row["gpu_radix_host_thread_ms"] = t.host_ms;
        row["gpu_radix_gpu_ms"] = t.gpu_ms;
        row["gpu_radix16_gpu_ms"] = gpu->run(depths, reps, 16).gpu_ms;
        series["gpu_radix"].emplace_back(double(n), t.wall_ms);
      }
      row["ratio_vs_vqsort"] = row["vqsort_ms"].get<double>() / row["ours_ms"].get<double>();
      row["ratio_vs_std_sort"] = row["std_sort_ms"].get<double>() / row["ours_ms"].get<double>();
      results.push_back(row);
      bar.update(++done, total, fmt::format("{} {}", input, n));
    }
  }
  if (!o.svg.empty()) {
    write_file(o.svg, svg_plot(series, "Sorting key-index pairs, random depths (median ms, log-log)"));
  }
  if (!o.markdown.empty()) {
    std::ostringstream md;
    md << "| input | N | memcpy of the pairs |";
    for (const auto& c : bench::contenders()) md << " " << c.name << " |";
    md << " vqsort / ours |\n|---|---:|---:|";
    for (std::size_t i = 0; i < bench::contenders().size(); ++i) md << "---:|";
    md << "---:|\n";
    for (const auto& row : results) {
      md << "| " << row["input"].get<std::string>() << " | " << row["n"].get<std::size_t>() << " | "
         << fmt::format("{:.3f}", row["memcpy_pairs_ms"].get<double>()) << " |";
      for (const auto& c : bench::contenders()) {
        const std::string key = std::string(c.name) + "_ms";
        md << " " << (row.contains(key) ? fmt::format("{:.3f}", row[key].get<double>()) : std::string("—")) << " |";
      }
      md << fmt::format(" {:.2f}× |\n", row["ratio_vs_vqsort"].get<double>());
    }
    write_file(o.markdown, md.str());
  }
  if (o.n) {
    const auto& r = results[0];
    nlohmann::ordered_json j{{"n", o.n},
                             {"ours_ms", r["ours_ms"]},
                             {"ours_2threads_ms", r["ours_2threads_ms"]},
                             {"ours_16bit_ms", r["ours_16bit_ms"]},
                             {"vqsort_ms", r["vqsort_ms"]},
                             {"std_sort_ms", r["std_sort_ms"]},
                             {"memcpy_pairs_ms", r["memcpy_pairs_ms"]},
                             {"ratio_vs_vqsort", r["ratio_vs_vqsort"]},
                             {"ratio_vs_std_sort", r["ratio_vs_std_sort"]},
                             {"gpu_renderer", gpu_renderer},
                             {"gpu_radix_ms", r.value("gpu_radix_ms", 0.0)},
                             {"gpu_radix_host_thread_ms", r.value("gpu_radix_host_thread_ms", 0.0)},
                             {"gpu_radix_gpu_ms", r.value("gpu_radix_gpu_ms", 0.0)},
                             {"gpu_radix16_gpu_ms", r.value("gpu_radix16_gpu_ms", 0.0)},
                             {"contenders", r}};
    if (o.json) {
      fmt::print("{}\n", j.dump());
    } else {
      fmt::print(
          "{} random depths: ours {:.2f} ms (2 threads {:.2f}, 16-bit {:.2f}), vqsort {:.2f} ms, std::sort {:.2f} ms, "
          "memcpy of the pairs {:.2f} ms\n  vqsort / ours = {:.2f}x (goal 3x)\n"
          "  GPU radix sort on {}: {:.2f} ms to completion, {:.2f} ms of GPU time ({:.2f} with 16-bit keys), {:.3f} ms "
          "of the host thread\n",
          o.n, r["ours_ms"].get<double>(), r["ours_2threads_ms"].get<double>(), r["ours_16bit_ms"].get<double>(),
          r["vqsort_ms"].get<double>(), r["std_sort_ms"].get<double>(), r["memcpy_pairs_ms"].get<double>(),
          r["ratio_vs_vqsort"].get<double>(), gpu_renderer, r.value("gpu_radix_ms", 0.0),
          r.value("gpu_radix_gpu_ms", 0.0), r.value("gpu_radix16_gpu_ms", 0.0),
          r.value("gpu_radix_host_thread_ms", 0.0));
    }
    return 0;
  }
  fmt::print("{}\n", o.json ? results.dump() : results.dump(1));
  return 0;
}

}  // namespace pstream::app
