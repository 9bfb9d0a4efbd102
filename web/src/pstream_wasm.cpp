// The browser player's decoder: the format's Reader and the particle codec's decoder, the same
// sources as the native library, over a byte source whose bytes the worker fetched (web/worker.js
// does the range requests; docs/web.md). Exported as plain C functions, called from the worker
// only: the page's main thread never decodes.
//
// A call that needs bytes the worker has not fetched yet returns kNeedBytes and says which
// (pw_need_offset, pw_need_size): the worker fetches them and calls again. Decoding resumes where
// it stopped, since the Reader keeps its place in the keyframe group.
#include <emscripten.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <memory>
#include <optional>
#include <string>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "particlestream/codec.hpp"
#include "particlestream/format.hpp"
#include "particlestream/frame.hpp"
#include "particlestream/playback.hpp"
#include "particlestream/render.hpp"
#include "particlestream/sort.hpp"
#include "playback/interpolate.hpp"

// Copies `size` bytes at file offset `offset` into `out` from the worker's fetched ranges; returns
// 0, or 1 when they are not all fetched yet.
EM_JS(int, pstream_host_read, (double offset, std::byte* out, double size),
      { return Module.readFetched(offset, out, size); });

namespace {

using namespace pstream;

constexpr int kOk = 0, kError = 1, kNeedBytes = 2;

// A drawn particle: position x, y, z and radius (float32), colour (RGBA8: the stored colour, the
// ramp's where the look colours by speed or an attribute, else the native batch's default), and,
// where the look streaks its sprites, velocity x, y, z (float32, units per second).
constexpr std::size_t kInstanceBytes = 20, kStreakInstanceBytes = 32;

struct NeedBytes {
  std::uint64_t offset, size;
};

class FetchedSource final : public io::ByteSource {
 public:
  FetchedSource(std::uint64_t size, std::string name) : size_(size), name_(std::move(name)) {}
  void read(std::uint64_t offset, std::span<std::byte> out) override {
    if (offset > size_ || out.size() > size_ - offset)
      throw Error(
          fmt::format("{}: read of {} bytes at offset {} past the end ({} bytes)", name_, out.size(), offset, size_));
    if (pstream_host_read(static_cast<double>(offset), out.data(), static_cast<double>(out.size())) != 0)
      throw NeedBytes{offset, out.size()};
  }
  std::uint64_t size() const override { return size_; }
  const std::string& name() const override { return name_; }

