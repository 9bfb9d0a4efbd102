// ParticleStream C++ API (C++20): RAII handles and exceptions over the C API
// (particlestream.h), header-only, so it is exactly as stable as the C ABI underneath: nothing
// of the C++ library's types crosses into the host, and a host built with another compiler or
// standard library links the same libparticlestream.so.
//
//   particlestream::PlayerOptions options;
//   options.cache_seconds = 2;
//   particlestream::Player player({"splash.pstream"}, options);   // throws particlestream::Error
//   player.play();
//   each host frame:
//     player.update(dt, view);                  // stream, interpolate, sort; allocates nothing
//     particlestream::Frame f = player.frame(0);
//     for (std::uint32_t i : f.draw_order()) draw(f.position(i));
//
// Errors are particlestream::Error (a std::runtime_error) carrying the C API's pstream_result
// and the library's message (file, frame or offset, and what was expected). Handles are movable,
// not copyable, and close in their destructors. Spans returned by a handle are valid until its
// next non-const call, as in the C API.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <functional>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "particlestream/particlestream.h"

namespace particlestream {

class Error : public std::runtime_error {
 public:
  Error(pstream_result code, const std::string& message) : std::runtime_error(message), code_(code) {}
  pstream_result code() const noexcept { return code_; }

 private:
  pstream_result code_;
};

// Throws Error with this thread's last message unless `result` is PSTREAM_OK.
inline void check(pstream_result result) {
  if (result != PSTREAM_OK) throw Error(result, pstream_last_error());
}

// The library's version as built (PSTREAM_VERSION layout), and whether it can serve this header.
inline std::uint32_t version() { return pstream_version(); }
inline bool compatible() { return pstream_version() / 10000 == PSTREAM_VERSION_MAJOR; }

using Attribute = pstream_attribute;
using ClipInfo = pstream_clip_info;
using PlayerStats = pstream_player_stats;

namespace detail {
// A C handle with its close function, movable and not copyable.
template <class T, pstream_result (*Close)(T*)>
class Handle {
 public:
  Handle() = default;
  explicit Handle(T* h) : h_(h) {}
  Handle(Handle&& o) noexcept : h_(std::exchange(o.h_, nullptr)) {}
  Handle& operator=(Handle&& o) noexcept {
    if (this != &o) {
      reset();
      h_ = std::exchange(o.h_, nullptr);
    }
    return *this;
  }
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  ~Handle() { reset(); }
  void reset() {
    if (h_ != nullptr) (void)Close(h_);  // a handle this object owns is open
    h_ = nullptr;
  }
  T* get() const { return h_; }

 private:
  T* h_ = nullptr;
};
}  // namespace detail

// ---- Alembic archives ---------------------------------------------------------------------

struct PointsObject {
  std::string full_name;
  std::uint32_t samples = 0;
};

class Archive {
 public:
  explicit Archive(const std::string& path) {
    pstream_archive* a = nullptr;
    check(pstream_archive_open(path.c_str(), &a));
    h_ = Handle(a);
  }
  std::size_t points_count() const {
    std::size_t n = 0;
    check(pstream_archive_points_count(h_.get(), &n));
    return n;
  }
  PointsObject points(std::size_t index) const {
    const char* name = nullptr;
    PointsObject o;
    check(pstream_archive_points_info(h_.get(), index, &name, &o.samples));
    o.full_name = name;
    return o;
  }
  // Particles in a sample and its time in seconds.
  std::pair<std::uint64_t, double> sample(std::size_t index, std::uint32_t sample) const {
    std::pair<std::uint64_t, double> r{};
    check(pstream_archive_points_sample(h_.get(), index, sample, &r.first, &r.second));
    return r;
  }
  // The sample's positions, xyz per particle, object space.
  std::vector<float> positions(std::size_t index, std::uint32_t sample) const {
    std::vector<float> out(3 * this->sample(index, sample).first);
    check(pstream_archive_read_positions(h_.get(), index, sample, out.data(), out.size()));
    return out;
  }
  pstream_archive* get() const { return h_.get(); }

