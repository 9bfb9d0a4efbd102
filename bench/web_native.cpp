// The native side of the web player's benchmark (bench/web/run.sh): per cached frame of a clip,
// the decode (the format's Reader, frames in order) and the back-to-front sort of its particles
// along the clip's framing camera (sort::DepthSorter, one thread), as wall-clock medians and 95th
// percentiles, the measure the browser's performance.now() gives the page.
//   pstream_bench_web_native CLIP   prints {"particles":…, "decode_ms":{…}, "sort_ms":{…}}
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <exception>
#include <vector>

#include <fmt/format.h>

#include "particlestream/format.hpp"
#include "particlestream/frame.hpp"
#include "particlestream/sort.hpp"

namespace {

struct Stat {
  double median = 0, p95 = 0;
};

Stat stat(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  if (v.empty()) return {};
  return {v[v.size() / 2], v[std::min(v.size() - 1, static_cast<std::size_t>(double(v.size()) * 0.95))]};
}

double ms_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

int main(int argc, char** argv) {
  using namespace pstream;
  if (argc != 2) {
    std::fprintf(stderr, "usage: pstream_bench_web_native CLIP\n");
    return 2;
  }
  try {
    const auto reader = format::Reader::open(argv[1]);
    const format::Metadata& m = reader.metadata();
    std::vector<std::byte> records = format::frame_buffer(m, reader.name());
    const auto& b = m.bounds;
    const render::Camera camera = render::Camera::framing({b[0], b[1], b[2]}, {b[3], b[4], b[5]}, 16.0f / 9.0f);
    sort::DepthSorter sorter(m.max_count);
    std::vector<double> decode, sorting, counts;
    for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
      auto t0 = std::chrono::steady_clock::now();
      reader.read_frame(f, records);
      decode.push_back(ms_since(t0));
      t0 = std::chrono::steady_clock::now();
      const auto order =
          sorter.sort(records.data(), m.frames[f].count, m.record_size, camera.view(), render::SortMode::BackToFront);
      sorting.push_back(ms_since(t0));
      counts.push_back(double(order.size()));
    }
    const Stat d = stat(decode), s = stat(sorting), n = stat(counts);
    fmt::print(
        "{{\"frames\":{},\"particles\":{},\"decode_ms\":{{\"median\":{:.3f},\"p95\":{:.3f}}},"
        "\"sort_ms\":{{\"median\":{:.3f},\"p95\":{:.3f}}}}}\n",
        m.frame_count(), n.median, d.median, d.p95, s.median, s.p95);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pstream_bench_web_native: %s\n", e.what());
    return 1;
  }
  return 0;
}