 private:
  std::uint64_t size_;
  std::string name_;
};

// A decoded cached frame, and the runs matching its particles to the frame before it.
struct Slot {
  std::uint64_t frame = UINT64_MAX;
  std::uint64_t used = 0;  // when it was last decoded or read (Player::clock)
  std::vector<std::byte> records;
  std::vector<format::MatchRun> matching;
  std::size_t runs = format::kNoMatching;
};

// Decoded frames kept: at least the two an interpolated image needs, and up to 8 within 64 MiB.
// The browser's decoder cannot save its state on the way (its zstd stream lives in the worker), so
// going back decodes from the keyframe; the frames kept from that walk then serve the next steps
// back without decoding (docs/web.md, "Playing backwards").
constexpr std::size_t kMostKeptFrames = 8;
constexpr std::uint64_t kKeptFramesBudget = 64ull << 20;

struct Player {
  std::optional<format::Reader> reader;
  std::optional<format::FrameDecoder> decoder;
  std::optional<playback::FrameBlender> blender;
  std::vector<std::byte> packet, chunk;  // a frame's packet, a chunk
  std::vector<Slot> slots;               // the decoded frames kept, allocated at open
  std::uint64_t clock = 0;               // counts decodes and reads, for Slot::used
  std::uint64_t frames_decoded = 0;      // every frame decoded, those on the way included
  std::vector<std::byte> blended;        // between two cached frames (room for both)
  const std::byte* records = nullptr;    // what pw_pack draws
  std::uint64_t count = 0;
  std::string metadata_json;
  std::vector<float> depths;  // the draw order's buffers, allocated at open
  std::vector<std::uint64_t> pairs, scratch;
  std::vector<std::uint32_t> order;
  std::vector<std::byte> instances;                    // what the page draws, back to front
  std::int32_t scale = -1, color = -1, velocity = -1;  // record offsets, or -1
  std::int32_t scalar = -1;                            // the float attribute the look colours by, or -1
  playback::DrawStyle style;                           // the look (pw_style)
  std::size_t instance_bytes = kInstanceBytes;
  bool ramp_from_first_image = false;  // the ramp's range is taken from the first image's particles
  std::vector<float> ramp_values;      // those particles' speeds or attribute values, allocated at open
  std::string style_json;
  bool shadows = false;  // the look self-shadows: pw_pack sorts along the half-angle, pw_shadow says how to draw
  render::Vec3 light{};  // towards the light, world, unit length (the native renderer's)
  std::array<float, 33> shadow{};  // the light's view and projection, and whether the eye blends front to back
  // The self-shadowing slices of the image pw_pack made: their number, then where each starts in
  // its order and the end (frame.hpp: slice_starts).
  std::array<std::uint32_t, render::kMaxSlices + 2> slices{};
  std::array<float, 6> lights{};  // the key and fill lights in view space, for the view pw_pack sorted along
  std::string liquid_json;        // the liquid's passes for the image pw_pack made (pw_liquid)
  std::array<std::uint8_t, 4> default_color{};  // a particle's where the clip stores none (RGBA8)
  playback::PairCurves curves;                  // whether a pair of frames blends along curves, decided once a pair
};

std::unique_ptr<Player> g = std::make_unique<Player>();
std::string g_error;
NeedBytes g_need{0, 0};

template <class F>
int guarded(F&& f) {
  try {
    f();
    return kOk;
  } catch (const NeedBytes& need) {
    g_need = need;
    return kNeedBytes;
  } catch (const std::exception& e) {
    g_error = e.what();
    return kError;
  }
}

// What the page needs of the clip, as JSON (nlohmann's: names escaped, an empty clip's infinite
// bounds written as null).
std::string describe(const format::Metadata& m) {
  nlohmann::json attributes = nlohmann::json::array(), chunks = nlohmann::json::array(),
                 times = nlohmann::json::array();
  for (const format::Attribute& a : m.layout) {
    attributes.push_back(
        {{"name", a.name}, {"type", static_cast<int>(a.type)}, {"components", a.components}, {"offset", a.offset}});
  }
  for (const format::ChunkEntry& c : m.chunks) {  // file offset and stored size: the page's cache view
    chunks.push_back(c.file_offset);
    chunks.push_back(c.stored_size);
  }
  for (const format::FrameEntry& f : m.frames) times.push_back(f.time);
  return nlohmann::json{{"frames", m.frame_count()},
                        {"fps", m.fps},
                        {"time_of_frame0", m.time_of_frame0},
                        {"record_size", m.record_size},
                        {"max_count", m.max_count},
                        {"bounds", m.bounds},
                        {"attributes", attributes},
                        {"chunks", chunks},
                        {"times", times}}
      .dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

Slot* slot_of(std::uint64_t frame) {
  for (Slot& slot : g->slots)
    if (slot.frame == frame) return &slot;
  return nullptr;
}

// Where decoding `frame` starts: nowhere when it is kept, else on from the frame decoded last, or
// at its keyframe.
std::uint64_t first_to_decode(std::uint64_t frame) {
  if (slot_of(frame) != nullptr) return frame;
  return format::decode_start(g->reader->metadata(), frame, g->decoder->last_decoded());
}

// The slot frame `f` is decoded into, on the way to `target`: the one already holding it, else the
// one used longest ago, sparing the frame before it (its matching by id needs it) and the target's
// successor (played backwards, the image before showed it, and the next interpolates towards it).
Slot& slot_for(std::uint64_t f, std::uint64_t target) {
  if (Slot* held = slot_of(f)) return *held;
  Slot* pick = nullptr;
  for (int spare_successor = 1; spare_successor >= 0 && pick == nullptr; --spare_successor) {
    for (Slot& slot : g->slots) {
      if (slot.frame != UINT64_MAX && (slot.frame + 1 == f || (spare_successor && slot.frame == target + 1))) continue;
      if (pick == nullptr || slot.used < pick->used) pick = &slot;
    }
  }
  return *pick;  // two slots or more: one holds neither the frame before nor, failing that, that successor
}

// Decodes up to `frame`, keeping the frames decoded last. A read that needs bytes not fetched yet
// throws NeedBytes before the decoder's state changes, so a call again resumes.
void decode(std::uint64_t frame) {
  if (Slot* held = slot_of(frame)) {
    held->used = ++g->clock;
    return;
  }
  const format::Metadata& m = g->reader->metadata();
  for (std::uint64_t f = first_to_decode(frame); f <= frame; ++f) {
    const std::uint64_t size = format::frame_packet(m, f).size;
    g->reader->read_packet(f, g->packet, g->chunk);
    Slot& slot = slot_for(f, frame);
    slot.frame = UINT64_MAX;  // a failed decode leaves nothing behind
    slot.runs = g->decoder->decode(f, std::span(g->packet).first(size), slot.records, slot.matching);
    ++g->frames_decoded;
    const Slot* prev = f == 0 ? nullptr : slot_of(f - 1);
    if (slot.runs == format::kNoMatching && prev != nullptr) {
      slot.runs =
          format::match_by_id(m, prev->records, m.frames[f - 1].count, slot.records, m.frames[f].count, slot.matching);
    }
    slot.frame = f;
    slot.used = ++g->clock;
  }
}

}  // namespace

extern "C" {

EMSCRIPTEN_KEEPALIVE const char* pw_error() { return g_error.c_str(); }
EMSCRIPTEN_KEEPALIVE double pw_need_offset() { return static_cast<double>(g_need.offset); }
EMSCRIPTEN_KEEPALIVE double pw_need_size() { return static_cast<double>(g_need.size); }

// Opens the clip at `name` (a URL, for messages) of `size` bytes: header and tables.
EMSCRIPTEN_KEEPALIVE int pw_open(double size, const char* name) {
  return guarded([&] {
    g = std::make_unique<Player>();
    g->reader.emplace(format::Reader::open(std::make_unique<FetchedSource>(static_cast<std::uint64_t>(size), name)));
    const format::Metadata& m = g->reader->metadata();
    g->decoder.emplace(m, name);
    g->blender.emplace(m);
    std::uint64_t largest = 0;
    for (std::uint64_t f = 0; f < m.frame_count(); ++f) largest = std::max(largest, format::frame_packet(m, f).size);
    g->packet.resize(largest);
    g->chunk.resize(std::min(m.chunk_size, m.stream_size()));
    const std::uint64_t slot_bytes = m.max_count * (m.record_size + 2 * sizeof(format::MatchRun));
    g->slots.resize(
        std::clamp<std::uint64_t>(kKeptFramesBudget / std::max<std::uint64_t>(slot_bytes, 1), 2, kMostKeptFrames));
    for (Slot& slot : g->slots) {
      slot.records = format::frame_buffer(m, name);
      slot.matching.resize(2 * m.max_count + 2);
    }
    g->blended.resize(2 * g->slots[0].records.size());
    // Between two frames, a frame's dying and newborn particles are both drawn: up to twice max_count.
    const std::uint64_t most = 2 * m.max_count;
    g->depths.resize(most);
    g->pairs.resize(most);
    g->scratch.resize(most);
    g->order.resize(most);
    g->instances.resize(most * kStreakInstanceBytes);
    g->ramp_values.resize(most);
    if (const format::Attribute* a = m.find("scale"); a && a->type == format::AttributeType::Float32)
      g->scale = static_cast<std::int32_t>(a->offset);
    g->color = playback::color_offset(m);
    g->velocity = playback::velocity_offset(m);
    g->metadata_json = describe(m);
  });
}

EMSCRIPTEN_KEEPALIVE const char* pw_metadata() { return g->metadata_json.c_str(); }

// The look the page asked for (docs/web.md, "Looks"): a preset by name (playback::look_preset, as
// `pstream render --preset`), then its colouring (`--color-by`, `--ramp`, `--ramp-range` when
// `has_range`, `--ramp-attribute`; empty strings leave the preset's), checked against the clip as
// the native player checks it, and what is drawn behind it (`--backdrop`: playback::backdrop_for;
// empty is "auto"). A ramp without a range spans the first image's particles (the native renderer
// samples the clip's frames, which a browser would have to fetch first). pw_style_json() then says
// what the page draws.
EMSCRIPTEN_KEEPALIVE int pw_style(const char* preset, const char* color_by, const char* ramp, int has_range, double low,
                                  double high, const char* ramp_attribute, const char* backdrop) {
  return guarded([&] {
    const format::Metadata& m = g->reader->metadata();
    playback::DrawStyle style = playback::look_preset(*preset != 0 ? preset : "sprites");
    playback::Colouring colouring{color_by, ramp, std::nullopt, ramp_attribute};
    if (has_range != 0) colouring.range = {float(low), float(high)};
    playback::apply_colouring(colouring, style);
    playback::check_style(style, m, g->reader->name());
    const render::SpriteStyle& s = style.sprites;
    g->scalar = -1;
    if (const format::Attribute* a = m.find(style.ramp_attribute); a && !style.ramp_attribute.empty())
      g->scalar = static_cast<std::int32_t>(a->offset);
    g->ramp_from_first_image = s.color_by != render::ColorBy::Stored && has_range == 0;
    const bool liquid = style.look == render::Look::Liquid;
    // Velocities travel with the particles where the look streaks them or makes fast ones spray.
    const bool moving = s.shutter > 0.0f || (liquid && style.liquid.foam_speed > 0.0f && g->velocity >= 0);
    g->instance_bytes = moving ? kStreakInstanceBytes : kInstanceBytes;
    g->style = style;
    // Self-shadowing as natively: sprites sorted front to back along the half-angle between the
    // view and the light, drawn in slices that alternate between the image and the light buffer
    // (additive light casts no shadow).
    g->shadows = s.shadows && style.blend != render::BlendMode::Additive;
    const render::Vec3 l = render::RendererOptions{}.light_direction;
    const float length = std::sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]);
    g->light = {l[0] / length, l[1] / length, l[2] / length};
    const std::array<float, 4> fallback = render::ParticleBatch{}.color;
    for (std::size_t c = 0; c < 4; ++c)
      g->default_color[c] = static_cast<std::uint8_t>(std::lround(fallback[c] * 255.0f));
    const std::optional<render::Backdrop> behind =
        playback::backdrop_for(*backdrop != 0 ? backdrop : "auto", style, m.bounds);
    // The liquid's shadow falls on the ground (Player::draw_data's rule; pw_liquid says whether
    // there is one), its light buffer over the clip's bounds.
    if (behind && behind->ground) g->style.liquid.ground_height = behind->ground_height;
    nlohmann::json unsupported = nlohmann::json::array();
    if (!style.texture.empty()) unsupported.push_back("sprite textures");
    nlohmann::json page;  // what the page's shaders and passes take (web/player.js: draw)
    page["blend"] = static_cast<int>(style.blend);
    page["lit"] = s.lit;
    page["opacity"] = s.opacity;
    page["tint"] = s.tint;
    page["shutter"] = s.shutter;
    page["minPixels"] = s.min_pixels;
    page["exposure"] = s.exposure;
    page["toneMap"] = static_cast<int>(s.tone_map);
    page["bloom"] = s.bloom;
    page["bloomRadius"] = s.bloom_radius;
    page["instanceBytes"] = g->instance_bytes;
    page["background"] = render::kDefaultBackground;
    page["shadows"] = g->shadows;
    page["slices"] = std::clamp(s.slices, 1, render::kMaxSlices);
    page["shadowDensity"] = std::max(s.shadow_density, 0.0f);
    page["shadowBlur"] = s.shadow_blur;
    page["shadowResolution"] = std::clamp(s.shadow_resolution, 64, 4096);
    page["groundShadow"] = std::clamp(s.ground_shadow, 0.0f, 1.0f);
    page["look"] = liquid ? "liquid" : "sprites";
    if (behind) {
      page["backdrop"] = {
          {"ground", behind->ground}, {"groundHeight", behind->ground_height}, {"grid", behind->grid_spacing}};
    }
    if (liquid) {  // what does not change from image to image; pw_liquid gives the rest
      const render::LiquidStyle& l = style.liquid;
      nlohmann::json taps = nlohmann::json::array(), scales = nlohmann::json::array();
      for (int pass = 0; pass < render::kLiquidRampPasses + render::kLiquidMaxIterations; ++pass) {
        taps.push_back(render::liquid_filter_taps(pass));
        scales.push_back(render::liquid_filter_scale(pass));
      }
      page["liquid"] = {{"color", l.color},
                        {"output", static_cast<int>(l.output)},
                        {"pairs", render::kLiquidFilterPairs},
                        {"taps", taps},
                        {"scales", scales}};
    }
    page["unsupported"] = unsupported;
    g->style_json = page.dump();
  });
}
EMSCRIPTEN_KEEPALIVE const char* pw_style_json() { return g->style_json.c_str(); }

