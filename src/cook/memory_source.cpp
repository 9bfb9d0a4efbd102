// Particles handed over in memory (cook.hpp: MemoryClip) as a cook source: the Blender add-on's
// and scripts' way in, cooked by the same path as a file.
#define XXH_STATIC_LINKING_ONLY  // XXH3_state_t on the stack
#include <xxhash.h>

#include <algorithm>
#include <cmath>
#include <cstring>

#include <fmt/format.h>

#include "cook/source.hpp"

namespace pstream::cook {

const MemoryFloats* floats_named(const MemoryFrame& f, const std::string& name) {
  for (const MemoryFloats& a : f.floats)
    if (a.name == name) return &a;
  return nullptr;
}

namespace {

class MemorySource final : public Source {
 public:
  MemorySource(const Options& options, const MemoryClip& clip) : clip_(clip) {
    const std::string& name = clip.name;
    if (clip.frames.empty()) throw Error(fmt::format("{}: no frames to cook", name));
    if (!(clip.fps > 0 && std::isfinite(clip.fps)))
      throw Error(fmt::format("{}: fps {} must be a positive number", name, clip.fps));
    // An attribute is in the clip when a frame with particles has it; then every such frame must.
    for (const MemoryFrame& f : clip.frames) {
      if (f.count > 0) has_.add(attributes_of(f));
    }
    for (std::size_t i = 0; i < clip.frames.size(); ++i) {
      const MemoryFrame& f = clip.frames[i];
      check_memory_frame(name, i, f, has_, i > 0 ? clip.frames[i - 1].time : std::nan(""));
      if (f.count > options.max_particles) {
        throw OptionError("max_particles", fmt::format("{}: frame {} has {} particles, more than `max_particles`, {}",
                                                       name, i, f.count, options.max_particles));
      }
      bytes_ += (f.position.size() + f.width.size() + f.velocity.size() + f.color.size()) * 4 + f.id.size() * 8;
      for (const MemoryFloats& a : f.floats) bytes_ += a.values.size_bytes();
    }
  }

  std::string name() const override { return clip_.name; }
  std::string object() const override { return clip_.object.empty() ? "particles" : clip_.object; }
  double default_fps() const override { return clip_.fps; }
  double start_time() const override { return clip_.frames.front().time; }
  double end_time() const override { return clip_.frames.back().time; }
  std::uint64_t input_bytes() const override { return bytes_; }
  bool has_widths() const override { return has_.width; }
  bool has_color() const override { return has_.color; }
  bool has_velocity() const override { return has_.velocity; }
  bool has_ids() const override { return has_.id; }
  std::string why_no_ids() const override { return clip_.name + " has no particle ids"; }
  bool can_interpolate() const override { return false; }
  std::string why_no_interpolation() const override {
    return clip_.name +
           ": particles handed over in memory are cooked frame by frame, each from the nearest one; cook "
           "without `interpolate`";
  }
  std::vector<std::filesystem::path> files() const override { return {}; }
  void check_intact() const override {}
  std::uint32_t float_components(const std::string& name) const override {
    for (const auto& [n, components] : has_.floats)
      if (n == name) return components;
    return 0;
  }
  std::uint64_t content_hash() const override {
    XXH3_state_t state;
    XXH3_64bits_reset(&state);
    const auto add = [&](const auto& span) { XXH3_64bits_update(&state, span.data(), span.size_bytes()); };
    for (const MemoryFrame& f : clip_.frames) {
      XXH3_64bits_update(&state, &f.time, sizeof f.time);
      XXH3_64bits_update(&state, &f.count, sizeof f.count);
      add(f.position), add(f.width), add(f.velocity), add(f.id), add(f.color);
      for (const MemoryFloats& a : f.floats) {
        XXH3_64bits_update(&state, a.name.data(), a.name.size() + 1);  // with its terminator: names stay apart
        XXH3_64bits_update(&state, &a.components, sizeof a.components);
        add(a.values);
      }
    }
    return XXH3_64bits_digest(&state);
  }

  void read(double time, const Request& request, ParticleFrame& out) override {
    if (request.scale_from == ScaleFrom::Attribute) {
      throw Error(
          fmt::format("{}: no attribute '{}' to take the scale from (particles in memory have position, "
                      "width, velocity, id and color)",
                      clip_.name, request.scale_attribute));
    }
    const MemoryFrame& f = clip_.frames[nearest(time)];
    const std::uint64_t base = out.count, n = f.count;
    out.count += n;
    ensure_size(out.position, out.count * 3);
    std::copy(f.position.begin(), f.position.end(), out.position.begin() + static_cast<std::ptrdiff_t>(base * 3));
    ensure_size(out.scale, out.count);
    for (std::uint64_t i = 0; i < n; ++i) {
      out.scale[base + i] =
          request.scale_from == ScaleFrom::Widths && has_.width ? scale_from_width(f.width[i]) : request.scale_constant;
    }
    if (request.color) {
      ensure_size(out.color, out.count * 4);
      for (std::uint64_t i = 0; i < n * 4; ++i) out.color[base * 4 + i] = to_unorm8(f.color[i]);
    }
    if (request.velocity) {
      ensure_size(out.velocity, out.count * 3);
      std::copy(f.velocity.begin(), f.velocity.end(), out.velocity.begin() + static_cast<std::ptrdiff_t>(base * 3));
    }
    if (request.id) {
      ensure_size(out.id, out.count);
      std::copy(f.id.begin(), f.id.end(), out.id.begin() + static_cast<std::ptrdiff_t>(base));
    }
    for (std::size_t e = 0; e < request.floats.size() && n > 0; ++e) {
      const MemoryFloats* a = floats_named(f, request.floats[e]);  // checked at open: there
      ensure_size(out.extra[e], out.count * a->components);
      std::copy(a->values.begin(), a->values.end(),
                out.extra[e].begin() + static_cast<std::ptrdiff_t>(base * a->components));
    }
  }

