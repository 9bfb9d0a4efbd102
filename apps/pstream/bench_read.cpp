// `pstream bench read FILE.abc`: reading every frame's positions into one caller buffer, timed
// side by side with a plain memcpy of exactly the same bytes out of the same mapping.
#include <algorithm>
#include <chrono>
#include <cstring>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "commands.hpp"
#include "particlestream/alembic.hpp"
#include "stats.hpp"

namespace pstream::app {
namespace {

using namespace pstream::alembic;
using Clock = std::chrono::steady_clock;

Object pick_points(const Archive& archive, const std::string& wanted) {
  if (!wanted.empty()) {
    const auto o = archive.find(wanted);
    if (!o || !Points::matches(*o)) throw Error(fmt::format("{}: no points object '{}'", archive.name(), wanted));
    return *o;
  }
  std::optional<Object> best;
  std::uint64_t best_total = 0;
  for (const Object& o : archive.objects()) {
    if (!Points::matches(o)) continue;
    const Points p(o);
    std::uint64_t total = 0;
    for (std::uint32_t i = 0; i < p.num_samples(); ++i) total += p.count(i);
    if (!best || total > best_total) best = o, best_total = total;
  }
  if (!best) throw Error(fmt::format("{}: the archive holds no points object", archive.name()));
  return *best;
}

}  // namespace

int bench_read(const BenchReadOptions& options) {
  const Archive archive = Archive::open(options.file);
  const Points points(pick_points(archive, options.object));
  const std::uint32_t frames = points.num_samples();

  std::vector<std::span<const std::byte>> spans;  // the baseline copies these very bytes
  std::uint64_t max_values = 0, total_bytes = 0;
  for (std::uint32_t f = 0; f < frames; ++f) {
    spans.push_back(points.positions(f).bytes());
    max_values = std::max<std::uint64_t>(max_values, points.positions(f).scalar_count());
    total_bytes += spans.back().size();
  }
  std::vector<float> buffer(std::max<std::uint64_t>(max_values, 1));
  const auto out_bytes = std::as_writable_bytes(std::span(buffer));

  auto time_ms = [](auto&& work) {
    const auto t0 = Clock::now();
    work();
    return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  };
  auto read_all = [&] {
    for (std::uint32_t f = 0; f < frames; ++f) points.read_positions(f, buffer);
  };
  auto memcpy_all = [&] {
    for (const auto& s : spans) std::memcpy(out_bytes.data(), s.data(), s.size());
  };
  read_all();  // warm the page cache and the buffer
  memcpy_all();
  std::vector<double> read_ms, memcpy_ms;
  for (int r = 0; r < options.repetitions; ++r) {  // interleaved, so drift hits both alike
    read_ms.push_back(time_ms(read_all));
    memcpy_ms.push_back(time_ms(memcpy_all));
  }
  const double read = median(read_ms), base = median(memcpy_ms);
  const double ratio = base > 0 ? read / base : 0.0;
  if (options.json) {
    nlohmann::ordered_json j{{"file", options.file},
                             {"frames", frames},
                             {"bytes", total_bytes},
                             {"read_ms", read},
                             {"memcpy_ms", base},
                             {"ratio", ratio},
                             {"repetitions", options.repetitions}};
    fmt::print("{}\n", j.dump());
  } else {
    fmt::print("{}: {} frames, {:.1f} MiB of positions\n", options.file, frames, total_bytes / 1048576.0);
    fmt::print("  read into caller buffer  {:8.3f} ms (median of {})\n", read, options.repetitions);
    fmt::print("  memcpy of the same bytes {:8.3f} ms\n", base);
    fmt::print("  ratio                    {:8.3f}  (target <= 1.5)\n", ratio);
  }
  return 0;
}

}  // namespace pstream::app
