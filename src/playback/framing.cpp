// The automatic camera and the automatic ramp range: one rule each for `pstream render`, the viewer
// and the demo.
#include <algorithm>
#include <cmath>
#include <cstring>

#include "particlestream/format.hpp"
#include "particlestream/playback.hpp"

namespace pstream::playback {

namespace {

// Frame `f` of `reader` decoded into `records` (sized on first use), and `use(record)` for about
// 50,000 of its records at most: every step-th.
template <class Use>
void sample_frame(const format::Reader& reader, std::uint64_t f, std::vector<std::byte>& records, Use&& use) {
  const format::Metadata& m = reader.metadata();
  if (records.empty()) records = format::frame_buffer(m, reader.name());
  reader.read_frame(f, records);
  const std::uint64_t step = std::max<std::uint64_t>(1, m.frames[f].count / 50000);
  for (std::uint64_t i = 0; i < m.frames[f].count; i += step) use(records.data() + i * m.record_size);
}

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
      sample_frame(reader, f, records, [&](const std::byte* record) { use(m, record); });
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
  void add(const std::byte* record) {
    render::Vec3 p;
    float scale = 0;
    std::memcpy(p.data(), record + render::kPositionOffset, sizeof p);
    std::memcpy(&scale, record + render::kScaleOffset, sizeof scale);
    if (std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2])) points.push_back(p);
    if (std::isfinite(scale)) scales.push_back(scale);
  }
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
      [&](const format::Metadata&, const std::byte* record) { s.add(record); });
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