 private:
  using Handle = detail::Handle<pstream_archive, pstream_archive_close>;
  Handle h_;
};

// ---- Cooking --------------------------------------------------------------------------------

struct CookOptions {
  std::string input, output;
  std::string object;      // empty: the only points object
  std::string attributes;  // "velocity,id,age"; empty: position, scale, colour
  double fps = 0;          // 0: the source's
  pstream_codec codec = PSTREAM_CODEC_PARTICLE;
  double error = 1e-4;  // the particle codec's bound, a fraction of the bounds diagonal
  bool interpolate = false;
  // Called after each frame with (done, total); return false to cancel (the cook then throws
  // Error with PSTREAM_ERROR_STATE and writes nothing).
  using Progress = std::function<bool(std::uint64_t, std::uint64_t)>;
  Progress progress;
};

namespace detail {
// `options` as the C API's struct; its strings and callback stay `options`'s.
inline pstream_cook_options to_c(const CookOptions& options) {
  pstream_cook_options o;
  pstream_cook_options_init(&o);
  o.input = options.input.empty() ? nullptr : options.input.c_str();
  o.output = options.output.c_str();
  o.object = options.object.empty() ? nullptr : options.object.c_str();
  o.attributes = options.attributes.empty() ? nullptr : options.attributes.c_str();
  o.fps = options.fps;
  o.codec = options.codec;
  o.error = options.error;
  o.interpolate = options.interpolate ? 1 : 0;
  if (options.progress) {
    o.progress = [](void* user, std::uint64_t done, std::uint64_t total) {
      return (*static_cast<const CookOptions::Progress*>(user))(done, total) ? 0 : 1;
    };
    o.progress_user = const_cast<void*>(static_cast<const void*>(&options.progress));
  }
  return o;
}
}  // namespace detail

inline pstream_cook_report cook(const CookOptions& options) {
  const pstream_cook_options o = detail::to_c(options);
  pstream_cook_report report{};
  check(pstream_cook(&o, &report));
  return report;
}

// One frame handed to a Spool: `count` particles; each array count x components (position 3,
// width 1, velocity 3, color 4, id 1), or null where the clip has none of it. The arrays are the
// caller's again once add() returns.
struct SpoolFrame {
  double time = 0;  // seconds, after the frame before's
  std::uint64_t count = 0;
  const float* position = nullptr;
  const float* width = nullptr;
  const float* velocity = nullptr;
  const std::uint64_t* id = nullptr;
  const float* color = nullptr;
  std::vector<pstream_float_attribute> floats;  // {name, components, values}
};

// A simulation handed over frame by frame (a DCC's exporter) and kept on disk until cook()
// (pstream_spool_*): memory stays a frame's, and the temporary goes with the spool.
class Spool {
 public:
  // `folder`: where the temporary lives (empty: $TMPDIR, else /tmp); `name` names the frames.
  explicit Spool(const std::string& folder = {}, const std::string& name = "particles") {
    pstream_spool* h = nullptr;
    check(pstream_spool_open(folder.empty() ? nullptr : folder.c_str(), name.c_str(), &h));
    h_ = Handle(h);
  }
  void add(const SpoolFrame& frame) {
    pstream_spool_frame f{};
    f.struct_size = sizeof f;
    f.time = frame.time;
    f.count = frame.count;
    f.position = frame.position;
    f.width = frame.width;
    f.velocity = frame.velocity;
    f.id = frame.id;
    f.color = frame.color;
    f.floats = frame.floats.empty() ? nullptr : frame.floats.data();
    f.float_count = static_cast<std::uint32_t>(frame.floats.size());
    check(pstream_spool_add(h_.get(), &f));
  }
  // As ::cook(), from the frames added: options.input stays empty, options.fps is their rate (0: 24).
  pstream_cook_report cook(const CookOptions& options) {
    const pstream_cook_options o = detail::to_c(options);
    pstream_cook_report report{};
    check(pstream_spool_cook(h_.get(), &o, &report));
    return report;
  }
  pstream_spool* get() const { return h_.get(); }

