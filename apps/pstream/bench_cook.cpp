// `pstream bench cook FILE.abc`: cooking with the raw codec against a baseline that plainly
// reads the source's positions and writes the same number of bytes, in the same run.
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "base/output_file.hpp"
#include "commands.hpp"
#include "particlestream/alembic.hpp"
#include "particlestream/cook.hpp"
#include "stats.hpp"

namespace pstream::app {
namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// Reads every sample's positions and widths and writes as many bytes as the cooked records.
double baseline_seconds(const std::string& input, const std::filesystem::path& out, std::uint64_t bytes_to_write) {
  const auto t0 = Clock::now();
  const alembic::Archive archive = alembic::Archive::open(input);
  std::FILE* f = std::fopen(out.c_str(), "wb");
  if (f == nullptr) throw Error(fmt::format("{}: cannot create", out.string()));
  std::vector<float> buffer;
  std::uint64_t written = 0;
  for (const alembic::Object& o : archive.objects()) {
    if (!alembic::Points::matches(o)) continue;
    const alembic::Points points(o);
    for (std::uint32_t s = 0; s < points.num_samples(); ++s) {
      buffer.resize(points.count(s) * 4);
      points.read_positions(s, buffer);
      std::fwrite(buffer.data(), 1, buffer.size() * 4, f);
      written += buffer.size() * 4;
    }
  }
  std::vector<std::byte> rest(std::min<std::uint64_t>(bytes_to_write - std::min(written, bytes_to_write), 1 << 20));
  while (written < bytes_to_write) {
    const std::uint64_t n = std::min<std::uint64_t>(rest.size(), bytes_to_write - written);
    std::fwrite(rest.data(), 1, n, f);
    written += n;
  }
  std::fflush(f);
  ::fsync(::fileno(f));
  std::fclose(f);
  return seconds_since(t0);
}

// Every timed run starts from the same state: no earlier output for it to free, nothing of
// the other side's left dirty for it to write back (the two otherwise pay for each other).
void settle(const std::filesystem::path& output) {
  std::filesystem::remove(output);
  ::sync();
}

}  // namespace

int bench_cook(const BenchCookOptions& options) {
  std::optional<ScratchFolder> scratch(std::in_place, "bench-cook");
  const std::filesystem::path dir = scratch->path();
  std::vector<double> cook_s, base_s;
  std::uint64_t stream_bytes = 0, file_bytes = 0;
  cook::Options o;
  o.input = options.file;
  o.output = dir / "bench.pstream";
  o.merge = true;
  o.frame_codec = format::FrameCodec::Records;  // the import and packing against reading the file (not the codec)
  const auto run_cook = [&] {
    settle(o.output);
    const auto t0 = Clock::now();
    const cook::Report report = cook::cook(o);
    stream_bytes = report.stream_bytes;
    file_bytes = report.file_bytes;
    return seconds_since(t0);
  };
  const auto run_baseline = [&] {
    settle(dir / "baseline.bin");
    return baseline_seconds(options.file, dir / "baseline.bin", file_bytes);
  };
  run_cook();  // warm-up: page cache, first-touch of the binary's code
  for (int r = 0; r < options.repetitions; ++r) {
    // Alternating order, so a drift of the machine within a pair hits both alike.
    if (r % 2 == 0) {
      cook_s.push_back(run_cook());
      base_s.push_back(run_baseline());
    } else {
      base_s.push_back(run_baseline());
      cook_s.push_back(run_cook());
    }
  }
  scratch.reset();  // the cooks' files go before the report
  const double mb = double(stream_bytes) / 1e6;
  const double cook_mb_s = mb / median(cook_s), base_mb_s = mb / median(base_s);
  const double ratio = cook_mb_s / base_mb_s;
  if (options.json) {
    fmt::print("{}\n", nlohmann::ordered_json{{"file", options.file},
                                              {"stream_bytes", stream_bytes},
                                              {"cook_mb_s", cook_mb_s},
                                              {"baseline_mb_s", base_mb_s},
                                              {"ratio", ratio},
                                              {"repetitions", options.repetitions},
                                              {"cook_seconds", cook_s},
                                              {"baseline_seconds", base_s}}
                           .dump());
  } else {
    fmt::print(
        "{}: {:.1f} MB of records\n  cook (raw)            {:8.1f} MB/s\n  read + write baseline {:8.1f} MB/s\n"
        "  ratio                 {:8.2f}  (target >= 0.70)\n",
        options.file, mb, cook_mb_s, base_mb_s, ratio);
  }
  return 0;
}

}  // namespace pstream::app