// The chunks holding frame `frame`'s packet: first and last index.
EMSCRIPTEN_KEEPALIVE double pw_first_chunk(double frame) {
  return static_cast<double>(g->reader->metadata().frame_chunks(static_cast<std::uint64_t>(frame)).first);
}
EMSCRIPTEN_KEEPALIVE double pw_last_chunk(double frame) {
  return static_cast<double>(g->reader->metadata().frame_chunks(static_cast<std::uint64_t>(frame)).second);
}

// Decodes frame `frame` (kept already, on from the frame decoded last, or forward from its
// keyframe), with the matching to the frame before it, as the native stream does.
EMSCRIPTEN_KEEPALIVE int pw_decode(double frame) {
  return guarded([&] {
    const auto target = static_cast<std::uint64_t>(frame);
    decode(target);
    const Slot& slot = *slot_of(target);
    g->records = slot.records.data();
    g->count = g->reader->metadata().frames.at(target).count;
  });
}
EMSCRIPTEN_KEEPALIVE double pw_count() { return static_cast<double>(g->count); }
EMSCRIPTEN_KEEPALIVE const std::byte* pw_records() { return g->records; }

// The frames pw_show(time) decodes: from pw_first_needed() to the frame after `time`'s (or its own).
EMSCRIPTEN_KEEPALIVE double pw_first_needed(double time) {
  const format::Metadata& m = g->reader->metadata();
  const auto [a, fraction] = m.frame_between(time);
  std::uint64_t first = first_to_decode(a);
  // With `a` kept, its successor is decoded on from the frame decoded last, or from its keyframe.
  if (fraction > 0 && a + 1 < m.frame_count() && first == a) first = std::min(first, first_to_decode(a + 1));
  return static_cast<double>(first);
}
EMSCRIPTEN_KEEPALIVE double pw_last_needed(double time) {
  const format::Metadata& m = g->reader->metadata();
  const auto [a, fraction] = m.frame_between(time);
  return static_cast<double>(fraction > 0 && a + 1 < m.frame_count() ? a + 1 : a);
}
// The frames decoded since open, those on the way to the frames shown included.
EMSCRIPTEN_KEEPALIVE double pw_frames_decoded() { return static_cast<double>(g->frames_decoded); }