 private:
  using Handle = detail::Handle<pstream_spool, pstream_spool_close>;
  Handle h_;
};

// ---- Reading a .pstream directly -------------------------------------------------------------

class Clip {
 public:
  explicit Clip(const std::string& path) {
    pstream_clip* c = nullptr;
    check(pstream_clip_open(path.c_str(), &c));
    h_ = Handle(c);
  }
  ClipInfo info() const {
    ClipInfo i{};
    check(pstream_clip_info_get(h_.get(), &i));
    return i;
  }
  std::vector<Attribute> layout() const {
    std::vector<Attribute> out(info().attribute_count);
    for (std::uint32_t i = 0; i < out.size(); ++i) check(pstream_clip_attribute(h_.get(), i, &out[i]));
    return out;
  }
  std::pair<std::uint64_t, double> frame_info(std::uint64_t frame) const {
    std::pair<std::uint64_t, double> r{};
    check(pstream_clip_frame_info(h_.get(), frame, &r.first, &r.second));
    return r;
  }
  // Decodes a frame's records (count x record_size bytes).
  std::vector<std::byte> read_frame(std::uint64_t frame) {
    std::vector<std::byte> out(frame_info(frame).first * info().record_size);
    check(pstream_clip_read_frame(h_.get(), frame, out.data(), out.size()));
    return out;
  }
  pstream_clip* get() const { return h_.get(); }

 private:
  using Handle = detail::Handle<pstream_clip, pstream_clip_close>;
  Handle h_;
};

// ---- Playback ---------------------------------------------------------------------------------

// A clip's frame as update() prepared it: the records and the order to draw them in.
struct Frame {
  pstream_frame raw{};

  std::uint64_t count() const { return raw.count; }
  std::uint32_t record_size() const { return raw.record_size; }
  std::span<const std::byte> records() const {
    return {static_cast<const std::byte*>(raw.records), raw.count * raw.record_size};
  }
  // Empty when the clip is drawn in stored order (or sorted with others: Player::merged_order()).
  std::span<const std::uint32_t> order() const {
    return raw.order != nullptr ? std::span<const std::uint32_t>(raw.order, raw.count)
                                : std::span<const std::uint32_t>();
  }
  // Record i's position (object space) and, when cooked, velocity (units per second).
  std::array<float, 3> position(std::uint64_t i) const { return vec3(i, 0); }
  std::optional<std::array<float, 3>> velocity(std::uint64_t i) const {
    if (raw.velocity_offset < 0) return std::nullopt;
    return vec3(i, static_cast<std::uint32_t>(raw.velocity_offset));
  }
  double time() const { return raw.time; }
  std::uint64_t frame() const { return raw.frame; }
  double fraction() const { return raw.fraction; }

