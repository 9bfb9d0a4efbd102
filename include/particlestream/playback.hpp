// Playback: the per-frame work between the stream and the screen, owned by the library.
//
// A Player owns one or more clips (each a stream::ParticleStream: the chunk cache and its
// playhead), their world transforms, the depth sorters and every scratch buffer. Each host frame
// the application calls advance(dt, view) and gets the frame ready to draw: per clip, the
// records contiguous in memory, the draw order, the layout facts a renderer needs and the world
// transform; several clips are sorted together so that where they overlap they blend in depth
// order. draw_data(style) describes that frame in the GL-free frame model (frame.hpp), and a
// renderer draws it: render::Renderer::draw(player.draw_data(style)), or an engine's own. This
// library neither includes nor links a renderer. An application is its own argument parsing,
// window or image output, and these calls; the viewer, `pstream render` and `pstream demo` are
// exactly that.
//
// Memory is fixed when the Player opens (the clips' caches, the sorters, the scratch for an
// interpolated frame); advance() and draw_data() allocate nothing.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <span>
#include <string_view>
#include <vector>

#include "particlestream/frame.hpp"
#include "particlestream/sort.hpp"
#include "particlestream/stream.hpp"

namespace pstream::playback {

// How a host frame between two cached frames is made (docs/playback.md).
enum class Interpolation {
  None,     // the nearest cached frame
  Linear,   // particles matched by id move in straight lines; births and deaths grow and shrink
  Hermite,  // the same along cubic Hermite curves through positions and velocities (when present)
};

// "none", "linear" or "hermite"; throws pstream::Error naming `interpolation` otherwise.
Interpolation parse_interpolation(std::string_view name);

// Where the per-frame work (interpolation between cached frames, the depth sort) happens.
enum class PlaybackPath {
  // On the GPU: advance() hands each clip's pair of cached frames and its pair table to the
  // renderer (ParticleBatch::pair, frame.hpp), which uploads each cached frame once and
  // interpolates, sorts and draws in compute shaders (render::Renderer does; an engine may, with
  // the rules in docs/embedding.md). The host thread's cost per frame does not grow with the
  // particle count. What the viewer, `pstream render` and `pstream demo` use.
  Gpu,
  // On the host thread: advance() interpolates and sorts, and batches() holds the records
  // (the reference, and for hosts that want the records on the CPU).
  Cpu,
};
// "gpu" or "cpu"; throws pstream::Error naming `playback` otherwise.
PlaybackPath parse_playback_path(std::string_view name);

struct PlayerOptions {
  Interpolation interpolation = Interpolation::Hermite;
  // The CPU path by default here, because batches() then holds the records a host can read; a
  // renderer that runs compute shaders asks for Gpu (the apps do, unless told `--playback cpu`).
  PlaybackPath path = PlaybackPath::Cpu;
  // For every clip (`blocking` for offline rendering: no frame skipped); `io` is not used: see below.
  stream::StreamOptions stream;
  // Where each clip's bytes come from (an engine's file system, a pak), one per clip; empty (or a
  // null entry): the clip's file.
  std::vector<std::unique_ptr<io::ByteSource>> io;
  sort::SorterOptions sorter;
  bool loop = true;
};

// How the frame is drawn.
struct DrawStyle {
  render::Look look = render::Look::Sprites;
  render::BlendMode blend = render::BlendMode::Alpha;  // sprites
  float size_multiplier = 1.0f;
  std::string texture;  // a sprite image (PNG); empty: the soft round sprite
  // Look::Liquid: every clip drawn as one liquid surface. draw() fills in its light buffer's bounds
  // and the ground its shadow falls on, as for sprites.
  render::LiquidStyle liquid;
  std::optional<render::Backdrop> backdrop;  // drawn first when set (sky and ground grid)
  bool bounds_box = false;                   // the clips' world bounds as lines
  // Look::Sprites: colour, light, shadows, motion and tone. draw() fills in what it knows: the
  // light buffer's bounds (the clips' world bounds) and the ground (the backdrop's).
  render::SpriteStyle sprites;
  std::string ramp_attribute;  // a float attribute for ColorBy::Attribute ("age", "temperature")
  // Per clip (in open order; up to 8): multiplies its colours, to tell overlapping clips apart.
  std::array<std::array<float, 4>, 8> clip_tints = white_tints();
  static std::array<std::array<float, 4>, 8> white_tints();
  // Distinct tints for clips 1.. (clip 0 keeps its colours): a palette for --tint-clips.
  static std::array<std::array<float, 4>, 8> distinct_tints();
};

// How advance() should sort for a draw in `style` seen through `camera_view`: not at all unless
// the style draws alpha-blended sprites (the only look that depends on the order); for the
// camera, as `requested`; or, for self-shadowed sprites, front to back along the half-angle
// between the view and the light (render::half_angle), which the slices need.
struct SortPlan {
  render::Mat4 view = render::identity();
  sort::SortMode mode = sort::SortMode::BackToFront;
};
SortPlan sort_plan(const DrawStyle& style, const render::Mat4& camera_view, const render::Vec3& light_direction,
                   sort::SortMode requested);

// A look by name: "sprites" (the defaults), "smoke" (self-shadowed, soft), "sparks" (additive,
// unlit, motion-blurred), "liquid-sprites" (lit droplets coloured by speed), "liquid" (the
// screen-space surface), "debug" (stored colours, flat, linear). Throws pstream::Error naming
// the choices for another name.
DrawStyle look_preset(std::string_view name);

// How sprites are coloured, by name, as `pstream render --color-by/--ramp/--ramp-range/
// --ramp-attribute` and the browser player's parameters give it; each empty is left as the look
// has it. A `ramp_attribute` alone colours by that attribute. Throws pstream::Error for an
// unknown name (with "did you mean") or a range whose low end is not below its high end.
struct Colouring {
  std::string color_by;  // "stored", "speed", "attribute"
  std::string ramp;      // "fire", "ice", "viridis", "grey"
  std::optional<std::array<float, 2>> range;
  std::string ramp_attribute;
};
void apply_colouring(const Colouring& colouring, DrawStyle& style);

// What is drawn behind the particles, by name, as `pstream render --backdrop` and the browser
// player's `backdrop=` give it: "auto" (a ground grid under the clip's `bounds` for the liquid and
// for self-shadowing sprites, whose shadows fall on it; nothing for other looks, which draw over
// the plain background), "ground", "sky" (the gradient alone) or "none". Throws OptionError for
// another name (with "did you mean").
std::optional<render::Backdrop> backdrop_for(std::string_view choice, const DrawStyle& style,
                                             const std::array<float, 6>& bounds);
// "auto"'s rule: whether the look wants the ground.
bool wants_ground(const DrawStyle& style);

// Throws OptionError naming the setting when `style` asks for what the clip `clip` (named `name`
// in the message) lacks: colouring by speed or motion blur without velocities (the message names
// the cook flag that adds them), a `ramp_attribute` that is not one of its float attributes (the
// message lists the ones it has), or colouring by attribute with none named. Player::check_style
// asks it of every clip; the browser player of its one.
void check_style(const DrawStyle& style, const format::Metadata& clip, std::string_view name);

// The automatic colour-ramp range of sampled `values` (reordered): speeds (`speeds` true) from 0
// to their 99th percentile, an attribute from its 1st to its 99th percentile; {0, 1} for fewer
// than two values, and LOW + 1 as the top when the values are all one.
std::array<float, 2> ramp_range_of(std::span<float> values, bool speeds);

// The automatic camera, one rule for `pstream render`, the viewer and the demo: a track over the
// seconds shown (by default the whole clip) that follows the effect.
//
// Its keys frame a frame's particles: per axis their 0.5th to 99.5th percentile (so that a few
// stray particles do not shrink the clip into a corner), the points inside it with the largest
// particle's radius around each, by render::Camera::framing. Keys lie at the first and last frames
// shown, at least every half second, and wherever a frame's extent (its stored bounds, within the
// box of the sampled frames below) has grown or shrunk by a quarter since the last key, or its
// centre has moved by a quarter of it. The view's direction never changes. The camera pulls back
// at once when the effect grows, and comes in by at most 30 % a second when it shrinks. Between
// keys the target moves linearly; the distance is the next key's when that is farther (the effect
// grows between them), else it shrinks geometrically. So an effect that grows from a point fills
// the image from its first frame. Making the track decodes the frames shown once.
struct CameraTrack {
  struct Key {
    double time = 0.0;  // clip seconds
    render::Camera camera;
  };
  std::vector<Key> keys;  // in time order, at least one
  // The camera at `seconds`: the first key's before it, the last one's after it.
  render::Camera at(double seconds) const;
};
// `region` frames them in part of the image (Camera::framing's region: x0, y0, x1, y1 as fractions
// from the top left), as the viewer does beside its panel. One key with the default camera when no
// clip has a particle.
CameraTrack framing_track(std::span<const std::filesystem::path> files, float aspect,
                          const std::array<float, 4>& region = {0.0f, 0.0f, 1.0f, 1.0f},
                          const std::array<double, 2>& seconds = {-INFINITY, INFINITY});
// One camera for all of those seconds (`render --camera fixed`, the viewer's F key): the same rule
// on four frames of each clip (a quarter, half, three quarters and the end of those shown), and
// their box (the clips' whole bounds when that finds too few particles).
std::array<float, 6> framing_box(std::span<const std::filesystem::path> files,
                                 const std::array<double, 2>& seconds = {-INFINITY, INFINITY});
render::Camera framing_camera(std::span<const std::filesystem::path> files, float aspect,
                              const std::array<float, 4>& region = {0.0f, 0.0f, 1.0f, 1.0f},
                              const std::array<double, 2>& seconds = {-INFINITY, INFINITY});

// The automatic colour-ramp range, for the same frames: speeds (the `velocity` attribute's
// magnitude, `attribute` empty) from 0 to their 99th percentile, or a float attribute from its
// 1st to its 99th percentile, so that the ramp spans what the clip holds whatever its units
// (an explosion at 40 m/s, a drip at 0.1). {0, 1} when no clip has the attribute.
std::array<float, 2> ramp_range(std::span<const std::filesystem::path> files, const std::string& attribute = {});

// Where the time of a host frame went (milliseconds, this frame).
struct FrameStats {
  double stream_ms = 0.0;  // update() of every clip
  double sort_ms = 0.0;
  double interpolate_ms = 0.0;  // blending two cached frames (when between them)
  // The GPU path: making pair tables (only when a clip reaches a new pair of cached frames).
  double pair_table_ms = 0.0;
  std::uint64_t particles = 0;
  std::size_t failed_clips = 0;  // clips in the Error state (they draw nothing; check() throws their error)
  // Clips between two frames whose particles the stream could not match (no ids and no codec
  // matching, or too many changes): they show the nearer frame moved along its velocities.
  std::size_t unmatched_clips = 0;
};

class Player {
 public:
  // Opens every clip (each sizes and allocates its cache once) and everything a frame needs.
  // Throws pstream::Error naming the file that could not be opened.
  static std::unique_ptr<Player> open(std::span<const std::filesystem::path> files, PlayerOptions options = {});
  ~Player();
  Player(const Player&) = delete;
  Player& operator=(const Player&) = delete;

