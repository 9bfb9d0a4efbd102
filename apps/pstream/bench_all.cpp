// `pstream bench all`: every benchmark of the project on generated 1M-particle clips, each run as
// `pstream bench ... --json` in a child process (so each starts cold and alone), collected into a
// Markdown page with the ratios against the baselines measured in the same runs.
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "base/output_file.hpp"
#include "commands.hpp"
#include "particlestream/alembic_writer.hpp"
#include "process.hpp"
#include "progress.hpp"

namespace pstream::app {
namespace {

using json = nlohmann::ordered_json;

// Runs this pstream binary with `args` and --json (no shell), and parses what it prints.
json run_json(std::vector<std::string> args) {
  std::string shown = "pstream";
  for (const std::string& a : args) shown += " " + a;
  args.insert(args.begin(), self_executable());
  args.emplace_back("--json");
  const ProgramResult r = run_program(args, /*capture=*/true, /*quiet=*/true);
  if (r.exit_code != 0) throw Error(fmt::format("`{}` failed (exit code {})", shown, r.exit_code));
  const json out = json::parse(r.output, nullptr, /*allow_exceptions=*/false);
  if (out.is_discarded()) throw Error(fmt::format("`{}` printed no JSON", shown));
  return out;
}

// An Alembic clip of `count` particles orbiting a centre, `frames` samples at 24 fps.
void write_clip(const std::filesystem::path& path, std::uint64_t count, int frames) {
  alembic::PointsWriterOptions o;
  o.name = "cloud";
  o.velocities = false;
  alembic::ArchiveWriter w(path, "pstream bench all", "generated", 24.0, 1.0 / 24, o);
  std::vector<float> P(count * 3), widths(count, 0.01f);
  std::vector<std::uint64_t> ids(count);
  for (std::uint64_t i = 0; i < count; ++i) ids[i] = i;
  for (int f = 0; f < frames; ++f) {
    const float t = float(f) / 24.0f;
    for (std::uint64_t i = 0; i < count; ++i) {
      const float a = float(i) * 0.618034f + t, r = 1.0f + float(i % 1000) * 0.001f;
      P[i * 3] = r * std::cos(a), P[i * 3 + 1] = float(i % 997) * 0.002f, P[i * 3 + 2] = r * std::sin(a);
    }
    w.write_sample({P, ids, {}, widths, {}});
  }
  w.close();
}

}  // namespace

int bench_all(const BenchAllOptions& o) {
  namespace fs = std::filesystem;
  check_output(o.out);  // before minutes of work: a missing folder is said now
  const ScratchFolder scratch("bench-all");
  const fs::path& dir = scratch.path();
  ProgressBar bar("bench all", true);
  const std::size_t steps = 6;
  bar.update(0, steps, "writing a 1M-particle Alembic clip");
  const fs::path abc = dir / "cloud.abc";
  write_clip(abc, 1u << 20, 10);
  ::sync();  // no writeback of the fresh clip competing with the benchmarks' own writes
  bar.update(1, steps, "bench read");
  const json read = run_json({"bench", "read", abc.string()});
  bar.update(2, steps, "bench cook");
  const json cook = run_json({"bench", "cook", abc.string(), "--repetitions", "7"});
  bar.update(3, steps, "bench stream");
  const json stream = run_json({"bench", "stream"});
  bar.update(4, steps, "bench sort");
  const fs::path plot = fs::path(o.out).parent_path() / "benchmarks_sort.svg";
  const json sort_one = run_json({"bench", "sort", "--n", "1048576"});
  const json sort_table = run_json({"bench", "sort", "--svg", plot.string()});
  bar.update(5, steps, "bench render");
  const json render = run_json({"bench", "render"});
  bar.update(6, steps, "done");

  std::ostringstream md;
  md << "# Benchmarks\n\n"
        "Written by `pstream bench all` on this project's machine (2 cores, shared: absolute times drift, so every "
        "stage\n"
        "is reported against a baseline measured in the same run). Clips are generated: 1,048,576 particles a "
        "frame.\n\n";
  md << "| stage | ours | baseline (same run) | ratio | target |\n|---|---:|---:|---:|---|\n";
  md << fmt::format(
      "| read Alembic positions into a caller buffer (10 frames) | {:.2f} ms | memcpy of the same bytes {:.2f} ms | "
      "{:.2f} | ≤ 1.5 |\n",
      read["read_ms"].get<double>(), read["memcpy_ms"].get<double>(), read["ratio"].get<double>());
  md << fmt::format(
      "| cook (raw codec) | {:.0f} MB/s | read source + write as many bytes {:.0f} MB/s | {:.2f} | ≥ 0.70 |\n",
      cook["cook_mb_s"].get<double>(), cook["baseline_mb_s"].get<double>(), cook["ratio"].get<double>());
  md << fmt::format(
      "| stream: update + copy a 16 MiB frame, real time | {:.3f} ms median | memcpy of the frame {:.3f} ms | {:.2f} | "
      "≤ 1.3, 0 stalls ({} stalls) |\n",
      stream["frame_ms_median"].get<double>(), stream["memcpy_ms_median"].get<double>(), stream["ratio"].get<double>(),
      stream["stalls"].get<std::uint64_t>());
  md << fmt::format(
      "| sort 1M depths back to front | {:.2f} ms (16-bit keys {:.2f}, 2 threads {:.2f}) | vqsort {:.2f} ms, std::sort "
      "{:.2f} ms | {:.2f}× vqsort | ≥ 3× vqsort |\n",
      sort_one["ours_ms"].get<double>(), sort_one["ours_16bit_ms"].get<double>(),
      sort_one["ours_2threads_ms"].get<double>(), sort_one["vqsort_ms"].get<double>(),
      sort_one["std_sort_ms"].get<double>(), sort_one["ratio_vs_vqsort"].get<double>());
  md << "\n## Rendering (" << render["gl_renderer"].get<std::string>()
     << ", 1280×720)\n\n| particles | method | ms a frame |\n|---:|---|---:|\n";
  for (const auto& r : render["results"]) {
    md << fmt::format("| {} | {} | {:.1f} |\n", r["particles"].get<std::uint64_t>(), r["method"].get<std::string>(),
                      r["frame_ms_median"].get<double>());
  }
  md << "\n## Sorting, every contender (ms, median)\n\n![sorting plot](" << plot.filename().string()
     << ")\n\n| input | N |";
  std::vector<std::string> keys;
  for (const auto& [k, v] : sort_table[0].items()) {
    if (k.size() > 3 && k.substr(k.size() - 3) == "_ms") keys.push_back(k);
  }
  for (const auto& k : keys) md << " " << k.substr(0, k.size() - 3) << " |";
  md << "\n|---|---:|";
  for (std::size_t i = 0; i < keys.size(); ++i) md << "---:|";
  md << "\n";
  for (const auto& row : sort_table) {
    md << "| " << row["input"].get<std::string>() << " | " << row["n"].get<std::uint64_t>() << " |";
    for (const auto& k : keys)
      md << " " << (row.contains(k) ? fmt::format("{:.3f}", row[k].get<double>()) : "—") << " |";
    md << "\n";
  }
  md << "\nRaw results:\n\n```json\n"
     << json{{"read", read}, {"cook", cook}, {"stream", stream}, {"sort", sort_one}, {"render", render}}.dump(1)
     << "\n```\n";
  write_file(o.out, md.str());
  if (!std::filesystem::exists(plot))
    throw Error(fmt::format("{}: the sort benchmark did not write its plot", plot.string()));
  fmt::print("wrote {} and {}\n", o.out, plot.string());
  return 0;
}

}  // namespace pstream::app