 private:
  std::array<float, 3> vec3(std::uint64_t i, std::uint32_t offset) const {
    std::array<float, 3> v{};
    std::memcpy(v.data(), static_cast<const std::byte*>(raw.records) + i * raw.record_size + offset, sizeof v);
    return v;
  }
};

struct PlayerOptions {
  double cache_seconds = 1;
  std::uint64_t memory_budget = 0;  // 0: no limit
  pstream_interpolation interpolation = PSTREAM_INTERPOLATION_HERMITE;
  pstream_sort sort = PSTREAM_SORT_BACK_TO_FRONT;
  bool blocking = false;  // update() waits for data (offline rendering)
  bool loop = true;
  int saved_states = 3;                // decoder states kept for going back (pstream_player_options)
  std::vector<pstream_io> io;          // empty, or one per clip (then paths only name them)
  std::optional<pstream_tasks> tasks;  // the host's job system
};

class Player {
 public:
  Player(const std::vector<std::string>& paths, const PlayerOptions& options = {}) {
    pstream_player_options o;
    pstream_player_options_init(&o);
    o.cache_seconds = options.cache_seconds;
    o.memory_budget = options.memory_budget;
    o.interpolation = options.interpolation;
    o.sort = options.sort;
    o.blocking = options.blocking ? 1 : 0;
    o.loop = options.loop ? 1 : 0;
    o.saved_states = options.saved_states;
    if (!options.io.empty()) {
      if (options.io.size() != paths.size())
        throw Error(PSTREAM_ERROR_ARGUMENT, "PlayerOptions::io has " + std::to_string(options.io.size()) +
                                                " entries for " + std::to_string(paths.size()) + " clips");
      o.io = options.io.data();
    }
    if (options.tasks) o.tasks = &*options.tasks;
    std::vector<const char*> c_paths;
    for (const auto& p : paths) c_paths.push_back(p.c_str());
    pstream_player* p = nullptr;
    check(pstream_player_open(options.io.empty() ? c_paths.data() : nullptr, paths.size(), &o, &p));
    h_ = Handle(p);
  }

  void play() { check(pstream_player_play(h_.get())); }
  void pause() { check(pstream_player_pause(h_.get())); }
  void seek(double time) { check(pstream_player_seek(h_.get(), time)); }
  void set_speed(double speed) { check(pstream_player_set_speed(h_.get(), speed)); }
  void set_loop(bool loop) { check(pstream_player_set_loop(h_.get(), loop ? 1 : 0)); }
  void set_range(double start, double end) { check(pstream_player_set_range(h_.get(), start, end)); }
  void set_transform(std::size_t clip, const std::array<float, 16>& world) {
    check(pstream_player_set_transform(h_.get(), clip, world.data()));
  }
  // One host frame; `view` (world -> view, column-major) orders the particles for drawing.
  void update(double dt, const std::array<float, 16>* view = nullptr) {
    check(pstream_player_update(h_.get(), dt, view != nullptr ? view->data() : nullptr));
  }
  // Throws the first failed clip's error (its file, chunk and cause).
  void check_clips() const { check(pstream_player_check(h_.get())); }

  std::size_t clip_count() const { return pstream_player_clip_count(h_.get()); }
  Frame frame(std::size_t clip) const {
    Frame f;
    check(pstream_player_frame(h_.get(), clip, &f.raw));
    return f;
  }
  // A player opened with PSTREAM_PLAYBACK_GPU: what an engine's shaders interpolate clip `clip`'s
  // frame from (particlestream.h: pstream_frame_pair; the rules in docs/embedding.md).
  pstream_frame_pair frame_pair(std::size_t clip) const {
    pstream_frame_pair p{};
    check(pstream_player_frame_pair(h_.get(), clip, &p));
    return p;
  }
  std::span<const std::uint32_t> merged_order() const {
    const std::uint32_t* order = nullptr;
    std::uint64_t n = 0;
    check(pstream_player_merged_order(h_.get(), &order, &n));
    return {order, n};
  }
  ClipInfo clip_info(std::size_t clip) const {
    ClipInfo i{};
    check(pstream_player_clip_info(h_.get(), clip, &i));
    return i;
  }
  std::vector<Attribute> layout(std::size_t clip) const {
    std::vector<Attribute> out(clip_info(clip).attribute_count);
    for (std::uint32_t i = 0; i < out.size(); ++i) check(pstream_player_attribute(h_.get(), clip, i, &out[i]));
    return out;
  }
  PlayerStats stats() const {
    PlayerStats s{};
    check(pstream_player_stats_get(h_.get(), &s));
    return s;
  }
  pstream_player* get() const { return h_.get(); }

 private:
  using Handle = detail::Handle<pstream_player, pstream_player_close>;
  Handle h_;
};

}  // namespace particlestream
