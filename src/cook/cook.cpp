// The cook driver: resample the source to fixed frames, pack records, cut the record stream
// into chunks, encode chunks in parallel, write them in order.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <thread>
#include <utility>

#include <fmt/format.h>

#include "base/memory.hpp"
#include "base/output_file.hpp"
#include "cook/chunk_cutter.hpp"
#include "cook/direct_pack.hpp"
#include "cook/source.hpp"
#include "cook/spacing.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/io.hpp"

namespace pstream::cook {
namespace {

using format::Attribute;
using format::AttributeType;

constexpr float kFallbackScale = 0.01f;  // a cache without widths whose spacing cannot be measured
// Raw chunks are written in pieces of this size: small enough to stay in a core's L2 cache
// between packing and the kernel's copy into the page cache. Measured on a 16 MB cook: 17.2 ms,
// against 20.8 ms for whole 2 MiB chunks handed to a writer thread (the copy then reads another
// core's cache).
constexpr std::size_t kRawPieceSize = 256 * 1024;

struct Plan {
  Request request;
  std::vector<Attribute> layout;
  std::uint32_t record_size = 16;
  const Attribute* color = nullptr;
  const Attribute* velocity = nullptr;
  bool derived_velocity = false;  // the particle codec derives it (the source's only seed births)
  const Attribute* id = nullptr;
  std::vector<const Attribute*> floats;
};

// The radius of a cache without widths: half the median nearest-neighbour spacing of its middle
// frame (neighbours just touch), so the default suits the scene's scale.
float default_scale(Source& source, const Options& options) {
  Request positions;
  positions.scale_from = ScaleFrom::Constant;
  positions.bake_xforms = options.bake_xforms;
  ParticleFrame frame;
  frame.clear(0);
  source.read((source.start_time() + source.end_time()) / 2, positions, frame);
  const float spacing =
      median_spacing(std::span(frame.position).first(std::min<std::size_t>(frame.position.size(), 3 * frame.count)));
  return spacing > 0 && std::isfinite(spacing) ? 0.5f * spacing : kFallbackScale;
}

Plan make_plan(const Options& options, const Source& source, Report& report, float no_widths_scale) {
  Plan plan;
  Request& r = plan.request;
  r.bake_xforms = options.bake_xforms;
  r.interpolate = options.interpolate;
  r.scale_from = options.scale_from;
  r.scale_constant = options.scale_constant;
  r.scale_attribute = options.scale_attribute;
  if (r.scale_from == ScaleFrom::Widths && !source.has_widths()) {
    r.scale_from = ScaleFrom::Constant;  // nothing to take it from: from the spacing, reported
    r.scale_constant = no_widths_scale;
    report.default_scale = no_widths_scale;
  }
  if (r.scale_from == ScaleFrom::Attribute && source.float_components(r.scale_attribute) != 1) {
    throw Error(fmt::format("{}: no one-component float attribute '{}' to take the scale from", source.name(),
                            r.scale_attribute));
  }
  plan.layout = format::default_layout();
  if (options.color_from == "Cd" && !source.has_color()) {
    throw OptionError("color_from",
                      fmt::format("{}: `color_from` is Cd, but the source has no Cd colours", source.name()));
  }
  if (options.color_from != "Cd" && options.color_from != "none" && options.color_from != "auto") {
    throw OptionError("color_from", fmt::format("`color_from` must be Cd, none or auto, not '{}'", options.color_from));
  }
  if (options.interpolate && !source.can_interpolate()) {
    throw OptionError("interpolate",
                      fmt::format("{}: `interpolate`: {}", source.name(), source.why_no_interpolation()));
  }
  r.color = options.color_from == "Cd" || (options.color_from == "auto" && source.has_color());
  if (r.color) format::append_attribute(plan.layout, "color", AttributeType::Unorm8, 4);
  // The particle codec derives velocity from the positions of particles matched by id: the
  // source's velocities, when it has them, only give new particles their first step. Without ids
  // the codec's matching pairs nearby particles, not the same ones (on Blender's FLIP fixture a
  // derived velocity is off by its own RMS), so the source's velocities are stored.
  const bool derive = options.frame_codec == format::FrameCodec::Particle && !options.particle.lossless &&
                      options.particle.derive_velocity && source.has_ids();
  const auto add_velocity = [&] {
    r.velocity = source.has_velocity();
    plan.derived_velocity = derive;
    format::append_attribute(plan.layout, "velocity", AttributeType::Float32, 3);
  };
  for (const std::string& a : options.attributes) {
    if (a == "velocity" && derive) {
      if (!plan.derived_velocity) add_velocity();
    } else if (a == "velocity") {
      if (!source.has_velocity())
        throw OptionError("attributes", fmt::format("{}: `attributes` has velocity, but the source has no velocities",
                                                    source.name()));
      r.velocity = true;
      format::append_attribute(plan.layout, "velocity", AttributeType::Float32, 3);
    } else if (a == "id" || a == "id32") {
      if (!source.has_ids())
        throw OptionError("attributes", fmt::format("{}: `attributes` has {}, but {}; leave {} out of `attributes`",
                                                    source.name(), a, source.why_no_ids(), a));
      r.id = true;
      format::append_attribute(plan.layout, "id", a == "id" ? AttributeType::Uint64 : AttributeType::Uint32, 1);
    } else {
      const std::uint32_t components = source.float_components(a);
      if (components == 0)
        throw OptionError("attributes", fmt::format("{}: `attributes` has {}, but the source has no such attribute",
                                                    source.name(), a));
      r.floats.push_back(a);
      format::append_attribute(plan.layout, a, AttributeType::Float32, static_cast<std::uint8_t>(components));
    }
  }
  if (options.keep_velocity && !r.velocity && !plan.derived_velocity && (derive || source.has_velocity())) {
    if (derive) {
      add_velocity();
    } else {
      r.velocity = true;
      format::append_attribute(plan.layout, "velocity", AttributeType::Float32, 3);
    }
  }
  plan.record_size = format::record_size_of(plan.layout);
  if (options.frame_codec == format::FrameCodec::Particle && !options.particle.lossless) {
    r.id = r.id || source.has_ids();  // frames are ordered and matched by id
  }
  for (const Attribute& a : plan.layout) {
    if (a.name == "color")
      plan.color = &a;
    else if (a.name == "velocity")
      plan.velocity = &a;
    else if (a.name == "id")
      plan.id = &a;
    else if (a.name != "position" && a.name != "scale")
      plan.floats.push_back(&a);
  }
  return plan;
}

// Bounds of the valid particles, and how many are not valid (one pass over the frame): a position
// that is not finite, or a size (scale) that is NaN, infinite or negative.
struct Scan {
  std::array<float, 6> bounds;
  std::uint64_t invalid = 0, first_invalid = 0;
  std::uint64_t bad_scale = 0, first_bad_scale = 0;  // of those, with a valid position but not size
};

bool valid_scale(float s) { return s >= 0.0f && s <= std::numeric_limits<float>::max(); }

// One pass over `count` positions given by `position(i, p)`.
template <class PositionOf>
Scan scan_positions(std::uint64_t count, PositionOf position) {
  constexpr float inf = std::numeric_limits<float>::infinity(), big = std::numeric_limits<float>::max();
  Scan s{{inf, inf, inf, -inf, -inf, -inf}};
  for (std::uint64_t i = 0; i < count; ++i) {
    float p[3];
    position(i, p);
    if (!(std::abs(p[0]) <= big && std::abs(p[1]) <= big && std::abs(p[2]) <= big)) {  // NaN or infinite
      if (s.invalid++ == 0) s.first_invalid = i;
      continue;
    }
    for (int c = 0; c < 3; ++c) {
      s.bounds[c] = std::min(s.bounds[c], p[c]);
      s.bounds[c + 3] = std::max(s.bounds[c + 3], p[c]);
    }
  }
  return s;
}

Scan scan(const ParticleFrame& f) {
  const bool sized = f.scale.size() >= f.count;
  Scan s = scan_positions(f.count, [&](std::uint64_t i, float* p) {
    std::copy_n(&f.position[i * 3], 3, p);
    if (sized && !valid_scale(f.scale[i])) p[0] = std::numeric_limits<float>::quiet_NaN();  // counted invalid
  });
  if (s.invalid == 0 || !sized) return s;
  for (std::uint64_t i = 0; i < f.count; ++i) {
    const float* p = &f.position[i * 3];
    if (std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]) && !valid_scale(f.scale[i])) {
      if (s.bad_scale++ == 0) s.first_bad_scale = i;
    }
  }
  return s;
}

