// The C API (include/particlestream/particlestream.h) over the C++ library: opaque handles, error
// codes, per-thread messages; every exception is caught here.
#include "particlestream/particlestream.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <new>
#include <set>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "base/memory.hpp"
#include "capi/callback_io.hpp"
#include "particlestream/alembic.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"
#include "particlestream/io.hpp"
#include "particlestream/playback.hpp"

namespace {

using namespace pstream;

thread_local std::string g_last_error;

pstream_result fail(pstream_result code, std::string message) {
  g_last_error = std::move(message);
  return code;
}

// Runs `body`, turning what it throws into a result and this thread's message. `code` is what a
// pstream::Error means where it is thrown from (a corrupt input, say).
template <class F>
pstream_result guarded(pstream_result code, F&& body) {
  try {
    return body();
  } catch (const OptionError& e) {  // a memory budget or a limit (max_particles, ...), or a bad setting
    const bool limit = e.option() == "budget" || e.option().rfind("max_", 0) == 0;
    return fail(limit ? PSTREAM_ERROR_BUDGET : PSTREAM_ERROR_ARGUMENT, e.what());
  } catch (const Error& e) {
    return fail(code, e.what());
  } catch (const std::bad_alloc&) {
    return fail(PSTREAM_ERROR_BUDGET, "out of memory");
  } catch (const std::exception& e) {
    return fail(PSTREAM_ERROR_INTERNAL, e.what());
  } catch (...) {
    return fail(PSTREAM_ERROR_INTERNAL, "unknown error");
  }
}

// A file that cannot be read is an IO error, whatever the reader would have said about it. A
// URL is checked by opening it (open_location).
pstream_result check_readable(const char* path) {
  if (path == nullptr) return fail(PSTREAM_ERROR_ARGUMENT, "a path is NULL");
  if (io::is_url(path)) return PSTREAM_OK;
  if (::access(path, R_OK) != 0) return fail(PSTREAM_ERROR_IO, std::string(path) + ": " + std::strerror(errno));
  return PSTREAM_OK;
}

// The byte source of a path or URL; a URL that cannot be fetched (refused, not found, no range
// support) is an IO error.
pstream_result open_location(const char* path, std::unique_ptr<io::ByteSource>& out) {
  if (const pstream_result r = check_readable(path); r != PSTREAM_OK) return r;
  return guarded(PSTREAM_ERROR_IO, [&] {
    out = io::open(path);
    return PSTREAM_OK;
  });
}

pstream_result null_argument(const char* what) { return fail(PSTREAM_ERROR_ARGUMENT, std::string(what) + " is NULL"); }

// The handles that are open, so that a closed one (closed twice, used after close) or a pointer
// no open returned is an error code and never a crash. Node-based: an empty set holds no memory,
// so once every handle is closed the library holds nothing from the host's allocator.
std::mutex g_handles_mutex;
std::set<const void*>& open_handles() {
  static std::set<const void*> handles;
  return handles;
}
template <class T>
T* opened(T* handle) {
  std::lock_guard lock(g_handles_mutex);
  open_handles().insert(handle);
  return handle;
}
bool is_open(const void* handle) {
  if (handle == nullptr) return false;
  std::lock_guard lock(g_handles_mutex);
  return open_handles().count(handle) != 0;
}
// Forgets `handle`; false when it was not open.
bool forget(const void* handle) {
  std::lock_guard lock(g_handles_mutex);
  return open_handles().erase(handle) != 0;
}
pstream_result not_open(const char* what, const void* handle) {
  if (handle == nullptr) return null_argument(what);
  return fail(PSTREAM_ERROR_ARGUMENT,
              fmt::format("{} ({}) is not open: it was closed already, or no open returned it", what, handle));
}

void fill_attribute(const format::Attribute& a, pstream_attribute* out) {
  out->name = a.name.c_str();
  out->type = static_cast<int32_t>(a.type);
  out->components = a.components;
  out->offset = a.offset;
}

void fill_info(const format::Metadata& m, pstream_clip_info* out) {
  out->frame_count = m.frame_count();
  out->max_count = m.max_count;
  out->record_size = m.record_size;
  out->attribute_count = static_cast<std::uint32_t>(m.layout.size());
  out->fps = m.fps;
  out->start_time = m.frame_count() ? m.frames.front().time : 0.0;
  out->end_time = m.frame_count() ? m.frames.back().time : 0.0;
  for (int i = 0; i < 6; ++i) out->bounds[i] = m.bounds[static_cast<std::size_t>(i)];
}

// `options` as this release's struct: older callers' structs end before the fields added since,
// which keep their defaults.
pstream_result cook_options_given(const pstream_cook_options* options, pstream_cook_options& given) {
  if (options == nullptr) return null_argument("options");
  if (options->struct_size < offsetof(pstream_cook_options, scale_error))
    return fail(PSTREAM_ERROR_ARGUMENT, "pstream_cook_options.struct_size is smaller than any release's");
  pstream_cook_options_init(&given);
  std::memcpy(&given, options, std::min(options->struct_size, sizeof given));
  return PSTREAM_OK;
}

// The options every cook shares (attributes, codec and bounds), as the library's.
pstream_result to_cook_options(const pstream_cook_options& options, cook::Options& o) {
  o.output = options.output;
  if (options.attributes) cook::add_attributes(o, options.attributes);
  switch (options.codec) {  // the command line's names, so that both choose the same codec
    case PSTREAM_CODEC_RAW: cook::set_codec(o, "raw"); break;
    case PSTREAM_CODEC_LZ4: cook::set_codec(o, "lz4"); break;
    case PSTREAM_CODEC_ZSTD: cook::set_codec(o, "zstd"); break;
    case PSTREAM_CODEC_PARTICLE:
    case PSTREAM_CODEC_PARTICLE_LOSSLESS:
      cook::set_codec(o, options.codec == PSTREAM_CODEC_PARTICLE ? "particle" : "particle-lossless");
      // The same rules as the command line's --error, --scale-error and --attribute-error; a
      // bound they refuse is the caller's argument.
      try {
        if (options.error != 0) {
          cook::set_error_bound(o, fmt::format("{}:{}", options.error_in_scene_units ? "abs" : "rel", options.error),
                                "error");
        }
        cook::set_scale_error(o, fmt::format("{}", options.scale_error), "scale_error");
        cook::set_attribute_error(o, fmt::format("{}", options.attribute_error), "attribute_error");
      } catch (const Error& e) {
        return fail(PSTREAM_ERROR_ARGUMENT, e.what());
      }
      o.particle.derive_velocity = options.store_velocity == 0;
      break;
    default: return fail(PSTREAM_ERROR_ARGUMENT, "unknown codec " + std::to_string(options.codec));
  }
  return PSTREAM_OK;
}

// Runs `cook` with the caller's progress callback (non-zero cancels: PSTREAM_ERROR_STATE) and fills
// `report` (may be NULL). `what` names the cook in the cancellation's message.
template <class Cook>
pstream_result run_cook(const pstream_cook_options& options, const char* what, pstream_cook_report* report,
                        const Cook& cook) {
  bool cancelled = false;
  std::function<void(const cook::Progress&)> progress;
  if (options.progress) {
    progress = [&](const cook::Progress& p) {
      if (p.stage == cook::Stage::Fetch) return;  // bytes, not frames
      if (options.progress(options.progress_user, p.frames_done, p.frame_count) != 0) {
        cancelled = true;
        throw Error(std::string(what) + ": the cook was cancelled by its progress callback");
      }
    };
  }
  try {
    const cook::Report r = cook(progress);
    if (report) *report = {r.frames, r.particles, r.file_bytes, r.seconds};
  } catch (const Error& e) {
    if (cancelled) return fail(PSTREAM_ERROR_STATE, e.what());
    throw;
  }
  return PSTREAM_OK;
}

}  // namespace