namespace {

// The framing rule for a cloud of points: the points inside their robust box (the strays left
// out), each with the largest particle's radius around it, framed by Camera::framing. That is
// tighter than the box, whose corners a round or slanted cloud leaves empty. Framed in part of the
// image (beside the viewer's panel), the strays stay in: one must not end up under the panel.
render::Camera frame_cloud(Positions s, const std::array<float, 6>& b, float aspect,
                           const std::array<float, 4>& region) {
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

bool has_volume(const std::array<float, 6>& b) { return b[0] <= b[3] && b[1] <= b[4] && b[2] <= b[5]; }

float distance_of(const render::Camera& c) {
  const float dx = c.eye[0] - c.target[0], dy = c.eye[1] - c.target[1], dz = c.eye[2] - c.target[2];
  return std::sqrt(dx * dx + dy * dy + dz * dz);
}

// `c` moved back along its view to `distance` (never nearer): its near plane still clears
// everything it framed, its far plane moves back with it.
render::Camera pulled_back(render::Camera c, float distance) {
  const float d = distance_of(c);
  if (!(distance > d) || d <= 0) return c;
  for (int a = 0; a < 3; ++a) c.eye[a] = c.target[a] + (c.eye[a] - c.target[a]) * (distance / d);
  c.far += distance - d;
  return c;
}

// The diagonal of `box` within `within` (0 when they do not meet).
float extent_within(const std::array<float, 6>& box, const std::array<float, 6>& within) {
  float sum = 0;
  for (int a = 0; a < 3; ++a) {
    const float lo = std::max(box[a], within[a]), hi = std::min(box[a + 3], within[a + 3]);
    if (!(lo <= hi)) return 0.0f;
    sum += (hi - lo) * (hi - lo);
  }
  return std::sqrt(sum);
}

constexpr float kKeyChange = 1.25f;  // a new key where the frames' extent has changed by this factor
constexpr double kKeyEvery = 0.5;    // and at least this often (seconds): the bounds miss a shrinking bulk
constexpr float kPullIn = 0.7f;      // the distance shrinks by at most this factor a second
constexpr std::size_t kMaxKeys = 64;

}  // namespace

std::array<float, 6> framing_box(std::span<const std::filesystem::path> files, const std::array<double, 2>& seconds) {
  return robust_box(sample_positions(files, seconds));
}

render::Camera framing_camera(std::span<const std::filesystem::path> files, float aspect,
                              const std::array<float, 4>& region, const std::array<double, 2>& seconds) {
  const Positions s = sample_positions(files, seconds);
  const std::array<float, 6> b = robust_box(s);
  if (!has_volume(b)) return render::Camera{};  // no particle anywhere
  return frame_cloud(s, b, aspect, region);
}

render::Camera CameraTrack::at(double seconds) const {
  if (keys.empty()) return render::Camera{};
  if (!(seconds > keys.front().time)) return keys.front().camera;
  if (!(seconds < keys.back().time)) return keys.back().camera;
  std::size_t k = 1;
  while (keys[k].time <= seconds) ++k;
  const Key &a = keys[k - 1], &b = keys[k];
  const float s = float((seconds - a.time) / (b.time - a.time));
  const float da = distance_of(a.camera), db = distance_of(b.camera);
  // Pulling back, the camera stands at the next key's distance over the whole interval: the effect
  // grows between the keys, and must not outgrow the view before the next one. Coming in, the
  // distance shrinks geometrically.
  const float d = db >= da ? db : da * std::pow(db / da, s);
  render::Camera c = b.camera;
  for (int i = 0; i < 3; ++i) {
    c.target[i] = a.camera.target[i] + (b.camera.target[i] - a.camera.target[i]) * s;
    const float dir = db > 0 ? (b.camera.eye[i] - b.camera.target[i]) / db : 0.0f;
    c.eye[i] = c.target[i] + dir * d;
  }
  // Near and far scale with the distance, as the framing sets them.
  const float k_near = db > 0 ? b.camera.near / db : 0.01f, k_far = db > 0 ? b.camera.far / db : 100.0f;
  const float a_near = da > 0 ? a.camera.near / da : k_near, a_far = da > 0 ? a.camera.far / da : k_far;
  c.near = d * std::min(a_near, k_near);
  c.far = d * std::max(a_far, k_far);
  return c;
}

CameraTrack framing_track(std::span<const std::filesystem::path> files, float aspect,
                          const std::array<float, 4>& region, const std::array<double, 2>& seconds) {
  CameraTrack track;
  const Positions sampled = sample_positions(files, seconds);
  const std::array<float, 6> box = robust_box(sampled);
  if (!has_volume(box)) {  // no particle anywhere
    track.keys.push_back({0.0, render::Camera{}});
    return track;
  }
  const float radius =
      sampled.scales.empty() ? 0.0f : std::max(*std::max_element(sampled.scales.begin(), sampled.scales.end()), 0.0f);
  const float least = std::max(2.0f * radius, extent_within(box, box) * 1e-3f);  // one particle's extent

  // Every non-empty frame shown, in time order, with the extent of its stored bounds within the
  // sampled box (a stray far away does not count).
  struct Shown {
    double time;
    float extent;
    render::Vec3 centre;
  };
  std::vector<Shown> shown;
  std::vector<format::Reader> readers;
  for (const auto& file : files) {
    readers.push_back(format::Reader::open(file));
    const format::Metadata& m = readers.back().metadata();
    for (const format::FrameEntry& e : m.frames) {
      if (e.count == 0 || e.time < seconds[0] || e.time > seconds[1] || !has_volume(e.bounds)) continue;
      render::Vec3 centre;
      for (int a = 0; a < 3; ++a) centre[a] = std::clamp(0.5f * (e.bounds[a] + e.bounds[a + 3]), box[a], box[a + 3]);
      shown.push_back({e.time, std::max(extent_within(e.bounds, box), least), centre});
    }
  }
  std::stable_sort(shown.begin(), shown.end(), [](const Shown& a, const Shown& b) { return a.time < b.time; });
  if (shown.empty()) {
    track.keys.push_back({0.0, frame_cloud(sampled, box, aspect, region)});
    return track;
  }
  // Keys: the first frame, each frame whose extent differs from the last key's by kKeyChange
  // (either way) or whose centre has moved by a quarter of that extent or that comes kKeyEvery
  // after it, and the last frame; every n-th of those when there are more than kMaxKeys.
  std::vector<std::size_t> keys{0};
  for (std::size_t k = 1; k < shown.size(); ++k) {
    const Shown& last = shown[keys.back()];
    const float ratio = shown[k].extent / last.extent;
    const render::Vec3 moved{shown[k].centre[0] - last.centre[0], shown[k].centre[1] - last.centre[1],
                             shown[k].centre[2] - last.centre[2]};
    const float travel = std::sqrt(moved[0] * moved[0] + moved[1] * moved[1] + moved[2] * moved[2]);
    if (ratio >= kKeyChange || ratio <= 1.0f / kKeyChange || travel >= 0.25f * last.extent ||
        shown[k].time - last.time >= kKeyEvery)
      keys.push_back(k);
  }
  if (keys.back() != shown.size() - 1) keys.push_back(shown.size() - 1);
  if (keys.size() > kMaxKeys) {
    const std::size_t every = (keys.size() + kMaxKeys - 3) / (kMaxKeys - 2);
    std::vector<std::size_t> fewer;
    for (std::size_t k = 0; k + 1 < keys.size(); k += every) fewer.push_back(keys[k]);
    fewer.push_back(keys.back());
    keys = std::move(fewer);
  }
  // Each key frames its own frame's particles (of every clip at that time) by the same rule as the
  // sampled frames, then stands back as far as the key before it did, less kPullIn a second.
  std::vector<std::vector<std::byte>> records(files.size());
  for (const std::size_t k : keys) {
    const double time = shown[k].time;
    Positions s;
    for (std::size_t i = 0; i < files.size(); ++i) {
      const format::Metadata& m = readers[i].metadata();
      // This clip's last frame at or before the key's time, within the seconds shown.
      std::uint64_t f = m.frame_count();
      while (f > 0 && m.frames[f - 1].time > time) --f;
      if (f == 0 || m.frames[f - 1].time < seconds[0] || m.frames[f - 1].count == 0) continue;
      --f;
      sample_frame(readers[i], f, records[i], [&](const std::byte* record) { s.add(record); });
    }
    if (s.points.empty()) continue;
    render::Camera c = frame_cloud(s, robust_box(s), aspect, region);
    if (!track.keys.empty()) {
      const CameraTrack::Key& before = track.keys.back();
      c = pulled_back(c, distance_of(before.camera) * std::pow(kPullIn, float(time - before.time)));
    }
    track.keys.push_back({time, c});
  }
  if (track.keys.empty()) track.keys.push_back({0.0, frame_cloud(sampled, box, aspect, region)});
  return track;
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
  return ramp_range_of(values, attribute.empty());
}

}  // namespace pstream::playback