// Removes particles whose position is not finite, or fails naming the frame.
std::uint64_t drop_invalid(ParticleFrame& f, const Scan& scan, const Plan& plan, const Options& options,
                           std::uint64_t frame, const std::string& source) {
  const std::uint64_t bad = scan.invalid, first_bad = scan.first_invalid;
  if (bad == 0) return 0;
  if (!options.drop_invalid && scan.bad_scale > 0) {
    const std::uint64_t i = scan.first_bad_scale;
    throw OptionError("drop_invalid",
                      fmt::format("{}: frame {}: {} particles have a NaN, infinite or negative size (the first is "
                                  "particle {}, size {}); `drop_invalid` drops them",
                                  source, frame, scan.bad_scale, i, f.scale[i]));
  }
  if (!options.drop_invalid) {
    throw OptionError("drop_invalid",
                      fmt::format("{}: frame {}: {} particles have NaN or infinite positions (the first is particle "
                                  "{}); `drop_invalid` drops them",
                                  source, frame, bad, first_bad));
  }
  std::uint64_t kept = 0;
  for (std::uint64_t i = 0; i < f.count; ++i) {
    const float* p = &f.position[i * 3];
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) continue;
    if (f.scale.size() >= f.count && !valid_scale(f.scale[i])) continue;
    const auto move = [&](auto& v, std::size_t k) {
      if (v.size() >= f.count * k)
        std::copy_n(v.begin() + static_cast<std::ptrdiff_t>(i * k), k,
                    v.begin() + static_cast<std::ptrdiff_t>(kept * k));
    };
    move(f.position, 3);
    move(f.scale, 1);
    if (plan.request.color) move(f.color, 4);
    if (plan.request.velocity) move(f.velocity, 3);
    if (plan.request.id) move(f.id, 1);
    for (std::size_t e = 0; e < f.extra.size(); ++e) move(f.extra[e], plan.floats[e]->components);
    ++kept;
  }
  f.count = kept;
  return bad;
}