  std::size_t clip_count() const;
  stream::ParticleStream& clip(std::size_t i);  // its playhead, state and statistics
  const stream::ParticleStream& clip(std::size_t i) const;
  // Object -> world of clip i (column-major, as OpenGL takes it); identity until set.
  void set_world_transform(std::size_t i, const render::Mat4& world);
  const render::Mat4& world_transform(std::size_t i) const;

  // The playhead of every clip together (clip times, seconds). Retiming: `speed` scales the host
  // clock (0 holds the current, possibly in-between, moment; 0.25 is slow motion, interpolated
  // at any host rate; negative plays backwards, interpolated too, at the cost stream.hpp gives);
  // play stays within [start, end] of set_range, and at its end either loops to the other end or
  // holds the last frame shown.
  void play();
  void pause();
  void stop();
  void seek(double time);
  void set_speed(double speed);
  void set_loop(bool loop);
  void set_range(double start, double end);

  // One host frame: advances every clip by `dt` seconds and prepares its records for drawing,
  // sorted for the camera `view` (world -> view) as `mode` asks (None: stored order; use it for
  // additive blending). A clip that has failed (a read or decode error) draws nothing from then
  // on; the frame goes on with the others, and check() reports it.
  const FrameStats& advance(double dt, const render::Mat4& view, sort::SortMode mode);
  // Throws pstream::Error with the error of the first clip that failed.
  void check() const;
  // The batches advance() prepared (one per clip with particles), for a custom renderer, and
  // the merged order when several clips were sorted together (entries are
  // (batch << sort::DepthSorter::kMergedIndexBits) | index), empty otherwise.
  std::span<const render::ParticleBatch> batches() const;
  // The batch of clip i in batches(), or -1 when it has none this frame (no particles, failed).
  std::ptrdiff_t batch_of(std::size_t clip) const;
  // What the last advance() measured.
  const FrameStats& stats() const { return stats_; }
  std::span<const std::uint32_t> merged_order() const;
  // What advance() prepared, styled for drawing: each batch's blend, size, texture, tint and
  // ramp attribute from `style`, the light buffer's bounds and the ground filled in from the
  // clips' world box. Valid until the next advance() or draw_data(); allocates nothing.
  const render::DrawData& draw_data(const DrawStyle& style);
  // Throws OptionError naming the setting when `style` asks for what a clip lacks: colouring by
  // speed or motion blur on a clip without velocities (the message names the cook flag that adds
  // them), a `ramp_attribute` that is not one of every clip's float attributes (the message lists
  // the ones it has), or colouring by attribute with none named. Call it once, before drawing.
  void check_style(const DrawStyle& style) const;