// The particles at `time` (seconds from the clip's first frame's time): the cached frame there, or
// between the two around it, interpolated as the native player interpolates (playback.hpp:
// FrameBlender, Hermite along the velocities where the clip has them).
EMSCRIPTEN_KEEPALIVE int pw_show(double time) {
  return guarded([&] {
    const format::Metadata& m = g->reader->metadata();
    const auto [a, fraction] = m.frame_between(time);
    if (fraction > 0 && a + 1 < m.frame_count()) {
      decode(a);
      decode(a + 1);
      const Slot& sa = *slot_of(a);
      const Slot& sb = *slot_of(a + 1);
      const std::span<const format::MatchRun> runs(sb.matching.data(), sb.runs == format::kNoMatching ? 0 : sb.runs);
      const double dt = m.frames[a + 1].time - m.frames[a].time;
      const bool curves = sb.runs != format::kNoMatching && g->curves(a, a + 1, [&] {
        return playback::velocities_describe_matching(sa.records, sb.records, runs, m.record_size, g->velocity, dt);
      });
      g->count =
          g->blender->blend(sa.records, m.frames[a].count, sb.records, m.frames[a + 1].count,
                            sb.runs == format::kNoMatching ? nullptr : &runs, fraction, dt, curves, g->blended.data());
      g->records = g->blended.data();
    } else {
      decode(a);
      g->records = slot_of(a)->records.data();
      g->count = m.frames[a].count;
    }
  });
}