void pack_record(const ParticleFrame& f, const Plan& plan, std::uint64_t i, std::byte* dst) {
  std::memcpy(dst, &f.position[i * 3], 12);
  std::memcpy(dst + 12, &f.scale[i], 4);
  if (plan.color) std::memcpy(dst + plan.color->offset, &f.color[i * 4], 4);
  if (plan.velocity && f.velocity.size() >= (i + 1) * 3)
    std::memcpy(dst + plan.velocity->offset, &f.velocity[i * 3], 12);
  else if (plan.velocity)
    std::memset(dst + plan.velocity->offset, 0, 12);  // derived, and the source has none
  if (plan.id) {
    if (plan.id->type == AttributeType::Uint64) {
      std::memcpy(dst + plan.id->offset, &f.id[i], 8);
    } else {
      const auto id32 = static_cast<std::uint32_t>(f.id[i]);
      std::memcpy(dst + plan.id->offset, &id32, 4);
    }
  }
  for (std::size_t e = 0; e < plan.floats.size(); ++e) {
    const std::size_t k = plan.floats[e]->components;
    std::memcpy(dst + plan.floats[e]->offset, &f.extra[e][i * k], k * 4);
  }
}

// Records `first` to `first + n` of a frame, packed one after another from `dst`.
void pack_records(const ParticleFrame& f, const Plan& plan, std::uint64_t first, std::uint64_t n, std::byte* dst) {
  for (std::uint64_t k = 0; k < n; ++k) pack_record(f, plan, first + k, dst + k * plan.record_size);
}

// A whole frame's records, into `out` (sized to fit).
void pack_frame(const ParticleFrame& f, const Plan& plan, std::vector<std::byte>& out) {
  out.resize(f.count * plan.record_size);
  pack_records(f, plan, 0, f.count, out.data());
}

// With ids, a frame is written in ascending id order (a stable sort when the source's is not), so
// that a player matches particles across frames by one linear merge (format::match_by_id).
void order_by_id(ParticleFrame& f, const Plan& plan) {
  if (!plan.request.id || f.id.size() < f.count) return;
  const auto ids = std::span(f.id).first(f.count);
  if (std::is_sorted(ids.begin(), ids.end())) return;
  std::vector<std::uint64_t> order(f.count);
  for (std::uint64_t i = 0; i < f.count; ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](std::uint64_t a, std::uint64_t b) { return ids[a] < ids[b]; });
  const auto permute = [&](auto& v, std::size_t k) {
    if (v.size() < f.count * k) return;
    auto copy = v;
    for (std::uint64_t i = 0; i < f.count; ++i)
      std::copy_n(copy.begin() + std::ptrdiff_t(order[i] * k), k, v.begin() + std::ptrdiff_t(i * k));
  };
  permute(f.position, 3);
  permute(f.scale, 1);
  if (plan.request.color) permute(f.color, 4);
  if (plan.request.velocity) permute(f.velocity, 3);
  permute(f.id, 1);
  for (std::size_t e = 0; e < f.extra.size(); ++e) permute(f.extra[e], plan.floats[e]->components);
}