  // The bytes every clip's frame can take at most (an interpolated frame holds the particles of
  // both cached frames at most): what a renderer's buffers must hold.
  std::uint64_t max_frame_bytes() const;
  PlaybackPath path() const { return path_; }

 private:
  Player() = default;
  struct Clip;
  struct TableThread;  // the GPU path: makes the next pair's table off the host thread
  std::uint64_t gpu_pair(Clip& c, const stream::FrameView& f);  // the GPU path: fills c's FramePair
  std::vector<Clip> clips_;
  std::unique_ptr<TableThread> tables_;  // (declared after clips_: it ends before they do)
  std::unique_ptr<sort::DepthSorter> merged_sorter_;
  std::vector<render::ParticleBatch> batches_;  // one slot per clip; the first batch_count_ are this frame's
  std::size_t batch_count_ = 0;
  std::vector<Clip*> sorted_by_;  // the clip of each batch
  std::vector<sort::DepthSorter::Source> sources_;
  std::span<const std::uint32_t> merged_order_;
  render::DrawData draw_data_;
  FrameStats stats_;
  Interpolation interpolation_ = Interpolation::Hermite;
  PlaybackPath path_ = PlaybackPath::Cpu;
  render::SortMode sort_mode_ = render::SortMode::None;
  render::Mat4 sort_view_ = render::identity();
};

}  // namespace pstream::playback
