/* ParticleStream C API (C99): the library behind a stable C ABI, for engines (native plugins,
 * GDExtension, in-house engines) and any language with a C FFI.
 *
 * Handles are opaque. Every function that can fail returns a pstream_result; on failure the
 * message (file, frame or offset, and what was expected, as the C++ library words it) is kept
 * per thread and read with pstream_last_error(). No C++ exception ever crosses this boundary.
 * Functions that take a handle accept NULL and return PSTREAM_ERROR_ARGUMENT.
 *
 * Memory: a handle allocates when it opens (the player: every cache, sorter and buffer, once)
 * and pstream_player_update() allocates nothing.
 *
 * ABI rules (docs/embedding.md): within a major version, functions are only added, enumerators only
 * appended, and option structs only grow at their end; each option struct starts with its
 * `struct_size` (set it with sizeof), so a library reads what the caller's version wrote and
 * defaults the rest. Handles never expose their layout. The shared library's SONAME carries the
 * major version.
 *
 *   pstream_player* player = NULL;
 *   const char* clips[] = {"splash.pstream"};
 *   pstream_player_options options;
 *   pstream_player_options_init(&options);
 *   if (pstream_player_open(clips, 1, &options, &player) != PSTREAM_OK)
 *     fprintf(stderr, "%s\n", pstream_last_error());
 *   pstream_player_play(player);
 *   each host frame:
 *     pstream_player_update(player, dt, view_matrix);       // stream, interpolate, sort
 *     pstream_frame frame;
 *     pstream_player_frame(player, 0, &frame);              // records in draw order
 *   pstream_player_close(player);
 */
#ifndef PARTICLESTREAM_H
#define PARTICLESTREAM_H

#include <stddef.h>
#include <stdint.h>

#define PSTREAM_VERSION_MAJOR 0
#define PSTREAM_VERSION_MINOR 1
#define PSTREAM_VERSION_PATCH 0
/* major * 10000 + minor * 100 + patch: what this header describes. */
#define PSTREAM_VERSION (PSTREAM_VERSION_MAJOR * 10000 + PSTREAM_VERSION_MINOR * 100 + PSTREAM_VERSION_PATCH)

#if defined(_WIN32)
#define PSTREAM_API __declspec(dllimport)
#elif defined(__GNUC__)
#define PSTREAM_API __attribute__((visibility("default")))
#else
#define PSTREAM_API
#endif