struct pstream_archive {
  alembic::Archive archive;
  std::vector<alembic::Object> points;
};

struct pstream_clip {
  format::Reader reader;
};

struct pstream_spool {
  cook::FrameSpool spool;
};

struct pstream_player {
  std::unique_ptr<playback::Player> player;
  sort::SortMode sort = sort::SortMode::BackToFront;
  std::uint64_t cache_bytes = 0;
};

extern "C" {

uint32_t pstream_version(void) { return PSTREAM_VERSION; }

pstream_result pstream_set_allocator(const pstream_allocator* allocator) {
  memory::Allocator a;
  if (allocator != nullptr) {
    if (allocator->allocate == nullptr || allocator->free == nullptr)
      return fail(PSTREAM_ERROR_ARGUMENT, "the allocator's allocate or free is NULL");
    a = memory::Allocator{allocator->user, allocator->allocate, allocator->free};
  }
  if (!memory::set_allocator(a))
    return fail(PSTREAM_ERROR_STATE, "64 allocators were installed already (each is kept for its blocks)");
  return PSTREAM_OK;
}
const char* pstream_last_error(void) { return g_last_error.c_str(); }

const char* pstream_result_name(pstream_result result) {
  switch (result) {
    case PSTREAM_OK: return "PSTREAM_OK";
    case PSTREAM_ERROR_ARGUMENT: return "PSTREAM_ERROR_ARGUMENT";
    case PSTREAM_ERROR_IO: return "PSTREAM_ERROR_IO";
    case PSTREAM_ERROR_FORMAT: return "PSTREAM_ERROR_FORMAT";
    case PSTREAM_ERROR_BUDGET: return "PSTREAM_ERROR_BUDGET";
    case PSTREAM_ERROR_STATE: return "PSTREAM_ERROR_STATE";
    case PSTREAM_ERROR_INTERNAL: return "PSTREAM_ERROR_INTERNAL";
  }
  return "PSTREAM_ERROR_UNKNOWN";
}

// ---- Archives ----------------------------------------------------------------------------

pstream_result pstream_archive_open(const char* path, pstream_archive** out) {
  if (out == nullptr) return null_argument("out");
  *out = nullptr;
  if (const pstream_result r = check_readable(path); r != PSTREAM_OK) return r;
  return guarded(PSTREAM_ERROR_FORMAT, [&] {
    auto a = std::make_unique<pstream_archive>(pstream_archive{alembic::Archive::open(path), {}});
    for (const alembic::Object& o : a->archive.objects()) {
      if (alembic::Points::matches(o)) a->points.push_back(o);
    }
    *out = opened(a.release());
    return PSTREAM_OK;
  });
}

pstream_result pstream_archive_close(pstream_archive* archive) {
  if (archive == nullptr) return PSTREAM_OK;  // as free(NULL)
  if (!forget(archive)) return not_open("the archive", archive);
  delete archive;
  return PSTREAM_OK;
}

pstream_result pstream_archive_points_count(const pstream_archive* archive, size_t* count) {
  if (!is_open(archive)) return not_open("the archive", archive);
  if (count == nullptr) return null_argument("count");
  *count = archive->points.size();
  return PSTREAM_OK;
}

pstream_result pstream_archive_points_info(const pstream_archive* archive, size_t index, const char** full_name,
                                           uint32_t* samples) {
  if (!is_open(archive)) return not_open("the archive", archive);
  if (index >= archive->points.size())
    return fail(PSTREAM_ERROR_ARGUMENT,
                "points object " + std::to_string(index) + " of " + std::to_string(archive->points.size()));
  return guarded(PSTREAM_ERROR_FORMAT, [&] {
    if (full_name) *full_name = archive->points[index].full_name().c_str();
    if (samples) *samples = alembic::Points(archive->points[index]).num_samples();
    return PSTREAM_OK;
  });
}

pstream_result pstream_archive_points_sample(const pstream_archive* archive, size_t index, uint32_t sample,
                                             uint64_t* count, double* time) {
  if (!is_open(archive)) return not_open("the archive", archive);
  if (index >= archive->points.size()) return fail(PSTREAM_ERROR_ARGUMENT, "no points object " + std::to_string(index));
  return guarded(PSTREAM_ERROR_FORMAT, [&] {
    const alembic::Points points(archive->points[index]);
    if (sample >= points.num_samples())
      return fail(PSTREAM_ERROR_ARGUMENT,
                  "sample " + std::to_string(sample) + " of " + std::to_string(points.num_samples()));
    if (count) *count = points.count(sample);
    if (time) *time = points.sample_time(sample);
    return PSTREAM_OK;
  });
}

pstream_result pstream_archive_read_positions(const pstream_archive* archive, size_t index, uint32_t sample, float* out,
                                              uint64_t capacity) {
  if (!is_open(archive)) return not_open("the archive", archive);
  if (out == nullptr) return null_argument("out");
  if (index >= archive->points.size()) return fail(PSTREAM_ERROR_ARGUMENT, "no points object " + std::to_string(index));
  return guarded(PSTREAM_ERROR_FORMAT, [&] {
    const alembic::Points points(archive->points[index]);
    if (sample >= points.num_samples()) return fail(PSTREAM_ERROR_ARGUMENT, "no sample " + std::to_string(sample));
    const alembic::SampleView p = points.positions(sample);
    const std::uint64_t floats = p.bytes().size() / 4;
    if (capacity < floats)
      return fail(PSTREAM_ERROR_ARGUMENT,
                  "the buffer holds " + std::to_string(capacity) + " floats, the sample has " + std::to_string(floats));
    if (floats != 0) std::memcpy(out, p.bytes().data(), floats * 4);
    archive->archive.check_intact();
    return PSTREAM_OK;
  });
}

// ---- Cooking ------------------------------------------------------------------------------

void pstream_cook_options_init(pstream_cook_options* options) {
  if (options == nullptr) return;
  *options = pstream_cook_options{};
  options->struct_size = sizeof(pstream_cook_options);
  options->codec = PSTREAM_CODEC_PARTICLE;
  options->error = 1e-4;
  options->scale_error = 0.01;
  options->attribute_error = 1e-3;
}

pstream_result pstream_cook(const pstream_cook_options* options, pstream_cook_report* report) {
  pstream_cook_options given;
  if (const pstream_result r = cook_options_given(options, given); r != PSTREAM_OK) return r;
  if (given.output == nullptr) return null_argument("options->output");
  if (const pstream_result r = check_readable(given.input); r != PSTREAM_OK) return r;
  return guarded(PSTREAM_ERROR_FORMAT, [&] {
    cook::Options o;
    if (const pstream_result r = to_cook_options(given, o); r != PSTREAM_OK) return r;
    o.input = given.input;
    if (given.object) o.object = given.object;
    o.fps = given.fps;
    o.interpolate = given.interpolate != 0;
    return run_cook(given, given.input, report, [&](const auto& progress) { return cook::cook(o, progress); });
  });
}

// ---- Spools -------------------------------------------------------------------------------

pstream_result pstream_spool_open(const char* folder, const char* name, pstream_spool** out) {
  if (out == nullptr) return null_argument("out");
  *out = nullptr;
  return guarded(PSTREAM_ERROR_IO, [&] {
    *out = opened(new pstream_spool{cook::FrameSpool(name ? name : "particles", folder ? folder : "")});
    return PSTREAM_OK;
  });
}

pstream_result pstream_spool_add(pstream_spool* spool, const pstream_spool_frame* frame) {
  if (!is_open(spool)) return not_open("the spool", spool);
  if (frame == nullptr) return null_argument("frame");
  if (frame->struct_size < sizeof(pstream_spool_frame))
    return fail(PSTREAM_ERROR_ARGUMENT, "pstream_spool_frame.struct_size is smaller than any release's");
  if (frame->count > 0 && frame->position == nullptr) return null_argument("frame->position");
  if (frame->float_count > 0 && frame->floats == nullptr) return null_argument("frame->floats");
  return guarded(PSTREAM_ERROR_ARGUMENT, [&] {
    // Sizes are the frame's own: count x components, each array checked for presence only.
    const std::uint64_t n = frame->count;
    const auto floats = [n](const float* p, std::size_t k) {
      return p == nullptr || n == 0 ? std::span<const float>{} : std::span<const float>(p, n * k);
    };
    cook::MemoryFrame f;
    f.time = frame->time;
    f.count = n;
    f.position = floats(frame->position, 3);
    f.width = floats(frame->width, 1);
    f.velocity = floats(frame->velocity, 3);
    f.color = floats(frame->color, 4);
    if (frame->id != nullptr && n > 0) f.id = {frame->id, n};
    for (std::uint32_t k = 0; k < frame->float_count; ++k) {
      const pstream_float_attribute& a = frame->floats[k];
      if (a.name == nullptr) return null_argument("a float attribute's name");
      if (a.values == nullptr && n > 0) return null_argument("a float attribute's values");
      // The components are checked (1 to 16) before any span is made from them.
      f.floats.push_back(
          {a.name, a.components,
           a.components < 1 || a.components > 16 ? std::span<const float>{} : floats(a.values, a.components)});
    }
    spool->spool.check(f);  // what the frame holds is the caller's argument (the guard's code) ...
    try {
      spool->spool.add(f);
    } catch (const Error& e) {
      return fail(PSTREAM_ERROR_IO, e.what());  // ... and a write that failed, the disk's
    }
    return PSTREAM_OK;
  });
}

pstream_result pstream_spool_cook(pstream_spool* spool, const pstream_cook_options* options,
                                  pstream_cook_report* report) {
  if (!is_open(spool)) return not_open("the spool", spool);
  pstream_cook_options given;
  if (const pstream_result r = cook_options_given(options, given); r != PSTREAM_OK) return r;
  if (given.output == nullptr) return null_argument("options->output");
  if (given.input != nullptr)
    return fail(PSTREAM_ERROR_ARGUMENT, "a spool's cook reads its frames: options->input must be NULL");
  if (given.interpolate != 0)
    return fail(PSTREAM_ERROR_ARGUMENT,
                "a spool's frames are cooked each from the nearest: options->interpolate must be 0");
  return guarded(PSTREAM_ERROR_ARGUMENT, [&] {
    cook::Options o;
    if (const pstream_result r = to_cook_options(given, o); r != PSTREAM_OK) return r;
    const cook::MemoryClip clip =
        spool->spool.clip(given.object ? given.object : "particles", given.fps > 0 ? given.fps : 24.0);
    return run_cook(given, clip.name.c_str(), report,
                    [&](const auto& progress) { return cook::cook(o, clip, progress); });
  });
}

pstream_result pstream_spool_close(pstream_spool* spool) {
  if (spool == nullptr) return PSTREAM_OK;  // as free(NULL)
  if (!forget(spool)) return not_open("the spool", spool);
  delete spool;
  return PSTREAM_OK;
}

// ---- Clips --------------------------------------------------------------------------------

pstream_result pstream_clip_open(const char* path, pstream_clip** out) {
  if (out == nullptr) return null_argument("out");
  *out = nullptr;
  std::unique_ptr<io::ByteSource> source;  // a URL's; a local file is mapped by the reader
  if (const pstream_result r = path && io::is_url(path) ? open_location(path, source) : check_readable(path);
      r != PSTREAM_OK)
    return r;
  return guarded(PSTREAM_ERROR_FORMAT, [&] {
    *out = opened(new pstream_clip{source ? format::Reader::open(std::move(source)) : format::Reader::open(path)});
    return PSTREAM_OK;
  });
}

pstream_result pstream_clip_close(pstream_clip* clip) {
  if (clip == nullptr) return PSTREAM_OK;  // as free(NULL)
  if (!forget(clip)) return not_open("the clip", clip);
  delete clip;
  return PSTREAM_OK;
}

pstream_result pstream_clip_info_get(const pstream_clip* clip, pstream_clip_info* out) {
  if (!is_open(clip)) return not_open("the clip", clip);
  if (out == nullptr) return null_argument("out");
  fill_info(clip->reader.metadata(), out);
  return PSTREAM_OK;
}

pstream_result pstream_clip_attribute(const pstream_clip* clip, uint32_t index, pstream_attribute* out) {
  if (!is_open(clip)) return not_open("the clip", clip);
  if (out == nullptr) return null_argument("out");
  const auto& layout = clip->reader.metadata().layout;
  if (index >= layout.size()) return fail(PSTREAM_ERROR_ARGUMENT, "no attribute " + std::to_string(index));
  fill_attribute(layout[index], out);
  return PSTREAM_OK;
}

pstream_result pstream_clip_frame_info(const pstream_clip* clip, uint64_t frame, uint64_t* count, double* time) {
  if (!is_open(clip)) return not_open("the clip", clip);
  const format::Metadata& m = clip->reader.metadata();
  if (frame >= m.frame_count())
    return fail(PSTREAM_ERROR_ARGUMENT, "frame " + std::to_string(frame) + " of " + std::to_string(m.frame_count()));
  if (count) *count = m.frames[frame].count;
  if (time) *time = m.frames[frame].time;
  return PSTREAM_OK;
}

pstream_result pstream_clip_read_frame(pstream_clip* clip, uint64_t frame, void* out, uint64_t capacity) {
  if (!is_open(clip)) return not_open("the clip", clip);
  if (out == nullptr) return null_argument("out");
  const format::Metadata& m = clip->reader.metadata();
  if (frame >= m.frame_count())
    return fail(PSTREAM_ERROR_ARGUMENT, "frame " + std::to_string(frame) + " of " + std::to_string(m.frame_count()));
  const std::uint64_t bytes = m.frames[frame].count * m.record_size;
  if (capacity < bytes)
    return fail(PSTREAM_ERROR_ARGUMENT, "frame " + std::to_string(frame) + " needs " + std::to_string(bytes) +
                                            " bytes, the buffer has " + std::to_string(capacity));
  return guarded(PSTREAM_ERROR_FORMAT, [&] {
    // The reader decodes into a whole frame's room; the caller's buffer may be just the records.
    clip->reader.read_frame(frame, {static_cast<std::byte*>(out), static_cast<std::size_t>(capacity)});
    return PSTREAM_OK;
  });
}

// ---- Playback -----------------------------------------------------------------------------

void pstream_player_options_init(pstream_player_options* options) {
  if (options == nullptr) return;
  *options = pstream_player_options{};
  options->struct_size = sizeof(pstream_player_options);
  options->cache_seconds = 1.0;
  options->interpolation = PSTREAM_INTERPOLATION_HERMITE;
  options->sort = PSTREAM_SORT_BACK_TO_FRONT;
  options->loop = 1;
  options->saved_states = static_cast<int32_t>(stream::StreamOptions{}.saved_states);
}

pstream_result pstream_player_open(const char* const* paths, size_t count, const pstream_player_options* options,
                                   pstream_player** out) {
  if (out == nullptr) return null_argument("out");
  *out = nullptr;
  pstream_player_options o;
  pstream_player_options_init(&o);
  if (options) {
    // Older callers' structs end before the fields added since: what they have, then defaults.
    constexpr std::size_t kFirstRelease = offsetof(pstream_player_options, io_timeout_seconds);
    if (options->struct_size < kFirstRelease)
      return fail(PSTREAM_ERROR_ARGUMENT, "pstream_player_options.struct_size is smaller than any release's");
    std::memcpy(&o, options, std::min(options->struct_size, sizeof o));
    if (options->struct_size < offsetof(pstream_player_options, playback) + sizeof o.playback)
      o.playback = PSTREAM_PLAYBACK_CPU;
    o.struct_size = sizeof o;
  }
  if (count == 0) return fail(PSTREAM_ERROR_ARGUMENT, "a player needs at least one clip");
  std::vector<std::unique_ptr<io::ByteSource>> sources;  // when a path is a URL: every clip's
  if (o.io == nullptr) {
    if (paths == nullptr) return null_argument("paths");
    bool urls = false;
    for (size_t i = 0; i < count; ++i) {
      if (const pstream_result r = check_readable(paths[i]); r != PSTREAM_OK) return r;
      urls = urls || io::is_url(paths[i]);
    }
    for (size_t i = 0; urls && i < count; ++i) {
      if (const pstream_result r = open_location(paths[i], sources.emplace_back()); r != PSTREAM_OK) return r;
    }
  } else {
    for (size_t i = 0; i < count; ++i) {
      if (o.io[i].read == nullptr && o.io[i].read_async == nullptr)
        return fail(PSTREAM_ERROR_ARGUMENT, "io[" + std::to_string(i) + "] has neither read nor read_async");
    }
  }
  if (o.tasks && o.tasks->submit == nullptr) return fail(PSTREAM_ERROR_ARGUMENT, "tasks->submit is NULL");
  if (o.interpolation < PSTREAM_INTERPOLATION_NONE || o.interpolation > PSTREAM_INTERPOLATION_HERMITE)
    return fail(PSTREAM_ERROR_ARGUMENT, "unknown interpolation " + std::to_string(o.interpolation));
  if (o.sort < PSTREAM_SORT_NONE || o.sort > PSTREAM_SORT_FRONT_TO_BACK)
    return fail(PSTREAM_ERROR_ARGUMENT, "unknown sort " + std::to_string(o.sort));
  if (!(o.cache_seconds >= 0.0)) return fail(PSTREAM_ERROR_ARGUMENT, "cache_seconds must be 0 or more");
  if (o.playback != PSTREAM_PLAYBACK_CPU && o.playback != PSTREAM_PLAYBACK_GPU)
    return fail(PSTREAM_ERROR_ARGUMENT, "unknown playback " + std::to_string(o.playback) + " (0: cpu, 1: gpu)");
  if (o.saved_states < 0)
    return fail(PSTREAM_ERROR_ARGUMENT, "saved_states is " + std::to_string(o.saved_states) + ", expected 0 or more");
  if (!(o.io_timeout_seconds >= 0.0) || !std::isfinite(o.io_timeout_seconds))
    return fail(PSTREAM_ERROR_ARGUMENT, "io_timeout_seconds must be a finite number of seconds, 0 or more");
  return guarded(PSTREAM_ERROR_FORMAT, [&] {
    playback::PlayerOptions po;
    po.interpolation = static_cast<playback::Interpolation>(o.interpolation);
    po.path = o.playback == PSTREAM_PLAYBACK_GPU ? playback::PlaybackPath::Gpu : playback::PlaybackPath::Cpu;
    po.stream.cache_seconds = o.cache_seconds;
    po.stream.saved_states = static_cast<std::size_t>(o.saved_states);
    po.stream.blocking = o.blocking != 0;
    po.loop = o.loop != 0;
    if (o.memory_budget) po.stream.budget = std::make_shared<stream::MemoryBudget>(o.memory_budget);
    if (o.tasks) {
      const pstream_tasks tasks = *o.tasks;
      po.stream.scheduler = std::make_shared<stream::IoScheduler>(
          [tasks](void (*run)(void*), void* job) { tasks.submit(tasks.user, run, job); });
    } else {  // the player's own IO thread, not a process-wide one: nothing outlives the handle
      po.stream.scheduler = std::make_shared<stream::IoScheduler>(1);
    }
    std::vector<std::filesystem::path> files(count);
    for (size_t i = 0; i < count; ++i) {
      if (o.io) {
        po.io.push_back(capi::callback_io(o.io[i], o.io_timeout_seconds));
        files[i] = o.io[i].name ? o.io[i].name : "pstream_io";
      } else {
        files[i] = paths[i];
      }
    }
    if (!sources.empty()) po.io = std::move(sources);
    auto p = std::make_unique<pstream_player>();
    p->sort = o.sort == PSTREAM_SORT_NONE            ? sort::SortMode::None
              : o.sort == PSTREAM_SORT_FRONT_TO_BACK ? sort::SortMode::FrontToBack
                                                     : sort::SortMode::BackToFront;
    p->player = playback::Player::open(files, std::move(po));
    for (std::size_t i = 0; i < p->player->clip_count(); ++i) {
      const stream::DebugInfo d = p->player->clip(i).debug();
      p->cache_bytes += d.cache_bytes + d.decode_bytes;
    }
    *out = opened(p.release());
    return PSTREAM_OK;
  });
}

pstream_result pstream_player_close(pstream_player* player) {
  if (player == nullptr) return PSTREAM_OK;  // as free(NULL)
  if (!forget(player)) return not_open("the player", player);
  delete player;
  return PSTREAM_OK;
}

#define PSTREAM_PLAYER_CALL(player, body)                        \
  do {                                                           \
    if (!is_open(player)) return not_open("the player", player); \
    return guarded(PSTREAM_ERROR_STATE, [&] {                    \
      body;                                                      \
      return PSTREAM_OK;                                         \
    });                                                          \
  } while (0)

pstream_result pstream_player_play(pstream_player* player) { PSTREAM_PLAYER_CALL(player, player->player->play()); }
pstream_result pstream_player_pause(pstream_player* player) { PSTREAM_PLAYER_CALL(player, player->player->pause()); }
pstream_result pstream_player_seek(pstream_player* player, double time) {
  if (!std::isfinite(time)) return fail(PSTREAM_ERROR_ARGUMENT, "seek: the time is not finite");
  PSTREAM_PLAYER_CALL(player, player->player->seek(time));
}
pstream_result pstream_player_set_speed(pstream_player* player, double speed) {
  if (!std::isfinite(speed)) return fail(PSTREAM_ERROR_ARGUMENT, "set_speed: the speed is not finite");
  PSTREAM_PLAYER_CALL(player, player->player->set_speed(speed));
}
pstream_result pstream_player_set_loop(pstream_player* player, int loop) {
  PSTREAM_PLAYER_CALL(player, player->player->set_loop(loop != 0));
}
pstream_result pstream_player_set_range(pstream_player* player, double start, double end) {
  if (!std::isfinite(start) || !std::isfinite(end)) return fail(PSTREAM_ERROR_ARGUMENT, "set_range: not finite");
  PSTREAM_PLAYER_CALL(player, player->player->set_range(start, end));
}

pstream_result pstream_player_set_transform(pstream_player* player, size_t clip, const float world[16]) {
  if (!is_open(player)) return not_open("the player", player);
  if (world == nullptr) return null_argument("world");
  if (clip >= player->player->clip_count()) return fail(PSTREAM_ERROR_ARGUMENT, "no clip " + std::to_string(clip));
  render::Mat4 m;
  std::memcpy(m.data(), world, sizeof(float) * 16);
  player->player->set_world_transform(clip, m);
  return PSTREAM_OK;
}

pstream_result pstream_player_update(pstream_player* player, double dt, const float view[16]) {
  if (!is_open(player)) return not_open("the player", player);
  if (!(dt >= 0.0) || !std::isfinite(dt)) return fail(PSTREAM_ERROR_ARGUMENT, "update: dt must be finite and >= 0");
  render::Mat4 v = render::identity();
  if (view) std::memcpy(v.data(), view, sizeof(float) * 16);
  return guarded(PSTREAM_ERROR_STATE, [&] {
    player->player->advance(dt, v, player->sort);
    return PSTREAM_OK;
  });
}

pstream_result pstream_player_check(const pstream_player* player) {
  if (!is_open(player)) return not_open("the player", player);
  return guarded(PSTREAM_ERROR_STATE, [&] {
    player->player->check();
    return PSTREAM_OK;
  });
}

size_t pstream_player_clip_count(const pstream_player* player) {
  return is_open(player) ? player->player->clip_count() : 0;
}

pstream_result pstream_player_frame(const pstream_player* player, size_t clip, pstream_frame* out) {
  if (!is_open(player)) return not_open("the player", player);
  if (out == nullptr) return null_argument("out");
  const playback::Player& p = *player->player;
  if (clip >= p.clip_count()) return fail(PSTREAM_ERROR_ARGUMENT, "no clip " + std::to_string(clip));
  *out = pstream_frame{};
  const stream::ParticleStream& s = p.clip(clip);
  out->time = s.time();
  out->fraction = s.fraction();
  out->frame = s.frame().frame;
  out->color_offset = out->velocity_offset = -1;
  out->record_size = s.metadata().record_size;
  // The batch advance() made for this clip (a clip without particles has none).
  const std::ptrdiff_t batch = p.batch_of(clip);
  if (batch < 0) return PSTREAM_OK;
  const render::ParticleBatch& b = p.batches()[static_cast<std::size_t>(batch)];
  out->records = b.pair != nullptr ? nullptr : b.first.data();  // the GPU path: pstream_player_frame_pair()
  out->count = b.count;
  out->color_offset = b.color_offset;
  out->velocity_offset = b.velocity_offset;
  out->order = b.order.empty() ? nullptr : b.order.data();
  return PSTREAM_OK;
}

pstream_result pstream_player_frame_pair(const pstream_player* player, size_t clip, pstream_frame_pair* out) {
  if (!is_open(player)) return not_open("the player", player);
  if (out == nullptr) return null_argument("out");
  const playback::Player& p = *player->player;
  if (clip >= p.clip_count()) return fail(PSTREAM_ERROR_ARGUMENT, "no clip " + std::to_string(clip));
  if (p.path() != playback::PlaybackPath::Gpu)
    return fail(PSTREAM_ERROR_ARGUMENT, "pstream_player_frame_pair needs a player opened with PSTREAM_PLAYBACK_GPU");
  *out = pstream_frame_pair{};
  const std::ptrdiff_t batch = p.batch_of(clip);
  if (batch < 0) return PSTREAM_OK;
  const render::FramePair& f = *p.batches()[static_cast<std::size_t>(batch)].pair;
  static_assert(sizeof(render::ParticlePair) == 8 && sizeof(render::RecordLane) == 1);
  static_assert(std::uint8_t(render::RecordLane::Copy) == PSTREAM_LANE_COPY &&
                std::uint8_t(render::RecordLane::Lerp) == PSTREAM_LANE_LERP &&
                std::uint8_t(render::RecordLane::Position) == PSTREAM_LANE_POSITION &&
                std::uint8_t(render::RecordLane::Velocity) == PSTREAM_LANE_VELOCITY);
  static_assert(render::kNoParticle == PSTREAM_NO_PARTICLE);
  out->a = f.a.data();
  out->a_frame = f.a_frame;
  out->a_count = f.a_count;
  if (!f.pairs.empty()) {
    out->b = f.b.data();
    out->b_frame = f.b_frame;
    out->b_count = f.b_count;
    out->pairs = reinterpret_cast<const std::uint32_t*>(f.pairs.data());
    out->pair_count = f.pairs.size();
  }
  out->pairs_version = f.pairs_version;
  out->t = f.t;
  out->dt = f.dt;
  out->hermite = f.hermite ? 1 : 0;
  out->nearer = f.nearer ? 1 : 0;
  out->record_size = f.record_size;
  out->lane_count = static_cast<std::uint32_t>(f.lanes.size());
  out->lanes = reinterpret_cast<const std::uint8_t*>(f.lanes.data());
  out->velocity_offset = f.velocity_offset;
  out->color_offset = f.color_offset;
  return PSTREAM_OK;
}

pstream_result pstream_player_merged_order(const pstream_player* player, const uint32_t** order, uint64_t* count) {
  if (!is_open(player)) return not_open("the player", player);
  if (order == nullptr || count == nullptr) return null_argument("order or count");
  const std::span<const std::uint32_t> merged = player->player->merged_order();
  *order = merged.empty() ? nullptr : merged.data();
  *count = merged.size();
  return PSTREAM_OK;
}

pstream_result pstream_player_clip_info(const pstream_player* player, size_t clip, pstream_clip_info* out) {
  if (!is_open(player)) return not_open("the player", player);
  if (out == nullptr) return null_argument("out");
  if (clip >= player->player->clip_count()) return fail(PSTREAM_ERROR_ARGUMENT, "no clip " + std::to_string(clip));
  fill_info(player->player->clip(clip).metadata(), out);
  return PSTREAM_OK;
}

pstream_result pstream_player_attribute(const pstream_player* player, size_t clip, uint32_t index,
                                        pstream_attribute* out) {
  if (!is_open(player)) return not_open("the player", player);
  if (out == nullptr) return null_argument("out");
  if (clip >= player->player->clip_count()) return fail(PSTREAM_ERROR_ARGUMENT, "no clip " + std::to_string(clip));
  const auto& layout = player->player->clip(clip).metadata().layout;
  if (index >= layout.size()) return fail(PSTREAM_ERROR_ARGUMENT, "no attribute " + std::to_string(index));
  fill_attribute(layout[index], out);
  return PSTREAM_OK;
}

pstream_result pstream_player_stats_get(const pstream_player* player, pstream_player_stats* out) {
  if (!is_open(player)) return not_open("the player", player);
  if (out == nullptr) return null_argument("out");
  const playback::FrameStats& s = player->player->stats();
  *out = pstream_player_stats{};
  out->stream_ms = s.stream_ms;
  out->interpolate_ms = s.interpolate_ms;
  out->sort_ms = s.sort_ms;
  out->particles = s.particles;
  out->failed_clips = static_cast<uint32_t>(s.failed_clips);
  out->cache_bytes = player->cache_bytes;
  for (std::size_t i = 0; i < player->player->clip_count(); ++i) out->stalls += player->player->clip(i).debug().stalls;
  return PSTREAM_OK;
}

}  // extern "C"