// The frame at or before `time` (seconds) and the fraction towards the next (Metadata's rule).
EMSCRIPTEN_KEEPALIVE double pw_frame_at(double time) {
  const auto [frame, fraction] = g->reader->metadata().frame_between(time);
  return static_cast<double>(frame) + fraction;
}

// The decoded frame's particles as the page draws them, ordered back to front along the view
// `view_world` (16 floats, column-major, object to view). Returns the count; pw_instances() holds them.
EMSCRIPTEN_KEEPALIVE double pw_pack(const float* view_world, int sorted) {
  const format::Metadata& m = g->reader->metadata();
  const std::size_t n = g->count, stride = m.record_size;
  const std::byte* records = g->records;
  std::array<float, 16> vw;
  std::memcpy(vw.data(), view_world, sizeof vw);
  const render::SpriteLights lights = render::sprite_lights(vw, g->light);
  std::copy(lights.key.begin(), lights.key.end(), g->lights.begin());
  std::copy(lights.fill.begin(), lights.fill.end(), g->lights.begin() + 3);
  if (g->shadows || g->style.look == render::Look::Liquid) {  // the light buffer's view over the clip's bounds
    const render::ShadowLight light = render::shadow_light(g->reader->metadata().bounds, vw, g->light);
    std::copy(light.view.begin(), light.view.end(), g->shadow.begin());
    std::copy(light.projection.begin(), light.projection.end(), g->shadow.begin() + 16);
  }
  if (g->shadows) {  // front to back along the half-angle (playback::sort_plan's rule)
    const render::HalfAngle half = render::half_angle(vw, g->light);
    g->shadow[32] = half.eye_front_to_back ? 1.0f : 0.0f;
    vw = half.sort_view;
    render::ParticleBatch batch;
    batch.first = std::span(records, n * stride);
    batch.count = n;
    batch.record_size = static_cast<std::uint32_t>(stride);
    const render::SliceStarts cut = render::slice_starts({&batch, 1}, vw, g->style.sprites.slices, n);
    g->slices[0] = static_cast<std::uint32_t>(cut.slices);
    for (int k = 0; k <= cut.slices; ++k)
      g->slices[std::size_t(k) + 1] = static_cast<std::uint32_t>(cut.starts[std::size_t(k)]);
  }
  if (sorted != 0 || g->shadows) {
    sort::compute_depths(records, n, stride, sort::depth_axis(vw), g->depths.data());
    // Back to front (the farthest, largest depth, first: the depths' order reversed), or front
    // to back along the half-angle.
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint32_t key = sort::order_preserving_key(g->depths[i]);
      g->pairs[i] = std::uint64_t(g->shadows ? key : ~key) << 32 | i;
    }
    sort::radix_sort_pairs(g->pairs.data(), g->scratch.data(), n, g->order.data());
  } else {
    for (std::size_t i = 0; i < n; ++i) g->order[i] = static_cast<std::uint32_t>(i);
  }
  const render::SpriteStyle& look = g->style.sprites;
  const bool by_speed = look.color_by == render::ColorBy::Speed && g->velocity >= 0;
  const bool by_scalar = look.color_by == render::ColorBy::Attribute && g->scalar >= 0;
  // The value a ramp colours by: the speed or the attribute.
  const auto ramp_value = [&](const std::byte* r) {
    float v[3] = {0, 0, 0};
    std::memcpy(v, r + (by_speed ? g->velocity : g->scalar), by_speed ? 12 : 4);
    return by_speed ? std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) : v[0];
  };
  render::Ramp& ramp = g->style.sprites.ramp;
  if (g->ramp_from_first_image && (by_speed || by_scalar) && n > 0) {
    std::size_t k = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const float v = ramp_value(records + i * stride);
      if (std::isfinite(v)) g->ramp_values[k++] = v;
    }
    const std::array<float, 2> range = playback::ramp_range_of(std::span(g->ramp_values).first(k), by_speed);
    ramp.low = range[0], ramp.high = range[1];
    g->ramp_from_first_image = false;
  }
  const std::size_t bytes = g->instance_bytes;
  std::byte* out = g->instances.data();
  for (std::size_t k = 0; k < n; ++k, out += bytes) {
    const std::byte* r = records + std::size_t(g->order[k]) * stride;
    std::memcpy(out, r, 12);  // position at offset 0 (format.md: every layout starts with it)
    float radius = 0.05f;
    if (g->scale >= 0) std::memcpy(&radius, r + g->scale, 4);
    std::memcpy(out + 12, &radius, 4);
    std::array<std::uint8_t, 4> rgba = g->default_color;
    if (g->color >= 0) std::memcpy(rgba.data(), r + g->color, 4);
    if (by_speed || by_scalar) {  // the ramp's colour, the alpha kept (the vertex shader's rule)
      const std::array<float, 3> c = ramp.at(ramp_value(r));
      for (std::size_t i = 0; i < 3; ++i)
        rgba[i] = static_cast<std::uint8_t>(std::lround(std::clamp(c[i], 0.0f, 1.0f) * 255.0f));
    }
    std::memcpy(out + 16, rgba.data(), 4);
    if (bytes == kStreakInstanceBytes) {
      const float none[3] = {0, 0, 0};
      std::memcpy(out + 20, g->velocity >= 0 ? static_cast<const void*>(r + g->velocity) : none, 12);
    }
  }
  return static_cast<double>(n);
}
// The camera the page starts from, for an image of this aspect: at `eye_target` (6 floats: eye
// xyz, target xyz, `camera=`'s; frame.hpp: Camera::looking, as `pstream render --camera`), or, when
// it is null, the framing `pstream render` and the viewer start from for the clip's bounds
// (Camera::framing). Into `out`: eye xyz, target xyz, up xyz, fov_y, near, far.
EMSCRIPTEN_KEEPALIVE void pw_camera(double aspect, const float* eye_target, float* out) {
  const auto& b = g->reader->metadata().bounds;
  const bool empty = !(b[0] <= b[3] && b[1] <= b[4] && b[2] <= b[5]);
  const render::Camera c = eye_target != nullptr
                               ? render::Camera::looking({eye_target[0], eye_target[1], eye_target[2]},
                                                         {eye_target[3], eye_target[4], eye_target[5]})
                           : empty ? render::Camera{}
                                   : render::Camera::framing({b[0], b[1], b[2]}, {b[3], b[4], b[5]}, float(aspect));
  const float values[12] = {c.eye[0], c.eye[1], c.eye[2], c.target[0],     c.target[1], c.target[2],
                            c.up[0],  c.up[1],  c.up[2],  c.fov_y_degrees, c.near,      c.far};
  std::memcpy(out, values, sizeof values);
}