// Every attribute size is a multiple of 4 and records are packed without gaps, so every byte of a
// record is written and the output is deterministic.
void pack(const ParticleFrame& f, const Plan& plan, ChunkCutter& out) {
  std::vector<std::byte> straddling(plan.record_size);
  for (std::uint64_t i = 0; i < f.count;) {
    const std::span<std::byte> room = out.room(plan.record_size);
    if (room.empty()) {  // one record across a border, in two pieces
      pack_record(f, plan, i, straddling.data());
      out.write(straddling.data(), straddling.size());
      ++i;
      continue;
    }
    const std::uint64_t n = std::min<std::uint64_t>(room.size() / plan.record_size, f.count - i);
    pack_records(f, plan, i, n, room.data());
    out.commit(n * plan.record_size);
    i += n;
  }
}

// A frame held for the particle codec: its records, and the ids that order and match particles
// across frames (whether or not the record keeps them).
struct HeldFrame {
  std::vector<std::byte> records;
  std::vector<std::uint64_t> ids;
  std::uint64_t count = 0;
  double time = 0.0;
  format::SourceFrame view() const { return {records, ids, count}; }
};

// The (at most two) frames just before group `g` of a batch, oldest first: the last of the
// groups before it, then `tail`, the frames before the batch. They seed a group's keyframe.
std::vector<HeldFrame*> two_before(std::vector<std::vector<HeldFrame>>& groups, std::size_t g,
                                   std::vector<HeldFrame>& tail) {
  std::vector<HeldFrame*> out;
  for (std::size_t h = g; h-- > 0 && out.size() < 2;)
    for (auto it = groups[h].rbegin(); it != groups[h].rend() && out.size() < 2; ++it) out.push_back(&*it);
  for (auto it = tail.rbegin(); it != tail.rend() && out.size() < 2; ++it) out.push_back(&*it);
  std::reverse(out.begin(), out.end());
  return out;
}

void hold(const ParticleFrame& f, const Plan& plan, HeldFrame& out) {
  out.count = f.count;
  pack_frame(f, plan, out.records);
  out.ids.assign(f.id.begin(), f.id.begin() + static_cast<std::ptrdiff_t>(plan.request.id ? f.count : 0));
}

// Encodes chunks on `threads` workers; results keep their order.
std::vector<format::EncodedChunk> encode_all(const std::vector<std::vector<std::byte>>& raws, const Options& options,
                                             unsigned threads) {
  std::vector<format::EncodedChunk> out(raws.size());
  const int level = options.codec == format::Codec::Zstd && options.codec_level == 0 ? 3 : options.codec_level;
  if (threads <= 1 || raws.size() <= 1) {
    for (std::size_t i = 0; i < raws.size(); ++i) out[i] = format::encode_chunk(raws[i], options.codec, level);
    return out;
  }
  std::vector<std::jthread> pool;
  std::vector<std::exception_ptr> errors(threads);
  for (unsigned t = 0; t < threads; ++t) {
    pool.emplace_back([&, t] {
      try {
        for (std::size_t i = t; i < raws.size(); i += threads)
          out[i] = format::encode_chunk(raws[i], options.codec, level);
      } catch (...) {
        errors[t] = std::current_exception();
      }
    });
  }
  pool.clear();
  for (auto& e : errors) {
    if (e) std::rethrow_exception(e);
  }
  return out;
}

// Refuses a cook that would not fit on the disk: once enough is written to project the total,
// the projection is compared with the free space left.
class SpaceCheck {
 public:
  SpaceCheck(const std::filesystem::path& output, std::uint64_t frames) : output_(output), frames_(frames) {}
  void operator()(std::uint64_t frames_done, std::uint64_t bytes_out) {
    if (checked_ || frames_done < std::min<std::uint64_t>(frames_, 16) || frames_done == 0) return;
    checked_ = true;
    const std::uint64_t free = free_space(output_);
    const double projected = double(bytes_out) / double(frames_done) * double(frames_);
    if (projected > double(free) + double(bytes_out)) {
      throw Error(
          fmt::format("{}: the cook would write about {:.1f} GB ({} frames at {:.1f} MB each so far), but "
                      "only {:.1f} GB are free there",
                      output_.string(), projected / 1e9, frames_, double(bytes_out) / double(frames_done) / 1e6,
                      double(free) / 1e9));
    }
  }

 private:
  std::filesystem::path output_;
  std::uint64_t frames_;
  bool checked_ = false;
};

