// The automatic camera and the automatic ramp range: one rule each for `pstream render`, the viewer
// and the demo.
#include <algorithm>
#include <cmath>
#include <cstring>

#include "particlestream/format.hpp"
#include "particlestream/playback.hpp"

namespace pstream::playback {

namespace {

// Four frames of each clip's frames within `seconds` (a quarter, half, three quarters, the end of
// them), at most 50,000 records of each: what the automatic camera and ramp look at. `clip(meta)`
// sees each clip first, then `use(meta, record)` each sampled record.
template <class Clip, class Use>
void sample_frames(std::span<const std::filesystem::path> files, const std::array<double, 2>& seconds, Clip&& clip,
                   Use&& use) {
  for (const auto& file : files) {
    const format::Reader reader = format::Reader::open(file);
    const format::Metadata& m = reader.metadata();
    clip(m);
    // The clip's frames shown: from the first at or after seconds[0] to the last at or before
    // seconds[1] (times increase: the reader checked them).
    std::uint64_t first = 0, last = m.frame_count();
    while (first < last && m.frames[first].time < seconds[0]) ++first;
    while (last > first && m.frames[last - 1].time > seconds[1]) --last;
    std::vector<std::byte> records;
    for (const double at : {0.25, 0.5, 0.75, 1.0}) {
      if (first == last) break;
      const auto f = first + std::min<std::uint64_t>(last - 1 - first, std::uint64_t(at * double(last - 1 - first)));
      if (records.empty()) records = format::frame_buffer(m, reader.name());
      reader.read_frame(f, records);
      const std::uint64_t step = std::max<std::uint64_t>(1, m.frames[f].count / 50000);
      for (std::uint64_t i = 0; i < m.frames[f].count; i += step) use(m, records.data() + i * m.record_size);
    }
  }
}

}  // namespace

namespace {

// The sampled particles' positions and sizes, and the clips' whole bounds.
struct Positions {
  std::vector<render::Vec3> points;
  std::vector<float> scales;
  std::array<float, 6> whole{INFINITY, INFINITY, INFINITY, -INFINITY, -INFINITY, -INFINITY};
};

Positions sample_positions(std::span<const std::filesystem::path> files, const std::array<double, 2>& seconds) {
  Positions s;
  sample_frames(
      files, seconds,
      [&](const format::Metadata& m) {  // the clips' whole bounds, for when too few particles are found
        for (std::size_t a = 0; a < 3; ++a) {
          s.whole[a] = std::min(s.whole[a], m.bounds[a]);
          s.whole[a + 3] = std::max(s.whole[a + 3], m.bounds[a + 3]);
        }
      },
      [&](const format::Metadata&, const std::byte* record) {
        render::Vec3 p;
        float scale = 0;
        std::memcpy(p.data(), record + render::kPositionOffset, sizeof p);
        std::memcpy(&scale, record + render::kScaleOffset, sizeof scale);
        if (std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2])) s.points.push_back(p);
        if (std::isfinite(scale)) s.scales.push_back(scale);
      });
  return s;
}

// Per axis, the 0.5th to 99.5th percentile of the points (all of them when there are too few),
// no smaller than one particle: the first frames of an effect that starts from a point hold a
// handful. The whole bounds when no point was found.
std::array<float, 6> robust_box(const Positions& s) {
  if (s.points.empty()) return s.whole;
  const float radius = s.scales.empty() ? 0.0f : *std::max_element(s.scales.begin(), s.scales.end());
  std::array<float, 6> box{};
  std::vector<float> v(s.points.size());
  for (std::size_t a = 0; a < 3; ++a) {
    for (std::size_t i = 0; i < v.size(); ++i) v[i] = s.points[i][a];
    const std::size_t cut = v.size() < 16 ? 0 : v.size() / 200;
    const auto lo = v.begin() + std::ptrdiff_t(cut), hi = v.begin() + std::ptrdiff_t(v.size() - 1 - cut);
    std::nth_element(v.begin(), lo, v.end());
    box[a] = *lo;
    std::nth_element(v.begin(), hi, v.end());
    box[a + 3] = *hi;
    const float centre = 0.5f * (box[a] + box[a + 3]);
    box[a] = std::min(box[a], centre - radius);
    box[a + 3] = std::max(box[a + 3], centre + radius);
  }
  return box;
}

}  // namespace

std::array<float, 6> framing_box(std::span<const std::filesystem::path> files, const std::array<double, 2>& seconds) {
  return robust_box(sample_positions(files, seconds));
}

render::Camera framing_camera(std::span<const std::filesystem::path> files, float aspect,
                              const std::array<float, 4>& region, const std::array<double, 2>& seconds) {
  Positions s = sample_positions(files, seconds);
  const std::array<float, 6> b = robust_box(s);
  if (!(b[0] <= b[3] && b[1] <= b[4] && b[2] <= b[5])) return render::Camera{};  // no particle anywhere
  // The points inside that box (the strays left out), each with the largest particle's radius
  // around it: tighter than the box, whose corners a round or slanted cloud leaves empty. Framed
  // in part of the image (beside the viewer's panel), the strays stay in: one must not end up
  // under the panel.
  const bool whole_image = region == std::array<float, 4>{0.0f, 0.0f, 1.0f, 1.0f};
  if (whole_image) {
    std::erase_if(s.points, [&](const render::Vec3& p) {
      return p[0] < b[0] || p[1] < b[1] || p[2] < b[2] || p[0] > b[3] || p[1] > b[4] || p[2] > b[5];
    });
  }
  if (s.points.empty()) return render::Camera::framing({b[0], b[1], b[2]}, {b[3], b[4], b[5]}, aspect, region);
  const float pad = s.scales.empty() ? 0.0f : std::max(*std::max_element(s.scales.begin(), s.scales.end()), 0.0f);
  return render::Camera::framing(s.points, pad, aspect, region);
}

std::array<float, 2> ramp_range(std::span<const std::filesystem::path> files, const std::string& attribute) {
  std::vector<float> values;
  sample_frames(
      files, {-INFINITY, INFINITY}, [](const format::Metadata&) {},
      [&](const format::Metadata& m, const std::byte* record) {
        const format::Attribute* a = m.find(attribute.empty() ? "velocity" : attribute);
        if (a == nullptr || a->type != format::AttributeType::Float32) return;
        if (attribute.empty() && a->components != 3) return;
        float v[3] = {0, 0, 0};
        std::memcpy(v, record + a->offset, 4 * std::min<std::size_t>(a->components, 3));
        const float x = attribute.empty() ? std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) : v[0];
        if (std::isfinite(x)) values.push_back(x);
      });
  if (values.size() < 2) return {0.0f, 1.0f};
  const auto at = [&](double q) {
    const auto it = values.begin() + std::ptrdiff_t(q * double(values.size() - 1));
    std::nth_element(values.begin(), it, values.end());
    return *it;
  };
  // Speeds from rest (0) to the 99th percentile; an attribute from its 1st to 99th percentile.
  const float low = attribute.empty() ? 0.0f : at(0.01), high = at(0.99);
  return high > low ? std::array<float, 2>{low, high} : std::array<float, 2>{low, low + 1.0f};
}

}  // namespace pstream::playback