EMSCRIPTEN_KEEPALIVE std::byte* pw_instances() { return g->instances.data(); }
EMSCRIPTEN_KEEPALIVE double pw_instance_bytes() { return static_cast<double>(g->instance_bytes); }
// For a self-shadowing look or a liquid that casts a shadow on the ground, after pw_pack: the light
// buffer's view and projection (16 floats each, column-major) and, self-shadowing, 1 where the
// image blends its slices front to back ("under"), else 0.
EMSCRIPTEN_KEEPALIVE const float* pw_shadow() { return g->shadow.data(); }
// For a self-shadowing look, after pw_pack: the number of slices, then where each starts in the
// order pw_instances() holds, and the end (uint32s; frame.hpp: slice_starts).
EMSCRIPTEN_KEEPALIVE const std::uint32_t* pw_slices() { return g->slices.data(); }
// After pw_pack: the key and the fill light's directions in its view (6 floats; frame.hpp: sprite_lights).
EMSCRIPTEN_KEEPALIVE const float* pw_lights() { return g->lights.data(); }

// For the liquid look, after pw_pack: what its passes take for this image (frame.hpp:
// liquid_passes), seen through `projection` (16 floats, column-major) at width x height pixels,
// with the particles' radius the median of the image's (or the look's); JSON.
EMSCRIPTEN_KEEPALIVE const char* pw_liquid(const float* projection, int width, int height) {
  render::Mat4 p;
  std::memcpy(p.data(), projection, sizeof p);
  const render::LiquidStyle& style = g->style.liquid;
  const std::size_t stride = g->reader->metadata().record_size;
  // Every record's head holds its radius (frame.hpp: kScaleOffset), as the native pass reads it;
  // the page draws the clip unscaled.
  const float median = render::median_radius(g->count, [&](std::uint64_t i) {
    float r = 0;
    std::memcpy(&r, g->records + i * stride + render::kScaleOffset, sizeof r);
    return r;
  });
  const render::LiquidPasses l = render::liquid_passes(style, 1.0f, median, p, width, height);
  g->liquid_json = nlohmann::json{{"width", l.width},
                                  {"height", l.height},
                                  {"radius", l.radius},
                                  {"fixedRadius", l.fixed_radius},
                                  {"radiusPxAt1", l.radius_px_at_1},
                                  {"filterMode", l.filter_mode},
                                  {"filterPasses", l.filter_passes},
                                  {"filterRadiusAt1", l.filter_radius_at_1},
                                  {"range", l.range},
                                  {"colorDepth", l.color_depth},
                                  {"absorb", l.absorb},
                                  {"refraction", l.refraction},
                                  {"opacityDepth", l.opacity_depth},
                                  {"foamSpeed", l.foam_speed},
                                  {"foamThickness", l.foam_thickness},
                                  {"spray", l.spray},
                                  {"shadowDepth", l.shadow_depth},
                                  {"shadowStrength", l.shadow_strength},
                                  {"shadowResolution", l.shadow_resolution}}
                       .dump();
  return g->liquid_json.c_str();
}

}  // extern "C"