// The particle codec's cook: a pass over the source for the clip's statistics (bounds, ranges,
// constants: what the quantisation grids need), then keyframe groups, read in order and encoded
// `threads` at a time, their packets written in order as raw chunks.
void cook_particle(const Options& options, const Plan& plan, format::Metadata meta, std::uint64_t frames,
                   unsigned threads, const std::function<std::array<float, 6>(std::uint64_t, ParticleFrame&)>& read,
                   const std::function<void(const Progress&)>& progress, const Source& source, Report& report) {
  ParticleFrame frame;
  HeldFrame held;
  Progress state;
  state.frame_count = frames;
  state.stage = Stage::Scan;
  format::ClipStats stats(plan.layout);
  const std::uint64_t dropped_before = report.dropped_invalid;  // counted by the encoding pass
  std::uint64_t most = 0;                                       // particles in the largest frame
  for (std::uint64_t k = 0; k < frames; ++k) {
    read(k, frame);
    hold(frame, plan, held);
    stats.add(held.records, held.count);
    most = std::max(most, held.count);
    state.frames_done = k + 1;
    if (progress) progress(state);
  }
  report.dropped_invalid = dropped_before;
  state.stage = Stage::Write;
  state.frames_done = 0;
  if (progress) progress(state);  // the writing starts (its first frames come after a batch's encode)
  const format::FrameCodecEncoding* encoder = format::find_frame_codec_encoder(options.frame_codec);
  if (encoder == nullptr) throw Error(fmt::format("unknown frame codec {}", static_cast<int>(options.frame_codec)));
  meta.codec =
      encoder->plan(plan.layout, stats, meta.fps, plan.request.id && !options.particle.lossless, options.particle);
  report.error = meta.codec.error;
  report.order = meta.codec.order;
  format::Writer writer(options.output, meta, source.files());
  SpaceCheck space(options.output, frames);
  const std::uint64_t K = meta.codec.keyframe_interval;
  // A group in flight holds its frames' records and ids: as many groups at once as threads, but no
  // more than fit in Options::group_memory (one at least: the codec encodes a group whole).
  const std::uint64_t group_bytes = K * most * (plan.record_size + sizeof(std::uint64_t));
  const std::uint64_t budget = options.group_memory ? options.group_memory : memory::physical_memory() / 2;
  threads =
      static_cast<unsigned>(std::clamp<std::uint64_t>(budget / std::max<std::uint64_t>(group_bytes, 1), 1, threads));
  report.groups_in_flight = threads;
  std::vector<std::vector<HeldFrame>> groups;
  std::vector<std::uint64_t> starts;  // each group's first frame
  std::vector<HeldFrame> tail;        // the last two frames before a batch, oldest first
  for (std::uint64_t g0 = 0; g0 < frames;) {
    // A batch: one group per thread, read in order.
    groups.clear();
    starts.clear();
    for (unsigned t = 0; t < threads && g0 < frames; ++t, g0 += K) {
      auto& group = groups.emplace_back();
      starts.push_back(g0);
      for (std::uint64_t k = g0; k < std::min(frames, g0 + K); ++k) {
        read(k, frame);
        hold(frame, plan, group.emplace_back());
        group.back().time = meta.time_of_frame0 + double(k) / meta.fps;
      }
    }
    std::vector<std::vector<format::EncodedFrame>> encoded(groups.size());
    std::vector<std::exception_ptr> errors(groups.size());
    {
      std::vector<std::jthread> pool;
      for (std::size_t g = 0; g < groups.size(); ++g) {
        pool.emplace_back([&, g] {
          try {
            std::vector<format::SourceFrame> views;
            for (const HeldFrame& h : groups[g]) views.push_back(h.view());
            std::vector<format::SourceFrame> prior;
            for (const HeldFrame* h : two_before(groups, g, tail)) prior.push_back(h->view());
            encoded[g] = encoder->encode_group(meta.codec, views, prior, starts[g]);
          } catch (...) {
            errors[g] = std::current_exception();
          }
        });
      }
    }
    for (auto& e : errors) {
      if (e) std::rethrow_exception(e);
    }
    for (std::size_t g = 0; g < groups.size(); ++g) {
      for (std::size_t f = 0; f < encoded[g].size(); ++f) {
        const format::EncodedFrame& e = encoded[g][f];
        writer.append_frame(e.count, groups[g][f].time, e.bounds, e.packet.size(), e.keyframe);
        writer.append_stream(e.packet);
        report.particles += e.count;
        report.keyframes += e.keyframe ? 1 : 0;
        if (!e.keyframe) {
          report.matched += e.matched;
          report.predictable += e.predictable;
        }
        state.bytes_out += e.packet.size();
        ++state.frames_done;
        space(state.frames_done, state.bytes_out);
      }
    }
    // Once a batch: its frames were encoded together, so a rate counted frame by frame while they
    // are written would understate the pace, and the time left overstate it.
    if (progress) progress(state);
    std::vector<HeldFrame> next_tail;
    for (HeldFrame* h : two_before(groups, groups.size(), tail)) next_tail.push_back(std::move(*h));
    tail = std::move(next_tail);
  }
  report.frames = frames;
  report.stream_bytes = writer.metadata().decoded_size();
  source.check_intact();
  report.file_bytes = writer.commit();
  report.chunks = writer.metadata().chunk_count();
}