 private:
  // The frame nearest `time` (the earlier one on a tie).
  std::size_t nearest(double time) const {
    const auto& frames = clip_.frames;
    const auto it =
        std::lower_bound(frames.begin(), frames.end(), time, [](const MemoryFrame& f, double t) { return f.time < t; });
    if (it == frames.begin()) return 0;
    if (it == frames.end()) return frames.size() - 1;
    const auto i = static_cast<std::size_t>(it - frames.begin());
    return time - frames[i - 1].time <= frames[i].time - time ? i - 1 : i;
  }

  const MemoryClip& clip_;
  MemoryAttributes has_;
  std::uint64_t bytes_ = 0;
};

// One array's size against count x components (none when the clip lacks the attribute).
void check_array(const std::string& name, std::size_t index, const MemoryFrame& f, const char* what, std::size_t size,
                 std::size_t components, bool present) {
  const std::size_t want = present ? f.count * components : 0;
  if (size == want) return;
  if (present && size == 0) {
    throw Error(
        fmt::format("{}: frame {} has no {} array, but other frames have one: an attribute must be in "
                    "every frame with particles or in none",
                    name, index, what));
  }
  if (!present && f.count > 0) {
    throw Error(
        fmt::format("{}: frame {} has a {} array, but the frames before it with particles have none: an "
                    "attribute must be in every frame with particles or in none",
                    name, index, what));
  }
  throw Error(fmt::format("{}: frame {}: the {} array holds {} values, expected {} ({} particles x {})", name, index,
                          what, size, want, f.count, components));
}

}  // namespace

MemoryAttributes attributes_of(const MemoryFrame& frame) {
  MemoryAttributes a{!frame.width.empty(), !frame.velocity.empty(), !frame.id.empty(), !frame.color.empty(), {}};
  for (const MemoryFloats& f : frame.floats) a.floats.emplace_back(f.name, f.components);
  return a;
}

void MemoryAttributes::add(const MemoryAttributes& other) {
  width = width || other.width;
  velocity = velocity || other.velocity;
  id = id || other.id;
  color = color || other.color;
  for (const auto& f : other.floats) {
    if (std::none_of(floats.begin(), floats.end(), [&](const auto& g) { return g.first == f.first; }))
      floats.push_back(f);
  }
}

void check_memory_frame(const std::string& name, std::size_t index, const MemoryFrame& f, const MemoryAttributes& has,
                        double previous_time) {
  if (!std::isfinite(f.time) || (index > 0 && !(f.time > previous_time))) {
    throw Error(index == 0 ? fmt::format("{}: frame 0 is at time {} s: times are finite seconds", name, f.time)
                           : fmt::format("{}: frame {} is at time {} s, after frame {} at {} s: times must increase",
                                         name, index, f.time, index - 1, previous_time));
  }
  check_array(name, index, f, "position", f.position.size(), 3, true);
  check_array(name, index, f, "width", f.width.size(), 1, has.width);
  check_array(name, index, f, "velocity", f.velocity.size(), 3, has.velocity);
  check_array(name, index, f, "id", f.id.size(), 1, has.id);
  check_array(name, index, f, "color", f.color.size(), 4, has.color);
  for (std::size_t k = 0; k < f.floats.size(); ++k) {
    const MemoryFloats& a = f.floats[k];
    const char* const builtin[] = {"position", "width", "scale", "velocity", "id", "color"};
    if (std::find(std::begin(builtin), std::end(builtin), a.name) != std::end(builtin) || a.name.empty()) {
      throw Error(fmt::format("{}: frame {}: a float attribute named '{}': that name is {}", name, index, a.name,
                              a.name.empty() ? "empty" : "a built-in attribute's, handed over in its own array"));
    }
    if (a.components < 1 || a.components > 16) {
      throw Error(fmt::format("{}: frame {}: float attribute '{}' has {} components; 1 to 16 are taken", name, index,
                              a.name, a.components));
    }
    for (std::size_t j = 0; j < k; ++j)
      if (f.floats[j].name == a.name)
        throw Error(fmt::format("{}: frame {}: float attribute '{}' is handed over twice", name, index, a.name));
  }
  for (const auto& [attribute, components] : has.floats) {
    const MemoryFloats* a = floats_named(f, attribute);
    if (a != nullptr && a->components != components) {
      throw Error(fmt::format("{}: frame {}: float attribute '{}' has {} components, the other frames {}", name, index,
                              attribute, a->components, components));
    }
    check_array(name, index, f, fmt::format("'{}'", attribute).c_str(), a ? a->values.size() : 0, components, true);
  }
  for (const MemoryFloats& a : f.floats) {
    if (std::none_of(has.floats.begin(), has.floats.end(), [&](const auto& h) { return h.first == a.name; }))
      check_array(name, index, f, fmt::format("'{}'", a.name).c_str(), a.values.size(), a.components, false);
  }
}

std::unique_ptr<Source> open_memory(const Options& options, const MemoryClip& clip) {
  return std::make_unique<MemorySource>(options, clip);
}

}  // namespace pstream::cook
