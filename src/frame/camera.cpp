#include <algorithm>
#include <cmath>
#include <numbers>

#include <fmt/format.h>

#include "particlestream/frame.hpp"
#include "particlestream/sort.hpp"

namespace pstream::render {
namespace {

Vec3 sub(const Vec3& a, const Vec3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
float dot(const Vec3& a, const Vec3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
Vec3 normalize(const Vec3& v) {
  const float l = std::sqrt(dot(v, v));
  return l > 0 ? Vec3{v[0] / l, v[1] / l, v[2] / l} : v;
}

}  // namespace

Mat4 identity() { return {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1}; }

Mat4 multiply(const Mat4& a, const Mat4& b) {
  Mat4 r{};
  for (int c = 0; c < 4; ++c) {
    for (int row = 0; row < 4; ++row) {
      float s = 0;
      for (int k = 0; k < 4; ++k) s += a[k * 4 + row] * b[c * 4 + k];
      r[c * 4 + row] = s;
    }
  }
  return r;
}

Mat4 translation(const Vec3& t) {
  Mat4 m = identity();
  m[12] = t[0], m[13] = t[1], m[14] = t[2];
  return m;
}

Mat4 look_at(const Vec3& eye, const Vec3& target, const Vec3& up) {
  const Vec3 f = normalize(sub(target, eye));
  Vec3 s = normalize(cross(f, up));
  if (dot(s, s) == 0) s = {1, 0, 0};  // looking straight along `up`
  const Vec3 u = cross(s, f);
  return {s[0], u[0], -f[0], 0, s[1], u[1], -f[1], 0, s[2], u[2], -f[2], 0, -dot(s, eye), -dot(u, eye), dot(f, eye), 1};
}

Mat4 perspective(float fov_y_degrees, float aspect, float near, float far) {
  const float f = 1.0f / std::tan(fov_y_degrees * std::numbers::pi_v<float> / 360.0f);
  Mat4 m{};
  m[0] = f / aspect;
  m[5] = f;
  m[10] = (far + near) / (near - far);
  m[11] = -1;
  m[14] = 2 * far * near / (near - far);
  return m;
}

namespace {

float half_tan(float fov_y_degrees) { return std::tan(fov_y_degrees * std::numbers::pi_v<float> / 360.0f); }

// Camera::framing for a view of `aspect` whose height spans tan(fov_y / 2) = tan_y: every point,
// and `pad` around it, inside the view, with a margin.
Camera frame_points(std::span<const Vec3> points, float pad, float aspect, float tan_y) {
  Camera c;
  const Vec3 dir = normalize({0.55f, 0.4f, 1.0f});  // three-quarter view, from above the front
  const Vec3 right = normalize(cross({-dir[0], -dir[1], -dir[2]}, {0, 1, 0}));
  const Vec3 up = cross(right, {-dir[0], -dir[1], -dir[2]});
  // The target: the middle of the points' extent across, up and along the view.
  std::array<float, 3> lo{INFINITY, INFINITY, INFINITY}, hi{-INFINITY, -INFINITY, -INFINITY};
  for (const Vec3& p : points) {
    const float q[3] = {dot(p, right), dot(p, up), dot(p, dir)};
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], q[a]), hi[a] = std::max(hi[a], q[a]);
  }
  if (points.empty()) lo = hi = {0, 0, 0};
  for (int a = 0; a < 3; ++a)
    c.target[a] = right[a] * 0.5f * (lo[0] + hi[0]) + up[a] * 0.5f * (lo[1] + hi[1]) + dir[a] * 0.5f * (lo[2] + hi[2]);
  // The nearest distance at which every point is inside the view.
  const float tan_x = tan_y * std::max(aspect, 0.1f);
  float distance = 0, radius = pad;
  for (const Vec3& p : points) {
    const Vec3 d = sub(p, c.target);
    const float toward = dot(d, dir);  // a point nearer the camera needs more distance
    distance = std::max(
        {distance, (std::abs(dot(d, up)) + pad) / tan_y + toward, (std::abs(dot(d, right)) + pad) / tan_x + toward});
    radius = std::max(radius, std::sqrt(dot(d, d)) + pad);
  }
  radius = std::max(radius, 1e-3f);
  distance = std::max(distance * 1.08f, radius * 0.2f);
  c.eye = {c.target[0] + dir[0] * distance, c.target[1] + dir[1] * distance, c.target[2] + dir[2] * distance};
  c.near = std::max(distance - radius * 2, distance * 0.01f);
  c.far = distance + radius * 2;
  return c;
}

Camera frame_box(const Vec3& lo, const Vec3& hi, float aspect, float tan_y) {
  std::array<Vec3, 8> corners;
  for (int k = 0; k < 8; ++k)
    corners[std::size_t(k)] = {k & 1 ? hi[0] : lo[0], k & 2 ? hi[1] : lo[1], k & 4 ? hi[2] : lo[2]};
  return frame_points(corners, 0.0f, aspect, tan_y);
}

// The region [x0, x1] x [y0, y1] of an image of `aspect` is (x1 - x0) of its width and (y1 - y0)
// of its height; projections are linear in NDC, so it sees the content as a whole view of that
// aspect and a height of (y1 - y0) x tan_y, moved there by a lens shift.
template <class Frame>
Camera in_region(const std::array<float, 4>& region, float aspect, Frame&& frame) {
  const float x0 = std::clamp(region[0], 0.0f, 1.0f), y0 = std::clamp(region[1], 0.0f, 1.0f);
  const float x1 = std::clamp(region[2], x0 + 1e-3f, 1.0f), y1 = std::clamp(region[3], y0 + 1e-3f, 1.0f);
  Camera c = frame(aspect * (x1 - x0) / (y1 - y0), half_tan(Camera{}.fov_y_degrees) * (y1 - y0));
  c.shift = {x0 + x1 - 1.0f, 1.0f - (y0 + y1)};
  return c;
}

}  // namespace

Camera Camera::looking(const Vec3& eye, const Vec3& target) {
  Camera c;
  c.eye = eye;
  c.target = target;
  const Vec3 d = sub(eye, target);
  const float distance = std::sqrt(dot(d, d));
  c.near = std::max(0.001f, distance * 0.001f);
  c.far = distance * 100.0f + 100.0f;
  return c;
}

Camera Camera::framing(const Vec3& lo, const Vec3& hi, float aspect) {
  return frame_box(lo, hi, aspect, half_tan(Camera{}.fov_y_degrees));
}

Camera Camera::framing(const Vec3& lo, const Vec3& hi, float aspect, const std::array<float, 4>& region) {
  return in_region(region, aspect, [&](float a, float tan_y) { return frame_box(lo, hi, a, tan_y); });
}

Camera Camera::framing(std::span<const Vec3> points, float pad, float aspect, const std::array<float, 4>& region) {
  return in_region(region, aspect, [&](float a, float tan_y) { return frame_points(points, pad, a, tan_y); });
}

Backdrop Backdrop::under(const Vec3& lo, const Vec3& hi) {
  Backdrop b;
  b.ground_height = std::isfinite(lo[1]) ? lo[1] : 0.0f;
  const float extent = std::max(hi[0] - lo[0], hi[2] - lo[2]);
  // A power of ten, or twice or five times one: lines a tenth of the box apart, rounded.
  const float raw = std::isfinite(extent) && extent > 0 ? extent / 10.0f : 1.0f;
  const float decade = std::pow(10.0f, std::floor(std::log10(raw)));
  const float m = raw / decade;
  b.grid_spacing = decade * (m < 1.5f ? 1.0f : m < 3.5f ? 2.0f : m < 7.5f ? 5.0f : 10.0f);
  return b;
}

Vec3 view_direction(const Mat4& view, const Vec3& world) {
  return normalize({view[0] * world[0] + view[4] * world[1] + view[8] * world[2],
                    view[1] * world[0] + view[5] * world[1] + view[9] * world[2],
                    view[2] * world[0] + view[6] * world[1] + view[10] * world[2]});
}

HalfAngle half_angle(const Mat4& camera_view, const Vec3& light_direction) {
  // The camera's forward axis in world space (the view matrix's third row, negated), and the
  // light's travel direction (from the light into the scene).
  const Vec3 forward = normalize({-camera_view[2], -camera_view[6], -camera_view[10]});
  const Vec3 travel = normalize({-light_direction[0], -light_direction[1], -light_direction[2]});
  HalfAngle h;
  h.eye_front_to_back = dot(forward, travel) >= 0;  // the light is behind the viewer
  // Slices run away from the light: along forward + travel when both point into the scene,
  // else along travel - forward (towards the viewer, from the far side the light comes from).
  Vec3 s = h.eye_front_to_back ? Vec3{forward[0] + travel[0], forward[1] + travel[1], forward[2] + travel[2]}
                               : Vec3{travel[0] - forward[0], travel[1] - forward[1], travel[2] - forward[2]};
  s = dot(s, s) > 1e-12f ? normalize(s) : travel;
  // A view looking along s: front to back in it is ascending along s.
  const Vec3 up = std::abs(s[1]) > 0.9f ? Vec3{1, 0, 0} : Vec3{0, 1, 0};
  h.sort_view = look_at({0, 0, 0}, s, up);
  return h;
}

SliceStarts slice_starts(std::span<const ParticleBatch> batches, const Mat4& sort_view, int slices,
                         std::uint64_t total) {
  SliceStarts out;
  out.slices = std::clamp(slices, 1, kMaxSlices);
  const auto n = static_cast<std::uint64_t>(out.slices);
  for (std::uint64_t k = 0; k <= n; ++k) out.starts[k] = total * k / n;  // equal counts, the fallback
  std::uint64_t batch_total = 0;
  for (const ParticleBatch& b : batches) batch_total += b.count;
  if (n < 2 || total == 0 || batch_total == 0) return out;
  // Each batch's share of the samples, spread evenly through its records, as the depths the sort
  // orders by (front to back: ascending).
  std::array<float, kSliceSamples> depth;
  std::size_t m = 0;
  std::uint64_t before = 0;  // particles of the batches before this one
  for (const ParticleBatch& b : batches) {
    const bool paired = b.pair != nullptr;
    const std::span<const std::byte> first = paired ? b.pair->a : b.first,
                                     second = paired ? std::span<const std::byte>{} : b.second;
    const std::uint64_t stored = paired ? b.pair->a_count : b.count;
    const std::size_t rs = paired ? b.pair->record_size : b.record_size;
    const std::size_t end = std::size_t((before + b.count) * kSliceSamples / batch_total);
    const std::size_t take = end - std::min(end, std::size_t(before * kSliceSamples / batch_total));
    before += b.count;
    if (stored == 0 || rs < 12) continue;
    const sort::DepthAxis axis = sort::depth_axis(multiply(sort_view, b.world));  // the sort's own depth
    for (std::size_t t = 0; t < take; ++t) {
      const std::size_t at = std::size_t((2 * t + 1) * stored / (2 * take)) * rs;  // the middle of its share
      const std::byte* r = at + 12 <= first.size()                   ? first.data() + at
                           : at - first.size() + 12 <= second.size() ? second.data() + (at - first.size())
                                                                     : nullptr;
      float d = 0;
      if (r != nullptr) sort::compute_depths(r, 1, rs, axis, &d);
      if (r != nullptr && std::isfinite(d)) depth[m++] = d;
    }
  }
  if (m < 2) return out;
  const auto [lo, hi] = std::minmax_element(depth.begin(), depth.begin() + std::ptrdiff_t(m));
  const double low = *lo, range = double(*hi) - low;
  if (!(range > 0)) return out;
  // The samples' depths in kBins bins of equal depth (a histogram, not a sort: its cost grows with
  // the samples alone). Across a bin both shares grow linearly, the particles' by its count over
  // m and the depth's by 1 / kBins; slice k starts where their sum reaches 2k / slices.
  constexpr std::size_t kBins = 1024;
  std::array<std::uint32_t, kBins> bins{};
  for (std::size_t t = 0; t < m; ++t)
    ++bins[std::min(kBins - 1, static_cast<std::size_t>((double(depth[t]) - low) / range * double(kBins)))];
  std::size_t b = 0;
  std::uint64_t below = 0;  // samples in the bins before b
  for (std::uint64_t k = 1; k < n; ++k) {
    const double target = 2.0 * double(k) / double(n);
    while (b < kBins && double(below + bins[b]) / double(m) + double(b + 1) / double(kBins) < target)
      below += bins[b++];
    double at = 1.0;  // the share of the order, 0..1
    if (b < kBins) {
      const double start_share = double(below) / double(m) + double(b) / double(kBins);
      const double width = double(bins[b]) / double(m) + 1.0 / double(kBins);
      at = (double(below) + (target - start_share) / width * double(bins[b])) / double(m);
    }
    const auto start = static_cast<std::uint64_t>(std::llround(double(total) * std::clamp(at, 0.0, 1.0)));
    out.starts[k] = std::clamp(start, out.starts[k - 1], total);
  }
  return out;
}

namespace {

Mat4 orthographic(float half_width, float near, float far) {
  Mat4 m{};
  m[0] = 1.0f / half_width;
  m[5] = 1.0f / half_width;
  m[10] = -2.0f / (far - near);
  m[14] = -(far + near) / (far - near);
  m[15] = 1.0f;
  return m;
}

}  // namespace

SpriteLights sprite_lights(const Mat4& camera_view, const Vec3& light_direction) {
  const Vec3& l = light_direction;
  return {view_direction(camera_view, l), view_direction(camera_view, {-l[0], 0.35f, -l[2]})};
}

ShadowLight shadow_light(const std::array<float, 6>& bounds, const Mat4& camera_view, const Vec3& light_direction) {
  const Vec3 lo{bounds[0], bounds[1], bounds[2]}, hi{bounds[3], bounds[4], bounds[5]};
  Vec3 center{(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2};
  float radius = 0.5f * std::sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) +
                                  (hi[2] - lo[2]) * (hi[2] - lo[2]));
  if (!(radius > 0) || !std::isfinite(radius)) {  // no bounds: around what the camera looks at
    const Mat4& v = camera_view;
    const Vec3 eye{-(v[0] * v[12] + v[1] * v[13] + v[2] * v[14]), -(v[4] * v[12] + v[5] * v[13] + v[6] * v[14]),
                   -(v[8] * v[12] + v[9] * v[13] + v[10] * v[14])};
    const float dist = std::sqrt(eye[0] * eye[0] + eye[1] * eye[1] + eye[2] * eye[2]);
    radius = std::max(dist * 0.5f, 1e-3f);
    center = {eye[0] - v[2] * dist, eye[1] - v[6] * dist, eye[2] - v[10] * dist};
  }
  const Vec3& ld = light_direction;
  const Vec3 light_eye{center[0] + ld[0] * 2 * radius, center[1] + ld[1] * 2 * radius, center[2] + ld[2] * 2 * radius};
  const Vec3 up = std::abs(ld[1]) > 0.9f ? Vec3{1, 0, 0} : Vec3{0, 1, 0};
  return {look_at(light_eye, center, up), orthographic(radius * 1.05f, radius * 0.5f, radius * 3.5f)};
}

}  // namespace pstream::render