// The output frames: how many the source spans at the frame rate, and the selected range.
struct FramePlan {
  double fps = 0.0, start = 0.0;
  std::int64_t first = 0, last = 0;
  std::uint64_t count() const { return static_cast<std::uint64_t>(last - first); }
  double time(std::uint64_t index) const {  // of output frame `index`, in seconds
    return start + static_cast<double>(first + static_cast<std::int64_t>(index)) / fps;
  }
};

FramePlan plan_frames(const Options& options, const Source& source) {
  FramePlan p;
  p.fps = options.fps > 0 ? options.fps : source.default_fps();
  if (!std::isfinite(p.fps) || !(p.fps > 0)) {
    throw OptionError("fps", fmt::format("{}: the frame rate `fps` {} must be a positive number of frames per second",
                                         source.name(), p.fps));
  }
  p.start = source.start_time();
  const double end = source.end_time();
  if (!std::isfinite(p.start) || !std::isfinite(end) || end < p.start) {
    throw Error(fmt::format("{}: the source's time range {} s .. {} s is not a range of finite times", source.name(),
                            p.start, end));
  }
  // Whole frames from start to end, kept as a double until it is known to be in range.
  const double span = std::floor((end - p.start) * p.fps + 1e-6) + 1.0;
  const double limit = static_cast<double>(options.max_frames);
  const double first = static_cast<double>(options.frame_begin);
  const double last = options.frame_end < 0 ? span : std::min(static_cast<double>(options.frame_end), span);
  if (options.frame_begin < 0 || !(first < last)) {
    throw OptionError(
        "frame_begin",
        fmt::format("{}: the frame range `frame_begin`:`frame_end` {}:{} selects no frames; the clip has "
                    "{:.0f} frames at {:g} fps, numbered from 0",
                    source.name(), options.frame_begin,
                    options.frame_end < 0 ? std::string("end") : std::to_string(options.frame_end), span, p.fps));
  }
  if (!(last - first <= limit)) {
    throw OptionError("max_frames",
                      fmt::format("{}: the cook would make {:.0f} frames ({:g} s at {:g} fps), more than `max_frames`, "
                                  "{}. Check the frame rate, choose a frame range, or raise `max_frames` if that many "
                                  "frames are really wanted",
                                  source.name(), last - first, (last - first) / p.fps, p.fps, options.max_frames));
  }
  p.first = options.frame_begin;
  p.last = static_cast<std::int64_t>(last);
  return p;
}

std::string codec_setting(const Options& o, bool has_ids) {
  if (o.frame_codec == format::FrameCodec::Particle) {
    const format::FrameOrder order = format::particle_frame_order(has_ids, o.particle.lossless);
    const int level =
        o.particle.zstd_level ? o.particle.zstd_level : format::default_particle_zstd_level(order, o.particle.lossless);
    if (o.particle.lossless) return fmt::format("particle-lossless:{}", level);
    return fmt::format(
        "particle:{} error={}:{:g} scale_error={:g} attribute_error={:g} keyframe_interval={} velocity={}", level,
        o.particle.error_relative ? "rel" : "abs", o.particle.error, o.particle.scale_error, o.particle.attribute_error,
        o.particle.keyframe_interval, o.particle.derive_velocity && has_ids ? "derived" : "stored");
  }
  return fmt::format("{}:{}", format::codec_name(o.codec), o.codec_level);
}

}  // namespace

std::string describe_settings(const Options& o, std::uint64_t content_hash, bool has_ids) {
  std::string attributes;
  for (const std::string& a : o.attributes) attributes += (attributes.empty() ? "" : ",") + a;
  const char* scale = o.scale_from == ScaleFrom::Widths     ? "widths"
                      : o.scale_from == ScaleFrom::Constant ? "constant"
                                                            : "attr";
  return fmt::format(
      "source={} source_xxh3={:016x} object={} merge={} bake_xforms={} fps={:g} interpolate={} scale_from={}{} "
      "color_from={} attributes={} keep_velocity={} chunk_size={} codec={} frames={}:{} drop_invalid={} "
      "keep_source_order={}",
      o.input.filename().string(), content_hash, o.object.empty() ? "auto" : o.object, int(o.merge), int(o.bake_xforms),
      o.fps, int(o.interpolate), scale,
      o.scale_from == ScaleFrom::Constant    ? fmt::format(":{:g}", o.scale_constant)
      : o.scale_from == ScaleFrom::Attribute ? ":" + o.scale_attribute
                                             : std::string(),
      o.color_from, attributes.empty() ? "none" : attributes, int(o.keep_velocity), o.chunk_size,
      codec_setting(o, has_ids), o.frame_begin, o.frame_end < 0 ? std::string("end") : std::to_string(o.frame_end),
      int(o.drop_invalid), int(o.keep_source_order));
}

