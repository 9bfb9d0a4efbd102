// The frame model: what a frame of particles is and how it is to look, with no graphics API in
// it. The playback layer fills it (batches of records, an order, the styles); a renderer consumes
// it — the OpenGL one in render.hpp, or an engine's own — as Dear ImGui's backends consume its
// draw data. Math (column-major 4x4 matrices), the camera and its framing rule, the batches, the
// sprite, liquid and backdrop styles.
#pragma once

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

namespace pstream::render {

using Mat4 = std::array<float, 16>;  // column-major, as OpenGL takes it
using Vec3 = std::array<float, 3>;

Mat4 identity();
Mat4 multiply(const Mat4& a, const Mat4& b);  // a * b
Mat4 translation(const Vec3& t);
Mat4 look_at(const Vec3& eye, const Vec3& target, const Vec3& up);
Mat4 perspective(float fov_y_degrees, float aspect, float near, float far);
Vec3 view_direction(const Mat4& view, const Vec3& world);  // a world direction in view space, normalised

struct Camera {
  Vec3 eye{0, 0, 5}, target{0, 0, 0}, up{0, 1, 0};
  float fov_y_degrees = 45.0f, near = 0.01f, far = 1000.0f;
  // A lens shift: where the view's centre lands on the image, in normalised device coordinates
  // (0, 0: the image's centre). Lets a clip be framed in part of a window (the viewer's, beside
  // its panel) while the perspective stays the camera's.
  std::array<float, 2> shift{0.0f, 0.0f};
  Mat4 view() const { return look_at(eye, target, up); }
  Mat4 projection(float aspect) const {
    Mat4 m = perspective(fov_y_degrees, aspect, near, far);
    m[8] = -shift[0];  // x_ndc += shift.x (the clip-space w is -z)
    m[9] = -shift[1];
    return m;
  }
  // A camera at `eye` looking at `target` (`pstream render --camera eye:target`, the browser's
  // `camera=`), its near and far planes from their distance d: max(0.001, d / 1000) and 100 d + 100.
  static Camera looking(const Vec3& eye, const Vec3& target);
  // A camera that frames the box [lo, hi] from a three-quarter view above the front, as close as
  // keeps all of it in a view of this width / height.
  static Camera framing(const Vec3& lo, const Vec3& hi, float aspect = 16.0f / 9.0f);
  // The same framing inside the region [x0, x1] x [y0, y1] of an image of this aspect (fractions
  // of its width and height from the top left): the box fills that region, through a lens shift.
  static Camera framing(const Vec3& lo, const Vec3& hi, float aspect, const std::array<float, 4>& region);
  // The same view direction, as close as keeps every point (and `pad` around each: a particle's
  // radius) inside that region: tighter than their box, whose corners are often empty.
  static Camera framing(std::span<const Vec3> points, float pad, float aspect, const std::array<float, 4>& region);
};

enum class BlendMode { Alpha, Additive, AlphaTest };

// Which way particles are ordered by their depth along a view (sort.hpp sorts on the CPU,
// render::GpuSorter on the GPU): not at all, far to near (alpha blending), near to far (the
// self-shadow slices along the half-angle).
enum class SortMode { None, BackToFront, FrontToBack };

struct FramePair;                                // below
BlendMode parse_blend(const std::string& name);  // "alpha", "additive", "alphatest"

// One stream's frame, as the stream hands it out.
struct ParticleBatch {
  std::span<const std::byte> first, second;  // the records (second: a second part, when not contiguous)
  std::uint64_t count = 0;
  std::uint32_t record_size = 16;
  std::int32_t color_offset = -1;  // an RGBA8 attribute in the record, or -1
  // A float32 x3 velocity (units per second) in the record, or -1: as cooked, and between cached
  // frames the derivative of the interpolated motion (playback.hpp), for motion blur and
  // stretched sprites.
  std::int32_t velocity_offset = -1;
  std::int32_t scalar_offset = -1;       // a float32 attribute for ColorBy::Attribute, or -1
  Mat4 world = identity();               // object -> world
  std::span<const std::uint32_t> order;  // draw order (back to front); empty: stored order
  BlendMode blend = BlendMode::Alpha;
  std::array<float, 4> color{0.45f, 0.65f, 0.95f, 0.9f};  // when the record has no colour
  std::array<float, 4> tint{1, 1, 1, 1};                  // multiplies this stream's colours (telling streams apart)
  float size_multiplier = 1.0f;
  std::string texture;  // optional sprite image (PNG); empty: the soft round sprite
  // The GPU path (playback.hpp: PlaybackPath::Gpu): when set, `first` and `second` are empty and
  // the renderer makes the `count` records on the GPU from this pair of cached frames (and sorts
  // them as DrawData::sort says); `order` is empty.
  const FramePair* pair = nullptr;
};

// ---- Sprites: colour, light, motion -------------------------------------------------------------

// Where a sprite's colour comes from: the record's colour (Cd) or the batch's, or a ramp over the
// particle's speed (from its velocity) or over a float attribute (ParticleBatch::scalar_offset).
enum class ColorBy { Stored, Speed, Attribute };
ColorBy parse_color_by(const std::string& name);  // "stored", "speed", "attribute"

// A colour ramp: up to 8 stops spread evenly over [low, high] (values outside take the end
// colours), linear RGB.
struct Ramp {
  std::array<std::array<float, 3>, 8> stops{};
  int count = 0;
  float low = 0.0f, high = 1.0f;
  std::array<float, 3> at(float value) const;  // what the shaders compute, for tests and tools
  // "fire" (black, red, orange, yellow, white), "ice", "viridis", "grey".
  static Ramp named(const std::string& name, float low, float high);
};

enum class ToneMap {
  Filmic,  // a filmic curve on each pixel's largest channel, scaling the others with it: bright
           // additive light saturates towards its own hue, never to white
  Linear,  // exposure, then clamp (what 8-bit additive blending did before HDR)
};
ToneMap parse_tone_map(const std::string& name);  // "filmic", "linear"

// How sprites are coloured, lit and moved. Sprites accumulate in a half-float buffer and are
// tone-mapped over what is already drawn (the backdrop).
struct SpriteStyle {
  ColorBy color_by = ColorBy::Stored;
  Ramp ramp = Ramp::named("fire", 0.0f, 1.0f);
  std::array<float, 4> tint{1, 1, 1, 1};  // multiplies every colour (a stream's tint)
  float opacity = 1.0f;                   // multiplies alpha
  bool lit = true;                        // key/fill/rim lighting of a sphere under the sprite; false: flat colour
  // Volumetric self-shadowing by half-angle slicing (Green 2008): the particles are sorted along
  // the vector halfway between the view and the light (sort_for_shadows()) and drawn in
  // `slices` batches, each into the eye buffer (lit by what the light buffer lets through) and
  // then into the light buffer (as opacity × shadow_density). The ground receives the light
  // buffer's final shadow.
  bool shadows = false;
  int slices = 32;              // 1..kMaxSlices (256)
  float shadow_density = 1.0f;  // a particle's opacity to light, × its alpha
  bool shadow_blur = true;      // a 5-tap blur when the light buffer is read
  int shadow_resolution = 512;  // the light buffer's size, 64..4096
  float ground_shadow = 0.8f;   // how dark the ground gets under an opaque column: 0.8 leaves it 20 % of its light
  std::array<float, 6>
      bounds{};  // world box the light buffer covers (lo xyz, hi xyz); all 0: the camera's target ± its distance
  std::optional<float> ground_height;  // a ground plane that receives the shadows (and hides what is under it)
  // Motion: sprites stretch along their screen-space velocity over `shutter` seconds (0: round
  // sprites), keeping their energy (a longer streak is fainter).
  float shutter = 0.0f;
  // Below `min_pixels` of radius a sprite is drawn at that radius with its alpha scaled by the
  // area it lost, so a receding cloud keeps its brightness instead of flickering away.
  float min_pixels = 1.0f;
  float exposure = 1.0f;
  ToneMap tone_map = ToneMap::Filmic;
  // Bloom: this share (0..1) of the accumulated light moves into a Gaussian blur of it, whose
  // sigma is `bloom_radius` image heights, before the tone map. Bright light spreads into a glow
  // around it; the light's total stays the same. 0: none.
  float bloom = 0.0f;
  float bloom_radius = 0.02f;
};

// The order self-shadowed sprites are drawn in: sort front to back in `sort_view` (whose view
// axis is the half-angle vector), and whether the eye buffer then blends front to back (the
// light is behind the viewer) or back to front.
struct HalfAngle {
  Mat4 sort_view = identity();
  bool eye_front_to_back = true;
};
HalfAngle half_angle(const Mat4& camera_view, const Vec3& light_direction);

// Where each self-shadowing slice starts in the drawing order (front to back in `sort_view`, as
// half_angle() gives it), for `slices` slices (1..kMaxSlices) of `total` particles: starts[k] for
// k = 0..slices, starts[0] = 0 and starts[slices] = total, never decreasing (a slice may be
// empty). Equal numbers of particles make a slice through a sparse part of the cloud thick in
// depth, and its particles do not shadow each other: bands across the top of a smoke plume, where
// few particles share a range of depth. So each slice takes an equal share of the two together,
// its part of the particles plus its part of the depth range (2 / slices): a dense core's slices
// are bounded by their counts, a sparse edge's by their depth. The depths are read from up to
// kSliceSamples particles spread evenly through each batch's records (a FramePair's earlier
// cached frame where the records are made on the GPU), so the drawing order itself is not needed
// (with 512 a slice through the last few particles at the plume's top stayed thick); no
// allocation, and no sort: the samples' depths are counted in bins.
constexpr int kMaxSlices = 256;
constexpr std::size_t kSliceSamples = 4096;
struct SliceStarts {
  std::array<std::uint64_t, kMaxSlices + 1> starts{};
  int slices = 1;
};
SliceStarts slice_starts(std::span<const ParticleBatch> batches, const Mat4& sort_view, int slices,
                         std::uint64_t total);

// The lit sprite's two lights in view space, the directions its fragment shader takes (u_key,
// u_fill): the key along `light_direction` (world, towards the light, unit length), and the fill
// from the opposite side, a little above.
struct SpriteLights {
  Vec3 key{}, fill{};
};
SpriteLights sprite_lights(const Mat4& camera_view, const Vec3& light_direction);

// The light buffer's view for self-shadowed sprites: an orthographic box around the world box
// `bounds` (lo xyz, hi xyz), or, where it is empty or not finite, around what `camera_view` looks
// at, seen along `light_direction` (world, towards the light, unit length).
struct ShadowLight {
  Mat4 view = identity();
  Mat4 projection = identity();
};
ShadowLight shadow_light(const std::array<float, 6>& bounds, const Mat4& camera_view, const Vec3& light_direction);

// How a draw shows its particles: each as a lit round sprite, or the surface of a liquid made
// from them in screen space (below).
enum class Look { Sprites, Liquid };
Look parse_look(const std::string& name);  // "sprites", "liquid"

// Screen-space liquid (van der Laan, Green and Sainz 2009; Truong and Yuksel 2018). Every
// particle is splatted as a sphere into a depth buffer and, additively, into a thickness buffer;
// the depth is smoothed by a two-dimensional filter whose radius is a world-space length (so it
// shrinks with distance in pixels); normals come from the smoothed depth; the surface reflects
// the sky (Fresnel), refracts and absorbs what is behind it by its thickness (Beer-Lambert) and
// takes a highlight from the key light. Isolated or fast particles are drawn over it as white
// spray. Lengths are in particle radii, so one style suits any scene scale.
enum class LiquidFilter {
  NarrowRange,  // Truong and Yuksel: neighbours far in front are another surface (ignored), far
                // behind or empty are clamped just behind: smooth surfaces, sharp silhouettes
  Bilateral,    // Gaussian in space and in depth (the classic filter, for comparison)
  Gaussian,     // depth-blind Gaussian (blends layers: halos; for comparison)
  None,         // the raw sphere splats (what sprites look like as a surface)
};
LiquidFilter parse_liquid_filter(const std::string& name);  // "narrow-range", "bilateral", "gaussian", "none"

enum class LiquidOutput { Shaded, Depth, Normals, Thickness };  // Depth, Normals, Thickness: inspection views
LiquidOutput parse_liquid_output(const std::string& name);      // "shaded", "depth", "normals", "thickness"

struct LiquidStyle {
  float particle_radius = 0.0f;  // world units; 0: the median radius of up to 255 records of the frame
  float resolution = 1.0f;       // depth and thickness buffers at this fraction of the viewport, 0.25..1
  LiquidFilter filter = LiquidFilter::NarrowRange;
  float smoothing = 4.0f;    // filter radius, in particle radii
  int iterations = 2;        // passes of the filter at its full radius (after three smaller ones), 0..8
  float depth_range = 4.0f;  // the narrow range: farther than this (in radii) is another layer
  std::array<float, 3> color{0.30f, 0.66f, 0.82f};  // what `color_depth` of liquid lets through
  float color_depth = 16.0f;                        // in particle radii
  float refraction = 1.0f;                          // how far the normal bends what is behind, 0..4
  // Liquid this thick (in particle radii of summed sphere chords: a layer of touching spheres
  // adds about 1) hides 63 % of what is behind it behind its own lit colour, and blurs the rest;
  // 0: clear as glass.
  float opacity_depth = 2.0f;
  float foam_speed = 0.0f;      // world units per second: faster particles are spray (0: off; needs velocities)
  float foam_isolation = 3.0f;  // particles where the liquid is thinner than this (radii) are spray (0: off)
  LiquidOutput output = LiquidOutput::Shaded;
  // The liquid's shadow on the ground, when there is one (`ground_height`): the particles' sphere
  // chords along the light, summed in a light buffer as self-shadowing sprites' opacities are
  // (shadow_light(), `shadow_resolution` square), darken the ground by 63 % of `shadow_strength`
  // where this many particle radii of liquid lie above it; 0: no shadow. Water lets most light
  // through (it bends it into caustics), so its shadow is lighter than smoke's.
  float shadow_depth = 8.0f;
  float shadow_strength = 0.5f;        // how dark the ground gets under deep liquid: 0.5 halves its light
  int shadow_resolution = 512;         // 64..4096
  std::array<float, 6> bounds{};       // world box the light buffer covers (lo xyz, hi xyz); all 0: as SpriteStyle's
  std::optional<float> ground_height;  // a ground plane that receives the shadow
};

// What the liquid's passes take for one image, derived from its style once for every renderer
// (the native passes and the browser player's; docs/rendering.md, "Liquid"). Lengths in view
// units unless said otherwise.
inline constexpr int kLiquidFilterPairs = 64;   // pairs of taps a filter pass reads
inline constexpr int kLiquidRampPasses = 3;     // passes at 1/8, 1/4 and 1/2 of the filter's radius first
inline constexpr int kLiquidMaxIterations = 8;  // passes at its radius, at most
struct LiquidPasses {
  int width = 1, height = 1;     // the depth, thickness and normal buffers (the style's resolution)
  float radius = 0.01f;          // the particles' radius: the style's, or the median of the image's
  float fixed_radius = 0.0f;     // > 0: every splat's radius in object units (the style's)
  float radius_px_at_1 = 0;      // a particle's radius in buffer pixels at distance 1
  int filter_mode = 0;           // 0 narrow range, 1 bilateral, 2 gaussian
  int filter_passes = 0;         // kLiquidRampPasses + the iterations, or 0 (no filter)
  float filter_radius_at_1 = 0;  // pixels at distance 1
  float range = 0;               // the narrow range: farther in depth is another surface
  float color_depth = 0;
  std::array<float, 3> absorb{};  // per view unit of thickness
  float refraction = 0;
  float opacity_depth = 0;  // 0: clear
  float foam_speed = 0;     // view units per second; 0: off
  float foam_thickness = 0;
  bool spray = false;         // a spray pass after the surface
  float shadow_depth = 0;     // a light-buffer opacity of 1 - exp(-chord / shadow_depth); 0: no shadow
  float shadow_strength = 0;  // the ground's darkening under an opaque column, 0..1
  int shadow_resolution = 512;
};
// The particles' radius in view units is the style's particle_radius times `world_scale` (how much
// the clips' world transform scales lengths), or where the style sets none `image_radius` (the
// median of the image's radii, median_radius, in view units). `projection`: the camera's, for an
// image of width x height.
LiquidPasses liquid_passes(const LiquidStyle& style, float world_scale, float image_radius, const Mat4& projection,
                           int width, int height);
// Filter pass `pass`'s taps: kLiquidFilterPairs pairs on a sunflower (Vogel) spiral over the unit
// disc, the i-th at radius sqrt((i + 0.5) / n) and i golden angles, the whole turned 1.1 radians
// a pass; each (x, y, Gaussian weight for a sigma of half the radius). And the pass's radius, a
// fraction of the filter's.
std::array<float, 3 * kLiquidFilterPairs> liquid_filter_taps(int pass);
float liquid_filter_scale(int pass);
// The median of up to 255 radii spread evenly over `count` particles (radius_at(i) for particle i;
// not finite or not positive: left out); 0.01 when none is left.
template <class RadiusAt>
float median_radius(std::uint64_t count, RadiusAt radius_at) {
  std::array<float, 255> sample{};
  std::size_t n = 0;
  const std::uint64_t want = count < sample.size() ? count : sample.size();
  for (std::uint64_t k = 0; k < want; ++k) {
    const float r = radius_at(count <= want ? k : k * count / want);
    if (std::isfinite(r) && r > 0) sample[n++] = r;
  }
  if (n == 0) return 0.01f;
  std::nth_element(sample.begin(), sample.begin() + std::ptrdiff_t(n / 2), sample.begin() + std::ptrdiff_t(n));
  return sample[n / 2];
}

// The colour behind the particles where no backdrop is drawn: the night blue of `pstream render`,
// the viewer and the browser player (linear RGBA).
inline constexpr std::array<float, 4> kDefaultBackground{0.02f, 0.025f, 0.035f, 1.0f};

// A context for what is drawn: a sky gradient and a ground plane with a grid (which the liquid
// refracts and reflects).
struct Backdrop {
  bool ground = true;
  float ground_height = 0.0f;  // world y of the ground plane
  float grid_spacing = 1.0f;   // world units between grid lines
  // The ground under the box [lo, hi] (y up), with a grid of about ten lines across it.
  static Backdrop under(const Vec3& lo, const Vec3& hi);
};

// Every record starts with the same head (docs/format.md): position float32 x3 at byte 0, scale
// (the particle's radius) float32 at byte kScaleOffset. Shaders and kernels that read records
// take these, never their own numbers.
inline constexpr std::uint32_t kPositionOffset = 0;
inline constexpr std::uint32_t kScaleOffset = 12;
inline constexpr std::uint32_t kRecordHeadSize = 16;

// How interpolation makes each 4-byte word of a record from the two cached frames (the CPU
// kernel, playback/interpolate.hpp, and the GPU one, render::GpuInterpolator, follow the same
// table): copied from the earlier frame (ids, colours' word, integers), blended linearly (scale
// and other floats), or along the Hermite curve (position) and its derivative (velocity).
enum class RecordLane : std::uint8_t { Copy, Lerp, Position, Velocity };

// GPU interpolation's pair table: per particle of the interpolated frame, its index in the
// earlier cached frame (`a`) and the later one (`b`), kNoParticle where it has none (born: only
// b; dying: only a), in the order the CPU path writes them. 8 bytes a particle.
inline constexpr std::uint32_t kNoParticle = 0xFFFFFFFFu;
struct ParticlePair {
  std::uint32_t a = kNoParticle, b = kNoParticle;
};

// What a renderer needs to make a clip's frame itself, on the GPU, between two cached frames:
// both frames' records as the stream decoded them, the pair table, the fraction and the rules.
// A frame's records are the same bytes whenever the same (source, frame) comes again, so a
// renderer uploads each cached frame once and the table once per pair of frames (when
// `pairs_version` changes), and nothing between cached frames.
struct FramePair {
  std::uint64_t source = 0;  // the clip, unique in the process (a renderer keeps buffers per source)
  std::uint32_t record_size = 16;
  std::uint64_t max_count = 0;        // the clip's largest frame: what each cached frame's buffer holds
  std::span<const RecordLane> lanes;  // per word of a record (playback::record_lanes)
  std::int32_t velocity_offset = -1, color_offset = -1;
  std::span<const std::byte> a;  // the earlier cached frame's records
  std::uint64_t a_frame = 0, a_count = 0;
  // Between two frames (`pairs` not empty): the later one, the table (the interpolated frame's
  // particles, in order) and how to blend. Otherwise the frame is `a` as it is.
  std::span<const std::byte> b;
  std::uint64_t b_frame = 0, b_count = 0;
  std::span<const ParticlePair> pairs;
  std::uint64_t pairs_version = 0;  // changes whenever `pairs` holds a new table
  double t = 0.0, dt = 0.0;         // the fraction from a to b, and the seconds between them
  bool hermite = false;             // along curves through the velocities where they describe the matching
  bool nearer = false;              // no matching: the table is the nearer frame, moved along its velocities
  // Optional, ahead of the playhead: the cached frame after `b` once the stream has decoded it and,
  // when its particles are matched to b's, the table from b to it (`ahead_pairs`, empty
  // otherwise). A renderer can copy them towards the GPU on a thread of its own, so that the host
  // frame which reaches them uploads nothing. The bytes are lent: the renderer stores 1 in `*lent`
  // before its thread reads them and 0 once it is done, touching `*lent` no more after (the player
  // polls for 0 before its streams move again, and may then free it).
  std::span<const std::byte> ahead;
  std::uint64_t ahead_frame = 0, ahead_count = 0;
  std::span<const ParticlePair> ahead_pairs;
  std::uint64_t ahead_pairs_version = 0;
  std::atomic<std::uint32_t>* lent = nullptr;
};

// Most batches one merged draw takes: a merged order's entry is (batch << kMergedIndexBits) |
// index (sort::DepthSorter::sort_merged makes it), so 32 - kMergedIndexBits bits name the batch.
inline constexpr unsigned kMergedIndexBits = 28;
inline constexpr std::size_t kMaxMergedBatches = 8;
static_assert(kMaxMergedBatches <= (std::size_t{1} << (32 - kMergedIndexBits)));

// Everything one frame draws, as a renderer takes it: the batches (one per clip with particles),
// their merged order when several clips are sorted together (else empty: each batch in its own
// order), and the look with its styles. The spans point into the producer (the Player) and are
// valid until its next advance().
struct DrawData {
  std::span<const ParticleBatch> batches;
  std::span<const std::uint32_t> merged_order;
  Look look = Look::Sprites;
  SpriteStyle sprites;  // with `bounds` and `ground_height` filled in
  LiquidStyle liquid;
  std::optional<Backdrop> backdrop;         // drawn first when set
  std::optional<std::array<float, 6>> box;  // the clips' world box as lines, when asked for
  // The GPU path: how the renderer is to order the batches' records it makes (the CPU path
  // ordered them already: ParticleBatch::order, merged_order), by depth along `sort_view`
  // (world -> view: the camera, or the half-angle for self-shadowed sprites); several batches
  // are sorted together.
  SortMode sort = SortMode::None;
  Mat4 sort_view = identity();
};

}  // namespace pstream::render