#ifdef __cplusplus
extern "C" {
#endif

/* ---- Results and errors ---------------------------------------------------------------- */

typedef enum pstream_result {
  PSTREAM_OK = 0,
  PSTREAM_ERROR_ARGUMENT = 1, /* a NULL handle or pointer, an index out of range, a bad option */
  PSTREAM_ERROR_IO = 2,       /* a file could not be opened, read or written */
  PSTREAM_ERROR_FORMAT = 3,   /* not an Alembic archive / .pstream, or corrupt (a checksum, a frame) */
  PSTREAM_ERROR_BUDGET = 4,   /* the memory budget or a limit (particles, frames) was exceeded */
  PSTREAM_ERROR_STATE = 5,    /* the handle cannot do that now (a clip in its error state) */
  PSTREAM_ERROR_INTERNAL = 6  /* anything else; the message says what */
} pstream_result;

/* The library's version, PSTREAM_VERSION as it was built (compare with the header's). */
PSTREAM_API uint32_t pstream_version(void);
/* The message of the last failure on this thread ("" when none); valid until the next call
 * that fails on this thread. */
PSTREAM_API const char* pstream_last_error(void);
/* "PSTREAM_OK", "PSTREAM_ERROR_IO", ... */
PSTREAM_API const char* pstream_result_name(pstream_result result);

/* ---- Memory -------------------------------------------------------------------------------- */

/* The host's allocator (malloc/free with a user pointer). `allocate` returns `size` bytes aligned
 * to `alignment` (a power of two, at least 16) or NULL; `free` releases a block it returned.
 * Both may be called from any thread, concurrently. */
typedef struct pstream_allocator {
  void* user;
  void* (*allocate)(void* user, size_t size, size_t alignment);
  void (*free)(void* user, void* block);
} pstream_allocator;

/* Every allocation the library makes from now on goes to `allocator` (NULL: back to malloc/free):
 * its containers, strings, threads' state, zstd's contexts. A handle allocates at open and
 * close, never in pstream_player_update(). Each block remembers its allocator, so it may be
 * changed at any time; memory taken before the change is returned to the allocator that gave it,
 * so keep that one usable until the handles opened with it are closed. After every handle is
 * closed the library holds nothing from the allocator, except the last error message of a thread
 * whose call failed (until that thread's next failure or its exit).
 * Not reached: what the C library allocates for itself (thread stacks and TLS). Builds with
 * sanitizers route only zstd's contexts here. At most 64 distinct allocators per process
 * (PSTREAM_ERROR_STATE past that); one of the functions NULL: PSTREAM_ERROR_ARGUMENT. */
PSTREAM_API pstream_result pstream_set_allocator(const pstream_allocator* allocator);

/* ---- Record layout --------------------------------------------------------------------- */

typedef enum pstream_attribute_type {
  PSTREAM_FLOAT32 = 0,
  PSTREAM_UNORM8 = 1,
  PSTREAM_UINT32 = 2,
  PSTREAM_UINT64 = 3
} pstream_attribute_type;

/* One attribute of a particle record: "position" (float32 x3 at 0) and "scale" (float32 at 12)
 * always come first; "color", "velocity", "id" and source attributes follow. */
typedef struct pstream_attribute {
  const char* name; /* valid while the handle is open */
  int32_t type;     /* a pstream_attribute_type */
  uint32_t components;
  uint32_t offset; /* bytes from the record's start */
} pstream_attribute;

/* ---- Alembic archives (our reader) ----------------------------------------------------- */

typedef struct pstream_archive pstream_archive;

/* `path`: a local .abc (mapped), or its http(s):// URL (read whole into memory at open). */
PSTREAM_API pstream_result pstream_archive_open(const char* path, pstream_archive** out);
/* Closes the handle (NULL: nothing to do, PSTREAM_OK). Closing it again, or one that no open
 * returned, is PSTREAM_ERROR_ARGUMENT
 * (never a crash); so is any other call with a closed handle. (The library tells only handles it
 * holds open: once closed, a handle's address may be reused by a later open.) */
PSTREAM_API pstream_result pstream_archive_close(pstream_archive* archive);
/* The archive's points objects (AbcGeom_Points_v1), in depth-first order. */
PSTREAM_API pstream_result pstream_archive_points_count(const pstream_archive* archive, size_t* count);
/* Object `index`'s full name ("/fx/sparks"; valid while the archive is open) and its samples. */
PSTREAM_API pstream_result pstream_archive_points_info(const pstream_archive* archive, size_t index,
                                                       const char** full_name, uint32_t* samples);
/* Particles in sample `sample` of object `index`, and the sample's time in seconds. */
PSTREAM_API pstream_result pstream_archive_points_sample(const pstream_archive* archive, size_t index, uint32_t sample,
                                                         uint64_t* count, double* time);
/* Copies the sample's positions (float32 x3 per particle, object space) into `out`, which holds
 * `capacity` floats (at least 3 x count). */
PSTREAM_API pstream_result pstream_archive_read_positions(const pstream_archive* archive, size_t index, uint32_t sample,
                                                          float* out, uint64_t capacity);

/* ---- Cooking (.abc or a PLY sequence -> .pstream) ------------------------------------ */

typedef enum pstream_codec {
  PSTREAM_CODEC_RAW = 0,      /* records in raw chunks */
  PSTREAM_CODEC_LZ4 = 1,      /* records in LZ4 chunks */
  PSTREAM_CODEC_ZSTD = 2,     /* records in zstd chunks */
  PSTREAM_CODEC_PARTICLE = 3, /* the particle codec, error-bounded (`error`, `scale_error`): the default */
  PSTREAM_CODEC_PARTICLE_LOSSLESS = 4
} pstream_codec;

/* Called after each cooked frame; return non-zero to cancel (the cook then fails with
 * PSTREAM_ERROR_STATE and writes nothing). */
typedef int (*pstream_progress_fn)(void* user, uint64_t frames_done, uint64_t frame_count);

typedef struct pstream_cook_options {
  size_t struct_size;     /* sizeof(pstream_cook_options) */
  const char* input;      /* .abc, or one file of a numbered PLY sequence */
  const char* output;     /* .pstream; written to a temporary and renamed when complete */
  const char* object;     /* the points object's full name; NULL: the only one */
  const char* attributes; /* comma-separated: "velocity,id,age"; NULL: none beyond position, scale, colour
                           * and a velocity (derived with ids, else the source's; store_velocity) */
  double fps;             /* output frame rate; 0: the source's */
  int32_t codec;          /* a pstream_codec (a fixed-size field: enums' sizes differ between compilers) */
  double error;           /* particle codec: the bound on positions, a fraction of the clip's bounds diagonal
                           * (default 1e-4), or scene units with error_in_scene_units; 0: the default */
  int interpolate;        /* resample between samples (by id, or along velocities) instead of the nearest */
  pstream_progress_fn progress;
  void* progress_user;
  /* Particle codec: the bound on each particle's scale relative to its own (default 0.01). Added
   * after progress_user: an older struct_size gets the default. */
  double scale_error;
  /* Particle codec: the bound on velocity and other float attributes, a fraction of each one's
   * own range (default 1e-3). Added with scale_error. */
  double attribute_error;
  /* Particle codec, particles with ids: non-zero stores the source's velocities (about 2.3 bytes
   * per particle) instead of deriving them from the matched positions (default 0). Added after
   * attribute_error: an older struct_size gets the default. */
  int store_velocity;
  /* Particle codec: non-zero reads `error` in scene units (the command line's --error abs:VALUE),
   * for a bound that does not change with the clip's extent (default 0: a fraction of the bounds
   * diagonal). Added after store_velocity: an older struct_size gets the default. */
  int error_in_scene_units;
} pstream_cook_options;

typedef struct pstream_cook_report {
  uint64_t frames, particles, file_bytes;
  double seconds;
} pstream_cook_report;

PSTREAM_API void pstream_cook_options_init(pstream_cook_options* options);
/* `report` may be NULL. */
PSTREAM_API pstream_result pstream_cook(const pstream_cook_options* options, pstream_cook_report* report);

/* ---- Cooking particles handed over frame by frame (a DCC's exporter) ------------------ */

/* A spool takes a simulation's frames one at a time, as an exporter evaluates them, and keeps them
 * on disk until pstream_spool_cook() cooks them (the same cook as pstream_cook's): memory stays a
 * frame's, whatever the simulation's length. The frames go to an unnamed temporary file, which
 * the system reclaims when the spool closes, even when the process is killed. */
typedef struct pstream_spool pstream_spool;

/* A float attribute handed over with a frame (an age, a temperature). */
typedef struct pstream_float_attribute {
  const char* name;    /* stored when pstream_cook_options.attributes names it */
  uint32_t components; /* 1 to 16 */
  const float* values; /* count x components */
} pstream_float_attribute;

/* One frame. An attribute is in every frame with particles or in none; a frame with no particles
 * has no arrays. The arrays are the caller's again once pstream_spool_add() returns. */
typedef struct pstream_spool_frame {
  size_t struct_size;                    /* sizeof(pstream_spool_frame) */
  double time;                           /* seconds; after the frame before's */
  uint64_t count;                        /* particles */
  const float* position;                 /* count x 3 (x y z); required when count > 0 */
  const float* width;                    /* count diameters (the record's scale is half), or NULL */
  const float* velocity;                 /* count x 3, scene units per second, or NULL */
  const uint64_t* id;                    /* count ids, stable across frames (matching and derived velocity), or NULL */
  const float* color;                    /* count x 4, linear RGBA in [0, 1], or NULL */
  const pstream_float_attribute* floats; /* float_count of them, or NULL */
  uint32_t float_count;
} pstream_spool_frame;

/* `folder`: where the temporary lives (room for every frame's arrays); NULL: $TMPDIR, else /tmp.
 * `name` names the frames in messages and the clip's source; NULL: "particles". */
PSTREAM_API pstream_result pstream_spool_open(const char* folder, const char* name, pstream_spool** out);
/* Checks the frame (sizes, times, the attributes of the frames before it with particles; a
 * refused frame leaves the spool as it was) and writes it: PSTREAM_ERROR_ARGUMENT names the frame
 * and what is wrong, PSTREAM_ERROR_IO a failed write (a full disk). */
PSTREAM_API pstream_result pstream_spool_add(pstream_spool* spool, const pstream_spool_frame* frame);
/* Cooks the frames added so far into options->output, as pstream_cook() cooks a file: options->input
 * and interpolate must be unset, options->fps is the frames' rate (0: 24), options->object the
 * clip's source object (NULL: "particles"). More frames may follow, and another cook. */
PSTREAM_API pstream_result pstream_spool_cook(pstream_spool* spool, const pstream_cook_options* options,
                                              pstream_cook_report* report);
/* Closes the spool and releases its temporary. NULL is ignored. */
PSTREAM_API pstream_result pstream_spool_close(pstream_spool* spool);

/* ---- Reading a .pstream directly ------------------------------------------------------ */

typedef struct pstream_clip pstream_clip;

typedef struct pstream_clip_info {
  uint64_t frame_count, max_count; /* frames; the most particles a frame has */
  uint32_t record_size;            /* bytes per particle */
  uint32_t attribute_count;
  double fps, start_time, end_time;
  float bounds[6]; /* min xyz, max xyz over every frame */
} pstream_clip_info;

PSTREAM_API pstream_result pstream_clip_open(const char* path, pstream_clip** out);
/* As pstream_archive_close(). */
PSTREAM_API pstream_result pstream_clip_close(pstream_clip* clip);
PSTREAM_API pstream_result pstream_clip_info_get(const pstream_clip* clip, pstream_clip_info* out);
PSTREAM_API pstream_result pstream_clip_attribute(const pstream_clip* clip, uint32_t index, pstream_attribute* out);
/* Frame `frame`'s particle count and time. */
PSTREAM_API pstream_result pstream_clip_frame_info(const pstream_clip* clip, uint64_t frame, uint64_t* count,
                                                   double* time);
/* Decodes frame `frame`'s records into `out` (`capacity` bytes, at least count x record_size).
   Read frames in order: each then continues from the one before, and a chunk is read and checked
   once while the frames come from it. The first read that goes back gives the clip's decoder 3
   saved states (fewer when the clip's stored bytes do not justify their memory): later reads
   back resume from the nearest one saved on the way rather than from the keyframe. */
PSTREAM_API pstream_result pstream_clip_read_frame(pstream_clip* clip, uint64_t frame, void* out, uint64_t capacity);

/* ---- Playback -------------------------------------------------------------------------- */

typedef struct pstream_player pstream_player;

typedef enum pstream_interpolation {
  PSTREAM_INTERPOLATION_NONE = 0,   /* the nearest cached frame */
  PSTREAM_INTERPOLATION_LINEAR = 1, /* matched particles along straight lines */
  PSTREAM_INTERPOLATION_HERMITE = 2 /* along cubic curves through their velocities (default) */
} pstream_interpolation;

/* Where the per-frame work runs (pstream_player_options.playback). */
typedef enum pstream_playback {
  /* The library interpolates and sorts on the host thread; pstream_player_frame() gives the
   * records and their order (the default). */
  PSTREAM_PLAYBACK_CPU = 0,
  /* The host's own shaders do it: pstream_player_update() only advances the clips (no
   * interpolation, no sort: its cost does not grow with the particle count), and
   * pstream_player_frame_pair() gives what they need; pstream_frame.records and .order are NULL.
   * The rules, as reference GLSL, are in docs/embedding.md. */
  PSTREAM_PLAYBACK_GPU = 1
} pstream_playback;

typedef enum pstream_sort {
  PSTREAM_SORT_NONE = 0, /* stored order (additive blending) */
  PSTREAM_SORT_BACK_TO_FRONT = 1,
  PSTREAM_SORT_FRONT_TO_BACK = 2
} pstream_sort;

/* Completes an asynchronous read: status 0 when `out` is filled, non-zero when the read failed. */
typedef void (*pstream_io_done)(void* token, int status);

/* Where a clip's bytes come from, instead of the file: an engine's own file system or pak.
 * Set `read`, `read_async`, or both.
 * - `read` runs on the library's IO thread (or a host job, with pstream_tasks) and must fill
 *   `size` bytes at `offset` (return 0), or return non-zero (the clip then goes to its error
 *   state with `name`, the offset and the status in the message).
 * - `read_async` starts the read and returns 0 at once (non-zero: refused, nothing will
 *   complete), then the host calls `done(token, status)` exactly once, from any thread, even
 *   before read_async returns. `out` stays valid until then. No library thread waits for it: the
 *   chunk's verification and decoding run as a new job after the completion. Chunk loads use
 *   read_async when it is set; the two small reads at open (header, tables) use `read`, or
 *   read_async and wait. pstream_player_close() waits for reads under way.
 * A clip has one read under way at most; several clips' reads may run at the same time. */
typedef struct pstream_io {
  void* user;
  int (*read)(void* user, uint64_t offset, void* out, uint64_t size);
  uint64_t size;    /* the clip's size in bytes */
  const char* name; /* for messages */
  int (*read_async)(void* user, uint64_t offset, void* out, uint64_t size, pstream_io_done done, void* token);
} pstream_io;

/* The host's job system, instead of the library's IO thread: every chunk load (read, verify,
 * decompress) and every frame-decoding turn becomes a job. `submit` is called with a clip's lock
 * held: it must queue `run(job)` for a worker and return, never run it inline. Every submitted
 * job must run; pstream_player_close() waits for them. */
typedef struct pstream_tasks {
  void* user;
  void (*submit)(void* user, void (*run)(void* job), void* job);
} pstream_tasks;

typedef struct pstream_player_options {
  size_t struct_size;     /* sizeof(pstream_player_options) */
  double cache_seconds;   /* stored bytes held ahead per clip (default 1) */
  uint64_t memory_budget; /* bytes all clips' caches must fit in together; 0: no limit */
  int32_t interpolation;  /* a pstream_interpolation */
  int32_t sort;           /* a pstream_sort */
  int blocking;           /* non-zero: update() waits for data (offline rendering) instead of skipping */
  int loop;               /* default 1 */
  /* Optional, one per clip (NULL: read the files named in pstream_player_open). */
  const pstream_io* io;
  /* Optional: run the IO and decoding on the host's jobs (NULL: the library's IO thread). */
  const pstream_tasks* tasks;
  /* A read_async completion that has not come after this many seconds puts its clip in the
   * error state, and pstream_player_close() stops waiting for it (the read's buffer then stays
   * allocated, so a late completion is ignored and writes into nothing freed). A completion
   * called twice does the same at once. 0: 30 s. (Added in 0.1.1: an older struct_size is
   * accepted, with the default.) */
  double io_timeout_seconds;
  /* A pstream_playback (added after io_timeout_seconds: an older struct_size gets
   * PSTREAM_PLAYBACK_CPU). */
  int32_t playback;
  /* Decoder states each particle clip keeps for going back (reverse play, seeks back), so that a
   * frame decodes from the nearest rather than from its keyframe: about 8 bytes per particle and
   * coded word each, plus 1.3 MiB. Default 3; 0: none. Under memory_budget a clip keeps only those
   * that fit. (Added after playback: an older struct_size gets the default.) */
  int32_t saved_states;
} pstream_player_options;

/* A clip's frame as update() prepared it, valid until the next update() or close(). */
typedef struct pstream_frame {
  const void* records; /* count x record_size bytes */
  uint64_t count;
  uint32_t record_size;
  int32_t color_offset;    /* RGBA8 in the record, or -1 */
  int32_t velocity_offset; /* float32 x3 (units per second), or -1 */
  const uint32_t* order;   /* draw order (indices into records), or NULL: stored order */
  uint64_t frame;          /* the cached frame at or before the playhead */
  double time;             /* the playhead, clip seconds */
  double fraction;         /* how far towards the next cached frame (interpolated when > 0) */
} pstream_frame;

/* How a word (4 bytes) of a record is made between two cached frames (pstream_frame_pair.lanes). */
typedef enum pstream_lane {
  PSTREAM_LANE_COPY = 0,     /* from the earlier frame's record (ids, integers, the colour word: see below) */
  PSTREAM_LANE_LERP = 1,     /* a float blended linearly (scale, other float attributes) */
  PSTREAM_LANE_POSITION = 2, /* along the Hermite curve through positions and velocities */
  PSTREAM_LANE_VELOCITY = 3  /* the curve's derivative */
} pstream_lane;

/* PSTREAM_PLAYBACK_GPU: what a host's shaders need to make clip `clip`'s frame between two cached
 * frames. Upload `a` and `b` when their frame numbers first appear (the same frame number always
 * has the same bytes), the pair table when `pairs_version` changes, and nothing else between
 * cached frames. Valid until the next update() or close(). */
#define PSTREAM_NO_PARTICLE 0xFFFFFFFFu
typedef struct pstream_frame_pair {
  const void* a;    /* the earlier cached frame's records (a_count x record_size bytes) */
  uint64_t a_frame; /* its frame number */
  uint64_t a_count;
  /* Between cached frames (pair_count > 0): the later frame, and per particle of the frame to
   * draw its index in a and in b (PSTREAM_NO_PARTICLE: born in b, or dying after a). With
   * pair_count 0 the frame is `a` as it is (b is NULL). */
  const void* b;
  uint64_t b_frame;
  uint64_t b_count;
  const uint32_t* pairs; /* pair_count x 2 (a, b) */
  uint64_t pair_count;
  uint64_t pairs_version; /* changes whenever the table does */
  double t;               /* 0..1 from a to b */
  double dt;              /* seconds from a to b */
  int hermite;            /* along the curves where the velocities describe the matching, else straight lines */
  int nearer;             /* no matching: the table is the nearer frame alone, moved along its velocities */
  uint32_t record_size;
  uint32_t lane_count;     /* record_size / 4 */
  const uint8_t* lanes;    /* a pstream_lane per word */
  int32_t velocity_offset; /* float32 x3, or -1 */
  int32_t color_offset;    /* RGBA8, blended per byte, or -1 */
} pstream_frame_pair;

typedef struct pstream_player_stats {
  double stream_ms, interpolate_ms, sort_ms; /* the last update() */
  uint64_t particles;
  uint64_t stalls;       /* frames a clip could not show in time, since open (all clips) */
  uint64_t cache_bytes;  /* memory held by all clips (chunk caches, decoded frames, decoder state) */
  uint32_t failed_clips; /* clips in their error state (pstream_player_check() returns the error) */
} pstream_player_stats;

PSTREAM_API void pstream_player_options_init(pstream_player_options* options);
/* Opens `count` clips. With options->io, `paths` may be NULL. `options` may be NULL (defaults). */
PSTREAM_API pstream_result pstream_player_open(const char* const* paths, size_t count,
                                               const pstream_player_options* options, pstream_player** out);
/* As pstream_archive_close(). */
PSTREAM_API pstream_result pstream_player_close(pstream_player* player);

PSTREAM_API pstream_result pstream_player_play(pstream_player* player);
PSTREAM_API pstream_result pstream_player_pause(pstream_player* player);
PSTREAM_API pstream_result pstream_player_seek(pstream_player* player, double time);
/* 0 holds, 0.25 slow motion, negative plays backwards. */
PSTREAM_API pstream_result pstream_player_set_speed(pstream_player* player, double speed);
PSTREAM_API pstream_result pstream_player_set_loop(pstream_player* player, int loop);
PSTREAM_API pstream_result pstream_player_set_range(pstream_player* player, double start, double end);
/* A clip's object -> world transform (column-major 4x4). */
PSTREAM_API pstream_result pstream_player_set_transform(pstream_player* player, size_t clip, const float world[16]);

/* One host frame: advances every clip by `dt` seconds, interpolates, and sorts for `view`
 * (world -> view, column-major; NULL: identity) as the options' `sort` says. Allocates nothing. */
PSTREAM_API pstream_result pstream_player_update(pstream_player* player, double dt, const float view[16]);
/* PSTREAM_OK, or the error of the first clip that failed (its file, chunk and cause). */
PSTREAM_API pstream_result pstream_player_check(const pstream_player* player);

PSTREAM_API size_t pstream_player_clip_count(const pstream_player* player);
/* Clip `clip`'s current frame (count 0 when it has none yet). */
PSTREAM_API pstream_result pstream_player_frame(const pstream_player* player, size_t clip, pstream_frame* out);
/* PSTREAM_PLAYBACK_GPU: clip `clip`'s pair of cached frames (all zero when it has no frame yet).
 * PSTREAM_ERROR_ARGUMENT on a player opened with PSTREAM_PLAYBACK_CPU. */
PSTREAM_API pstream_result pstream_player_frame_pair(const pstream_player* player, size_t clip,
                                                     pstream_frame_pair* out);
/* With several clips sorted together (they blend in depth order where they overlap), the order
 * across them: entries are (batch << 28) | index, batch counting the clips that have particles
 * this frame in clip order; each clip's pstream_frame.order is then NULL. Empty (count 0)
 * otherwise. Valid until the next update(). */
PSTREAM_API pstream_result pstream_player_merged_order(const pstream_player* player, const uint32_t** order,
                                                       uint64_t* count);
PSTREAM_API pstream_result pstream_player_clip_info(const pstream_player* player, size_t clip, pstream_clip_info* out);
PSTREAM_API pstream_result pstream_player_attribute(const pstream_player* player, size_t clip, uint32_t index,
                                                    pstream_attribute* out);
PSTREAM_API pstream_result pstream_player_stats_get(const pstream_player* player, pstream_player_stats* out);

#ifdef __cplusplus
}
#endif

#endif /* PARTICLESTREAM_H */