namespace {

// The options every source is cooked under, checked before any source is opened.
void check_cook_options(const Options& options) {
  if (!std::has_single_bit(options.chunk_size) || options.chunk_size < format::kMinChunkSize ||
      options.chunk_size > format::kMaxChunkSize) {
    throw OptionError("chunk_size",
                      fmt::format("`chunk_size` {} must be a power of two from 64 KiB to 64 MiB", options.chunk_size));
  }
  if (options.fps != 0 && !(options.fps > 0 && std::isfinite(options.fps))) {
    throw OptionError("fps", fmt::format("`fps` {} must be a positive number (or 0: the source's)", options.fps));
  }
}

// What a cook of `source` makes: the records' plan, the output frames and the clip's header.
struct Prepared {
  Plan plan;
  FramePlan frames;
  format::Metadata meta;
};

// One output frame through the general path: read, scanned, NaN/Inf dropped or refused, the
// particle limit checked. Returns the frame's bounds.
std::array<float, 6> read_frame(Source& source, const Options& options, const Plan& plan, const FramePlan& frames,
                                std::uint64_t index, ParticleFrame& frame, Report& report) {
  const double time = frames.time(index);
  frame.clear(plan.request.floats.size());
  source.read(time, plan.request, frame);
  const Scan found = scan(frame);
  report.dropped_invalid += drop_invalid(frame, found, plan, options, index, source.name());
  if (frame.count > options.max_particles) {
    throw OptionError("max_particles", fmt::format("{}: frame {} has {} particles, more than `max_particles`, {}",
                                                   source.name(), index, frame.count, options.max_particles));
  }
  source.check_intact();
  return found.bounds;
}

// The clip's header as the cook writes it (the frame table is filled as frames are written).
// Without `settings`, no "cooked with": it hashes every byte of the source.
format::Metadata clip_metadata(const Options& options, const Source& source, const Plan& plan, const FramePlan& frames,
                               bool settings) {
  format::Metadata meta;
  meta.flags =
      (options.bake_xforms ? format::kFlagXformsBaked : 0) | (options.interpolate ? format::kFlagInterpolated : 0);
  meta.fps = frames.fps;
  meta.time_of_frame0 = frames.time(0);
  meta.chunk_size = options.chunk_size;
  meta.layout = plan.layout;
  meta.record_size = plan.record_size;
  meta.source_file = std::filesystem::path(source.name()).filename().string();
  meta.source_object = source.object();
  if (settings) meta.cooked_with = describe_settings(options, source.content_hash(), plan.request.id);
  return meta;
}

Prepared prepare(const Options& options, Source& source, Report& report, bool settings = true) {
  const float no_widths_scale =
      options.scale_from == ScaleFrom::Widths && !source.has_widths() ? default_scale(source, options) : kFallbackScale;
  Prepared p{make_plan(options, source, report, no_widths_scale), plan_frames(options, source), {}};
  p.meta = clip_metadata(options, source, p.plan, p.frames, settings);
  return p;
}

std::unique_ptr<Source> open_source(const Options& options, const std::function<void(const Progress&)>& progress) {
  check_cook_options(options);
  if (!is_ply_sequence(options.input)) return open_alembic(options, progress);
  return open_ply_sequence(options);
}

// Cooks from an open source: the one path for files and for particles handed over in memory.
Report cook_source(const Options& options, Source& opened, const std::function<void(const Progress&)>& progress,
                   std::chrono::steady_clock::time_point t0) {
  Source* const source = &opened;
  Report report;
  report.object = source->object();
  report.mesh_vertices = source->mesh_vertices();
  const Prepared prepared = prepare(options, *source, report);
  const Plan& plan = prepared.plan;
  const FramePlan& frames = prepared.frames;
  const format::Metadata& meta = prepared.meta;
  const std::vector<std::filesystem::path> inputs = source->files();
  check_output(options.output, inputs);  // before any long work

  const unsigned threads = options.threads ? options.threads : std::max(1u, std::thread::hardware_concurrency());

  const auto read = [&](std::uint64_t index, ParticleFrame& frame) {
    return read_frame(*source, options, plan, frames, index, frame, report);
  };
  if (options.frame_codec == format::FrameCodec::Particle) {
    cook_particle(options, plan, meta, frames.count(), threads, read, progress, *source, report);
    report.input_bytes = source->input_bytes();
    report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return report;
  }
  format::Writer writer(options.output, meta, inputs);
  SpaceCheck space(options.output, frames.count());

  const std::size_t batch_chunks = std::max<std::size_t>(2, threads * 2);
  std::vector<std::vector<std::byte>> batch;  // raw chunks waiting to be encoded together
  Progress state;
  state.frame_count = frames.count();
  const auto encode_batch = [&] {
    for (const auto& c : encode_all(batch, options, threads)) {
      writer.append_chunk(c);
      state.bytes_out += c.stored.size();
    }
    batch.clear();
  };
  // Raw chunks go to the file in cache-sized pieces as they fill (no chunk-sized buffer, the
  // kernel copies from hot cache lines); other codecs need whole chunks to encode.
  const bool raw = options.codec == format::Codec::Raw;
  ChunkCutter cutter(options.chunk_size, raw ? kRawPieceSize : options.chunk_size,
                     [&](std::span<const std::byte> piece, bool ends_chunk) {
                       if (ends_chunk) ++report.chunks;
                       if (raw) {
                         writer.append_raw_piece(piece);
                         if (ends_chunk) writer.end_raw_chunk();
                         state.bytes_out += piece.size();
                         return;
                       }
                       batch.emplace_back(piece.begin(), piece.end());
                       if (batch.size() >= batch_chunks) encode_batch();
                     });

  ParticleFrame frame;
  Source::DirectFrame direct;
  for (std::uint64_t index = 0; index < frames.count(); ++index) {
    const double time = frames.time(index);
    // The default record straight from the source's mapping, packed, scanned and checked in one
    // pass. A frame it cannot take (or one that fails) goes through the general path below,
    // which names what is wrong.
    if (plan.layout.size() == 2 && source->read_direct(time, plan.request, direct) &&
        direct.count <= options.max_particles) {
      const DirectPackResult packed = pack_direct(direct, options.drop_invalid, cutter);
      if (packed.invalid == 0 || options.drop_invalid) {
        writer.append_frame(packed.packed, time, packed.bounds);
        report.dropped_invalid += packed.invalid;
        report.particles += packed.packed;
        state.frames_done = index + 1;
        source->check_intact();
        space(state.frames_done, state.bytes_out);
        if (progress) progress(state);
        continue;
      }
    }
    const std::array<float, 6> bounds = read(index, frame);
    if (!options.keep_source_order) order_by_id(frame, plan);
    writer.append_frame(frame.count, time, bounds);
    pack(frame, plan, cutter);
    report.particles += frame.count;
    state.frames_done = index + 1;
    space(state.frames_done, state.bytes_out);
    if (progress) progress(state);
  }
  cutter.finish();
  encode_batch();
  report.frames = state.frame_count;
  report.stream_bytes = writer.metadata().stream_size();
  report.input_bytes = source->input_bytes();
  source->check_intact();
  report.file_bytes = writer.commit();
  report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return report;
}

}  // namespace

Report cook(const Options& options, const std::function<void(const Progress&)>& progress) {
  const auto t0 = std::chrono::steady_clock::now();
  const std::unique_ptr<Source> source = open_source(options, progress);
  return cook_source(options, *source, progress, t0);
}

std::uint64_t read_frames(const Options& options, const FrameVisitor& visit) {
  const std::unique_ptr<Source> source = open_source(options, {});
  Report report;
  const Prepared prepared = prepare(options, *source, report, false);  // a few frames need not hash the whole source
  const Plan& plan = prepared.plan;
  const FramePlan& frames = prepared.frames;
  ParticleFrame frame;
  std::vector<std::byte> records;
  std::uint64_t index = 0;
  for (; index < frames.count(); ++index) {
    read_frame(*source, options, plan, frames, index, frame, report);
    if (!options.keep_source_order) order_by_id(frame, plan);
    pack_frame(frame, plan, records);
    if (!visit(prepared.meta, CookedFrame{index, frames.count(), frames.time(index), frame.count, records}))
      return index + 1;
  }
  return index;
}

Report cook(const Options& options, const MemoryClip& clip, const std::function<void(const Progress&)>& progress) {
  const auto t0 = std::chrono::steady_clock::now();
  check_cook_options(options);
  const std::unique_ptr<Source> source = open_memory(options, clip);
  return cook_source(options, *source, progress, t0);
}

bool is_ply_sequence(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  return ext == ".ply";
}

}  // namespace pstream::cook
