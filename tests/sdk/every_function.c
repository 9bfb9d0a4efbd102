/* Every function of the C API (include/particlestream/particlestream.h), from C99 compiled with
 * -Wall -Wextra -Werror -pedantic: results and messages of each error path, a cook with progress
 * and cancellation, reading a clip, playing it (also through IO callbacks, with failures), and
 * what a corrupt chunk and a small memory budget give.
 *
 *   every_function DATA_DIR WORK_DIR     (DATA_DIR: tests/data; WORK_DIR: an empty folder)
 */
#define _POSIX_C_SOURCE 200809L /* pthreads under -std=c99 */
#include <math.h>
#include <pthread.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <particlestream/particlestream.h>

#include "check.h"

static char path_buffer[8][1024];
static const char* join(int slot, const char* dir, const char* name) {
  snprintf(path_buffer[slot], sizeof path_buffer[slot], "%s/%s", dir, name);
  return path_buffer[slot];
}

static int progress_calls = 0;
static int count_progress(void* user, uint64_t done, uint64_t total) {
  (void)user;
  ++progress_calls;
  return done > total; /* never */
}
static int cancel_at_two(void* user, uint64_t done, uint64_t total) {
  (void)user;
  (void)total;
  return done >= 2;
}

/* A clip held in memory, read through pstream_io; `fail_after` reads succeed, then every read fails. */
typedef struct memory_file {
  unsigned char* bytes;
  uint64_t size;
  int reads, fail_after;
} memory_file;

static int read_memory(void* user, uint64_t offset, void* out, uint64_t size) {
  memory_file* f = (memory_file*)user;
  if (f->fail_after >= 0 && f->reads >= f->fail_after) return -1;
  ++f->reads;
  memcpy(out, f->bytes + offset, (size_t)size);
  return 0;
}

/* An engine's asynchronous IO: read_async queues the request and returns; a thread of the host
 * serves it after a millisecond and calls the completion. Reads at offsets in [fail_from,
 * fail_to] complete with status 5 (fail_from -1: none fail). */
typedef struct async_io {
  pthread_mutex_t mutex;
  pthread_cond_t wake;
  memory_file* file;
  uint64_t offset[64], size[64];
  void* out[64];
  pstream_io_done done[64];
  void* token[64];
  int head, count, stop, served, overflow;
  int64_t fail_from, fail_to;
  pthread_t thread;
} async_io;

static int read_async(void* user, uint64_t offset, void* out, uint64_t size, pstream_io_done done, void* token) {
  async_io* io = (async_io*)user;
  int at;
  pthread_mutex_lock(&io->mutex);
  if (io->count == 64) {
    io->overflow = 1;
    pthread_mutex_unlock(&io->mutex);
    return -1;
  }
  at = (io->head + io->count) % 64;
  io->offset[at] = offset;
  io->size[at] = size;
  io->out[at] = out;
  io->done[at] = done;
  io->token[at] = token;
  ++io->count;
  pthread_cond_signal(&io->wake);
  pthread_mutex_unlock(&io->mutex);
  return 0;
}

static void* async_io_main(void* user) {
  async_io* io = (async_io*)user;
  for (;;) {
    int at, status;
    struct timespec pause = {0, 1000000};
    pthread_mutex_lock(&io->mutex);
    while (!io->stop && io->count == 0) pthread_cond_wait(&io->wake, &io->mutex);
    if (io->count == 0) {
      pthread_mutex_unlock(&io->mutex);
      return NULL;
    }
    at = io->head;
    io->head = (io->head + 1) % 64;
    --io->count;
    ++io->served;
    pthread_mutex_unlock(&io->mutex);
    nanosleep(&pause, NULL); /* the engine's latency */
    status = io->fail_from >= 0 && io->offset[at] >= (uint64_t)io->fail_from && io->offset[at] <= (uint64_t)io->fail_to
                 ? 5
                 : 0;
    if (status == 0) memcpy(io->out[at], io->file->bytes + io->offset[at], (size_t)io->size[at]);
    io->done[at](io->token[at], status);
  }
}

/* A host job system: one worker thread and a queue, as an engine would give the library. */
typedef struct job_queue {
  pthread_mutex_t mutex;
  pthread_cond_t wake;
  void (*run[256])(void*);
  void* job[256];
  int head, count, stop, ran, overflow;
  pthread_t worker;
} job_queue;

static void submit_job(void* user, void (*run)(void* job), void* job) {
  job_queue* q = (job_queue*)user;
  pthread_mutex_lock(&q->mutex);
  if (q->count == 256) {
    q->overflow = 1;
  } else {
    q->run[(q->head + q->count) % 256] = run;
    q->job[(q->head + q->count) % 256] = job;
    ++q->count;
  }
  pthread_cond_signal(&q->wake);
  pthread_mutex_unlock(&q->mutex);
}

static void* worker_main(void* user) {
  job_queue* q = (job_queue*)user;
  for (;;) {
    void (*run)(void*);
    void* job;
    pthread_mutex_lock(&q->mutex);
    while (!q->stop && q->count == 0) pthread_cond_wait(&q->wake, &q->mutex);
    if (q->count == 0) {
      pthread_mutex_unlock(&q->mutex);
      return NULL;
    }
    run = q->run[q->head];
    job = q->job[q->head];
    q->head = (q->head + 1) % 256;
    --q->count;
    ++q->ran;
    pthread_mutex_unlock(&q->mutex);
    run(job);
  }
}

static unsigned char* load(const char* path, uint64_t* size) {
  FILE* f = fopen(path, "rb");
  unsigned char* bytes;
  long n;
  if (!f) return NULL;
  fseek(f, 0, SEEK_END);
  n = ftell(f);
  fseek(f, 0, SEEK_SET);
  bytes = (unsigned char*)malloc((size_t)n);
  if (bytes && fread(bytes, 1, (size_t)n, f) != (size_t)n) {
    free(bytes);
    bytes = NULL;
  }
  fclose(f);
  *size = (uint64_t)n;
  return bytes;
}

static int save(const char* path, const unsigned char* bytes, uint64_t size) {
  FILE* f = fopen(path, "wb");
  int ok;
  if (!f) return 0;
  ok = fwrite(bytes, 1, (size_t)size, f) == (size_t)size;
  return fclose(f) == 0 && ok;
}

/* Plays `player`'s clip 0 for `frames` host frames at 96 Hz; returns the particles seen. */
static uint64_t play(pstream_player* player, int frames) {
  static const float view[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, -5, 1};
  uint64_t seen = 0;
  int k;
  for (k = 0; k < frames; ++k) {
    pstream_frame frame;
    CHECK(pstream_player_update(player, k == 0 ? 0.0 : 1.0 / 96, view) == PSTREAM_OK);
    CHECK(pstream_player_frame(player, 0, &frame) == PSTREAM_OK);
    seen += frame.count;
  }
  return seen;
}

int main(int argc, char** argv) {
  const char *data, *work;
  if (argc != 3) {
    fprintf(stderr, "usage: %s DATA_DIR WORK_DIR\n", argv[0]);
    return 2;
  }
  data = argv[1];
  work = argv[2];

  /* ---- Version and names ---- */
  CHECK(pstream_version() == PSTREAM_VERSION);
  CHECK(strcmp(pstream_result_name(PSTREAM_OK), "PSTREAM_OK") == 0);
  CHECK(strcmp(pstream_result_name(PSTREAM_ERROR_BUDGET), "PSTREAM_ERROR_BUDGET") == 0);

  /* ---- Archives ---- */
  {
    pstream_archive* archive = NULL;
    size_t objects = 0;
    const char* name = NULL;
    uint32_t samples = 0;
    uint64_t count = 0;
    double time = -1, sum = 0;
    float* positions;
    uint64_t i;
    CHECK(pstream_archive_open(join(0, data, "alembic/points_varying.abc"), &archive) == PSTREAM_OK);
    CHECK(pstream_archive_points_count(archive, &objects) == PSTREAM_OK && objects == 1);
    CHECK(pstream_archive_points_info(archive, 0, &name, &samples) == PSTREAM_OK);
    CHECK(name && strcmp(name, "/particles") == 0);
    CHECK(samples == 60);
    CHECK(pstream_archive_points_sample(archive, 0, 5, &count, &time) == PSTREAM_OK && count > 0 && time > 0);
    positions = (float*)malloc((size_t)count * 3 * sizeof(float));
    CHECK(pstream_archive_read_positions(archive, 0, 5, positions, count * 3) == PSTREAM_OK);
    for (i = 0; i < count * 3; ++i) sum += positions[i];
    CHECK(sum != 0);
    EXPECT_ERROR(pstream_archive_read_positions(archive, 0, 5, positions, 2), PSTREAM_ERROR_ARGUMENT, "buffer holds 2");
    EXPECT_ERROR(pstream_archive_points_info(archive, 1, &name, &samples), PSTREAM_ERROR_ARGUMENT, "points object 1");
    EXPECT_ERROR(pstream_archive_points_sample(archive, 0, 60, &count, &time), PSTREAM_ERROR_ARGUMENT, "sample 60");
    free(positions);
    pstream_archive_close(archive);
    EXPECT_ERROR(pstream_archive_open(join(0, data, "no/such.abc"), &archive), PSTREAM_ERROR_IO, "no/such.abc");
    CHECK(archive == NULL);
    EXPECT_ERROR(pstream_archive_open(join(0, data, "alembic/points_varying.expected.json"), &archive),
                 PSTREAM_ERROR_FORMAT, "points_varying.expected.json");
    EXPECT_ERROR(pstream_archive_open(NULL, &archive), PSTREAM_ERROR_ARGUMENT, "NULL");
    EXPECT_ERROR(pstream_archive_points_count(NULL, &objects), PSTREAM_ERROR_ARGUMENT, "NULL");
    CHECK(pstream_archive_close(NULL) == PSTREAM_OK); /* harmless */
    CHECK(pstream_archive_open(join(0, data, "alembic/points_varying.abc"), &archive) == PSTREAM_OK);
    CHECK(pstream_archive_close(archive) == PSTREAM_OK);
    EXPECT_ERROR(pstream_archive_close(archive), PSTREAM_ERROR_ARGUMENT, "is not open");
    EXPECT_ERROR(pstream_archive_points_count(archive, &objects), PSTREAM_ERROR_ARGUMENT, "is not open");
  }

  /* ---- Cooking ---- */
  {
    pstream_cook_options o;
    pstream_cook_report report;
    FILE* exists;
    pstream_cook_options_init(&o);
    CHECK(o.struct_size == sizeof o && o.codec == PSTREAM_CODEC_PARTICLE && o.scale_error == 0.01);
    o.input = join(0, data, "alembic/points_varying.abc");
    o.output = join(1, work, "particle.pstream");
    o.attributes = "velocity,id";
    o.codec = PSTREAM_CODEC_PARTICLE;
    o.progress = count_progress;
    CHECK(pstream_cook(&o, &report) == PSTREAM_OK);
    CHECK(report.frames == 60 && report.particles > 0 && report.file_bytes > 0);
    CHECK(progress_calls >= 60);
    o.output = join(2, work, "raw.pstream");
    o.codec = PSTREAM_CODEC_RAW;
    o.progress = NULL;
    {
      /* The records as they are: larger than the particle codec's (until 2026-11-29 the C API's
       * raw, lz4 and zstd cooked with the particle codec, the library's default). */
      pstream_cook_report raw;
      CHECK(pstream_cook(&o, &raw) == PSTREAM_OK);
      CHECK(raw.file_bytes > 3 * report.file_bytes);
    }
    o.output = join(3, work, "cancelled.pstream");
    o.progress = cancel_at_two;
    EXPECT_ERROR(pstream_cook(&o, NULL), PSTREAM_ERROR_STATE, "cancelled");
    exists = fopen(join(3, work, "cancelled.pstream"), "rb");
    CHECK(exists == NULL); /* nothing written */
    /* The scale's relative bound, by the command line's rules; a caller built before it existed
     * (a struct_size that ends before scale_error) gets the default. */
    o.progress = NULL;
    o.codec = PSTREAM_CODEC_PARTICLE;
    o.output = join(3, work, "scale.pstream");
    o.scale_error = 0.7;
    EXPECT_ERROR(pstream_cook(&o, NULL), PSTREAM_ERROR_ARGUMENT, "scale_error '0.7'");
    o.scale_error = 0.001;
    CHECK(pstream_cook(&o, NULL) == PSTREAM_OK);
    o.struct_size = offsetof(pstream_cook_options, scale_error);
    o.scale_error = 0.7; /* not read */
    CHECK(pstream_cook(&o, NULL) == PSTREAM_OK);
    o.struct_size = sizeof o;
    o.scale_error = 0.01;
    /* The position bound in scene units (--error abs:VALUE): a coarser one than the default's
     * makes a smaller clip, and a bound the command line refuses is refused here too. */
    {
      pstream_cook_report fine, coarse;
      o.output = join(3, work, "fine.pstream");
      CHECK(pstream_cook(&o, &fine) == PSTREAM_OK);
      o.output = join(3, work, "coarse.pstream");
      o.error = 0.05;
      o.error_in_scene_units = 1;
      CHECK(pstream_cook(&o, &coarse) == PSTREAM_OK);
      CHECK(coarse.file_bytes < fine.file_bytes);
      o.error = -1;
      EXPECT_ERROR(pstream_cook(&o, NULL), PSTREAM_ERROR_ARGUMENT, "error 'abs:-1'");
      o.error_in_scene_units = 0;
      o.error = 2; /* a fraction of the diagonal: below 1 */
      EXPECT_ERROR(pstream_cook(&o, NULL), PSTREAM_ERROR_ARGUMENT, "error 'rel:2'");
      o.error = 1e-4;
      /* A caller built before error_in_scene_units reads `error` as a fraction. */
      o.struct_size = offsetof(pstream_cook_options, error_in_scene_units);
      o.error_in_scene_units = 1; /* not read */
      o.error = 0.5;
      CHECK(pstream_cook(&o, NULL) == PSTREAM_OK);
      o.struct_size = sizeof o;
      o.error_in_scene_units = 0;
      o.error = 1e-4;
    }
    if (exists) fclose(exists);
    o.progress = NULL;
    o.codec = 99;
    EXPECT_ERROR(pstream_cook(&o, NULL), PSTREAM_ERROR_ARGUMENT, "unknown codec 99");
    o.codec = PSTREAM_CODEC_RAW;
    o.object = "/nothing/here";
    EXPECT_ERROR(pstream_cook(&o, NULL), PSTREAM_ERROR_FORMAT, "/nothing/here");
    o.object = NULL;
    o.input = join(0, data, "no/such.abc");
    EXPECT_ERROR(pstream_cook(&o, NULL), PSTREAM_ERROR_IO, "no/such.abc");
    EXPECT_ERROR(pstream_cook(NULL, NULL), PSTREAM_ERROR_ARGUMENT, "NULL");
  }

  /* ---- Cooking frames handed over one at a time (a spool) ---- */
  {
    enum { kFrames = 6, kCount = 40 };
    static float position[kCount * 3], width[kCount], age[kCount];
    static uint64_t id[kCount];
    static unsigned char records[kCount * 64];
    pstream_spool* spool = NULL;
    pstream_spool_frame f;
    pstream_float_attribute age_attribute;
    pstream_cook_options o;
    pstream_cook_report report;
    pstream_clip* clip = NULL;
    pstream_clip_info info;
    pstream_attribute a;
    uint64_t count = 0;
    double time = 0;
    uint32_t k;
    int frame, i, equal = 1;
    CHECK(pstream_spool_open(work, "c spool", &spool) == PSTREAM_OK);
    memset(&f, 0, sizeof f);
    f.struct_size = sizeof f;
    f.count = kCount;
    f.position = position;
    f.width = width;
    f.id = id;
    age_attribute.name = "age";
    age_attribute.components = 1;
    age_attribute.values = age;
    f.floats = &age_attribute;
    f.float_count = 1;
    for (frame = 0; frame < kFrames; ++frame) {
      for (i = 0; i < kCount; ++i) {
        position[i * 3] = (float)i * 0.1f;
        position[i * 3 + 1] = (float)frame * 0.05f;
        position[i * 3 + 2] = (float)(i % 3);
        width[i] = 0.02f;
        age[i] = (float)frame / 24.0f;
        id[i] = (uint64_t)i;
      }
      f.time = (frame + 1) / 24.0;
      CHECK(pstream_spool_add(spool, &f) == PSTREAM_OK);
    }
    /* Refused, by name, and the spool goes on: a time that goes back, an attribute missing. */
    EXPECT_ERROR(pstream_spool_add(spool, &f), PSTREAM_ERROR_ARGUMENT, "c spool: frame 6 is at time");
    f.time = 1.0;
    f.float_count = 0;
    EXPECT_ERROR(pstream_spool_add(spool, &f), PSTREAM_ERROR_ARGUMENT, "c spool: frame 6 has no 'age' array");
    f.float_count = 1;
    age_attribute.components = 40;
    EXPECT_ERROR(pstream_spool_add(spool, &f), PSTREAM_ERROR_ARGUMENT, "'age' has 40 components; 1 to 16");
    age_attribute.components = 1;
    pstream_cook_options_init(&o);
    o.output = join(3, work, "spool.pstream");
    o.codec = PSTREAM_CODEC_RAW;
    o.attributes = "id,age";
    o.fps = 24;
    o.input = "x.abc";
    EXPECT_ERROR(pstream_spool_cook(spool, &o, NULL), PSTREAM_ERROR_ARGUMENT, "options->input must be NULL");
    o.input = NULL;
    o.progress = cancel_at_two;
    EXPECT_ERROR(pstream_spool_cook(spool, &o, NULL), PSTREAM_ERROR_STATE, "c spool: the cook was cancelled");
    o.progress = NULL;
    CHECK(pstream_spool_cook(spool, &o, &report) == PSTREAM_OK);
    CHECK(report.frames == kFrames && report.particles == kFrames * kCount);
    /* The last frame's records are what was handed over (the raw codec). */
    CHECK(pstream_clip_open(join(3, work, "spool.pstream"), &clip) == PSTREAM_OK);
    CHECK(pstream_clip_info_get(clip, &info) == PSTREAM_OK);
    CHECK(info.frame_count == kFrames && info.record_size * kCount <= sizeof records);
    CHECK(pstream_clip_frame_info(clip, kFrames - 1, &count, &time) == PSTREAM_OK && count == kCount);
    CHECK(pstream_clip_read_frame(clip, kFrames - 1, records, sizeof records) == PSTREAM_OK);
    for (k = 0; k < info.attribute_count; ++k) {
      CHECK(pstream_clip_attribute(clip, k, &a) == PSTREAM_OK);
      for (i = 0; i < kCount && strcmp(a.name, "age") == 0; ++i) {
        float v;
        memcpy(&v, records + (size_t)i * info.record_size + a.offset, 4);
        equal = equal && v == age[i];
      }
      for (i = 0; i < kCount && strcmp(a.name, "position") == 0; ++i)
        equal = equal && memcmp(records + (size_t)i * info.record_size + a.offset, position + i * 3, 12) == 0;
    }
    CHECK(equal);
    CHECK(pstream_clip_close(clip) == PSTREAM_OK);
    CHECK(pstream_spool_close(spool) == PSTREAM_OK);
    EXPECT_ERROR(pstream_spool_add(spool, &f), PSTREAM_ERROR_ARGUMENT, "is not open");
    CHECK(pstream_spool_close(NULL) == PSTREAM_OK);
    EXPECT_ERROR(pstream_spool_open(join(4, work, "no/such/folder"), NULL, &spool), PSTREAM_ERROR_IO,
                 "cannot make the frame spool's temporary file there");
    CHECK(spool == NULL);
  }

  /* ---- Reading a clip ---- */
  {
    pstream_clip* clip = NULL;
    pstream_clip_info info;
    pstream_attribute a;
    uint32_t i;
    uint64_t count = 0;
    double time = 0;
    void* records;
    CHECK(pstream_clip_open(join(1, work, "particle.pstream"), &clip) == PSTREAM_OK);
    CHECK(pstream_clip_info_get(clip, &info) == PSTREAM_OK);
    /* position, scale, color (from Cd), velocity, id */
    CHECK(info.frame_count == 60 && info.record_size == 16 + 4 + 12 + 8 && info.attribute_count == 5);
    for (i = 0; i < info.attribute_count; ++i) CHECK(pstream_clip_attribute(clip, i, &a) == PSTREAM_OK);
    CHECK(strcmp(a.name, "id") == 0 && a.type == PSTREAM_UINT64 && a.components == 1 && a.offset == 32);
    CHECK(pstream_clip_attribute(clip, 0, &a) == PSTREAM_OK && strcmp(a.name, "position") == 0 && a.offset == 0);
    EXPECT_ERROR(pstream_clip_attribute(clip, 9, &a), PSTREAM_ERROR_ARGUMENT, "attribute 9");
    CHECK(pstream_clip_frame_info(clip, 5, &count, &time) == PSTREAM_OK && count > 0);
    records = malloc((size_t)(info.max_count * info.record_size));
    CHECK(pstream_clip_read_frame(clip, 59, records, info.max_count * info.record_size) == PSTREAM_OK);
    EXPECT_ERROR(pstream_clip_read_frame(clip, 5, records, 3), PSTREAM_ERROR_ARGUMENT, "the buffer has 3");
    EXPECT_ERROR(pstream_clip_frame_info(clip, 60, &count, &time), PSTREAM_ERROR_ARGUMENT, "frame 60 of 60");
    free(records);
    CHECK(pstream_clip_close(clip) == PSTREAM_OK);
    EXPECT_ERROR(pstream_clip_close(clip), PSTREAM_ERROR_ARGUMENT, "is not open");
    EXPECT_ERROR(pstream_clip_info_get(clip, &info), PSTREAM_ERROR_ARGUMENT, "is not open");
    EXPECT_ERROR(pstream_clip_open(join(0, data, "alembic/points_varying.abc"), &clip), PSTREAM_ERROR_FORMAT,
                 "points_varying.abc");
  }

  /* ---- The same clip by URL, when a test server runs (tests/http/with_server.sh) ---- */
  if (getenv("PSTREAM_TEST_URL_BASE") != NULL) {
    pstream_clip *local = NULL, *remote = NULL;
    pstream_clip_info a, b;
    pstream_player* player = NULL;
    pstream_player_options options;
    const char* clips[1];
    char url[1200], missing[1200];
    void *x, *y;
    uint64_t f, seen_file, seen_url;
    snprintf(url, sizeof url, "%s%s/particle.pstream", getenv("PSTREAM_TEST_URL_BASE"), work);
    snprintf(missing, sizeof missing, "%s%s/missing.pstream", getenv("PSTREAM_TEST_URL_BASE"), work);
    CHECK(pstream_clip_open(join(1, work, "particle.pstream"), &local) == PSTREAM_OK);
    CHECK(pstream_clip_open(url, &remote) == PSTREAM_OK);
    CHECK(pstream_clip_info_get(local, &a) == PSTREAM_OK && pstream_clip_info_get(remote, &b) == PSTREAM_OK);
    CHECK(a.frame_count == b.frame_count && a.record_size == b.record_size && a.max_count == b.max_count);
    x = malloc((size_t)(a.max_count * a.record_size));
    y = malloc((size_t)(a.max_count * a.record_size));
    for (f = 0; f < a.frame_count; ++f) { /* every frame, byte for byte */
      uint64_t count = 0;
      double time = 0;
      CHECK(pstream_clip_read_frame(local, f, x, a.max_count * a.record_size) == PSTREAM_OK);
      CHECK(pstream_clip_read_frame(remote, f, y, a.max_count * a.record_size) == PSTREAM_OK);
      CHECK(pstream_clip_frame_info(local, f, &count, &time) == PSTREAM_OK);
      CHECK(memcmp(x, y, (size_t)(count * a.record_size)) == 0);
    }
    free(x);
    free(y);
    CHECK(pstream_clip_close(local) == PSTREAM_OK && pstream_clip_close(remote) == PSTREAM_OK);
    EXPECT_ERROR(pstream_clip_open(missing, &remote), PSTREAM_ERROR_IO, "missing.pstream");
    /* A player streams it too: the same particles, frame after frame, as from the file. */
    pstream_player_options_init(&options);
    options.blocking = 1;
    clips[0] = join(1, work, "particle.pstream");
    CHECK(pstream_player_open(clips, 1, &options, &player) == PSTREAM_OK);
    CHECK(pstream_player_play(player) == PSTREAM_OK);
    seen_file = play(player, 60);
    pstream_player_close(player);
    clips[0] = url;
    CHECK(pstream_player_open(clips, 1, &options, &player) == PSTREAM_OK);
    CHECK(pstream_player_play(player) == PSTREAM_OK);
    seen_url = play(player, 60);
    CHECK(seen_url > 0 && seen_url == seen_file);
    pstream_player_close(player);
    clips[0] = missing;
    EXPECT_ERROR(pstream_player_open(clips, 1, &options, &player), PSTREAM_ERROR_IO, "404");
    printf("by URL: %s, every frame equal to the file's\n", url);
  }

  /* ---- Playback ---- */
  {
    pstream_player* player = NULL;
    pstream_player_options options;
    pstream_player_stats stats;
    pstream_clip_info info;
    pstream_attribute a;
    pstream_frame frame;
    const uint32_t* order = NULL;
    uint64_t merged = 0;
    const char* clips[2];
    static const float world[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0.5f, 0, 0, 1};
    int k, between = 0, drawn = 0;
    clips[0] = join(1, work, "particle.pstream");
    clips[1] = join(2, work, "raw.pstream");
    pstream_player_options_init(&options);
    CHECK(options.struct_size == sizeof options && options.loop == 1 && options.saved_states == 3);
    options.blocking = 1;
    CHECK(pstream_player_open(clips, 1, &options, &player) == PSTREAM_OK);
    CHECK(pstream_player_clip_count(player) == 1);
    CHECK(pstream_player_clip_info(player, 0, &info) == PSTREAM_OK && info.frame_count == 60);
    CHECK(pstream_player_attribute(player, 0, 3, &a) == PSTREAM_OK && strcmp(a.name, "velocity") == 0);
    CHECK(pstream_player_set_transform(player, 0, world) == PSTREAM_OK);
    CHECK(pstream_player_set_range(player, info.start_time, info.end_time) == PSTREAM_OK);
    CHECK(pstream_player_set_loop(player, 0) == PSTREAM_OK);
    CHECK(pstream_player_set_speed(player, 0.5) == PSTREAM_OK);
    CHECK(pstream_player_seek(player, info.start_time) == PSTREAM_OK);
    CHECK(pstream_player_play(player) == PSTREAM_OK);
    for (k = 0; k < 40; ++k) {
      CHECK(pstream_player_update(player, k == 0 ? 0.0 : 1.0 / 96, NULL) == PSTREAM_OK);
      CHECK(pstream_player_frame(player, 0, &frame) == PSTREAM_OK);
      CHECK(frame.record_size == info.record_size);
      if (frame.count > 0) { /* the clip's first frames are empty */
        CHECK(frame.records != NULL && frame.order != NULL);
        CHECK(frame.velocity_offset == 20 && frame.color_offset == 16);
        ++drawn;
      }
      between += frame.fraction > 0;
    }
    CHECK(between > 20); /* 96 Hz at half speed on a 24 fps clip: mostly between frames */
    CHECK(drawn > 30);
    CHECK(pstream_player_merged_order(player, &order, &merged) == PSTREAM_OK && merged == 0 && order == NULL);
    CHECK(pstream_player_stats_get(player, &stats) == PSTREAM_OK);
    CHECK(stats.particles > 0 && stats.cache_bytes > 0 && stats.failed_clips == 0);
    CHECK(pstream_player_check(player) == PSTREAM_OK);
    CHECK(pstream_player_pause(player) == PSTREAM_OK);
    EXPECT_ERROR(pstream_player_frame(player, 3, &frame), PSTREAM_ERROR_ARGUMENT, "no clip 3");
    EXPECT_ERROR(pstream_player_update(player, -1.0, NULL), PSTREAM_ERROR_ARGUMENT, "dt");
    EXPECT_ERROR(pstream_player_seek(player, NAN), PSTREAM_ERROR_ARGUMENT, "not finite");
    pstream_player_close(player);
    {
      /* Without the decoder's saved states for going back, the particle clip holds less. */
      pstream_player_stats lean;
      options.saved_states = 0;
      CHECK(pstream_player_open(clips, 1, &options, &player) == PSTREAM_OK);
      CHECK(pstream_player_stats_get(player, &lean) == PSTREAM_OK);
      CHECK(lean.cache_bytes < stats.cache_bytes);
      pstream_player_close(player);
      options.saved_states = 3;
    }

    /* The GPU path for an engine's own shaders: no records, a frame pair (tests/sdk/frame_pair.c
     * checks its values against the CPU path). */
    options.playback = PSTREAM_PLAYBACK_GPU;
    CHECK(pstream_player_open(clips, 1, &options, &player) == PSTREAM_OK);
    CHECK(pstream_player_set_speed(player, 0.5) == PSTREAM_OK);
    CHECK(pstream_player_play(player) == PSTREAM_OK);
    {
      pstream_frame_pair pair;
      int pairs = 0;
      for (k = 0; k < 40; ++k) {
        CHECK(pstream_player_update(player, k == 0 ? 0.0 : 1.0 / 96, NULL) == PSTREAM_OK);
        CHECK(pstream_player_frame(player, 0, &frame) == PSTREAM_OK && frame.records == NULL);
        CHECK(pstream_player_frame_pair(player, 0, &pair) == PSTREAM_OK);
        if (pair.pair_count > 0) {
          CHECK(pair.a != NULL && pair.b != NULL && pair.pairs != NULL && pair.lanes != NULL);
          CHECK(pair.b_frame == pair.a_frame + 1 && pair.t > 0 && pair.t < 1 && pair.dt > 0);
          CHECK(pair.lane_count == info.record_size / 4 && pair.velocity_offset == 20);
          CHECK(pair.lanes[0] == PSTREAM_LANE_POSITION && pair.lanes[3] == PSTREAM_LANE_LERP);
          ++pairs;
        }
      }
      CHECK(pairs > 20);
      EXPECT_ERROR(pstream_player_frame_pair(player, 4, &pair), PSTREAM_ERROR_ARGUMENT, "no clip 4");
      EXPECT_ERROR(pstream_player_frame_pair(player, 0, NULL), PSTREAM_ERROR_ARGUMENT, "out");
    }
    pstream_player_close(player);
    options.playback = PSTREAM_PLAYBACK_CPU;

    /* Two clips sorted together: one order across both. */
    CHECK(pstream_player_open(clips, 2, &options, &player) == PSTREAM_OK);
    CHECK(pstream_player_play(player) == PSTREAM_OK);
    CHECK(play(player, 10) > 0);
    CHECK(pstream_player_merged_order(player, &order, &merged) == PSTREAM_OK && merged > 0 && order != NULL);
    pstream_player_close(player);

    EXPECT_ERROR(pstream_player_open(clips, 0, &options, &player), PSTREAM_ERROR_ARGUMENT, "at least one clip");
    clips[1] = join(3, work, "missing.pstream");
    EXPECT_ERROR(pstream_player_open(clips, 2, &options, &player), PSTREAM_ERROR_IO, "missing.pstream");
    clips[1] = join(2, work, "raw.pstream");
    options.interpolation = 7;
    EXPECT_ERROR(pstream_player_open(clips, 1, &options, &player), PSTREAM_ERROR_ARGUMENT, "unknown interpolation 7");
    options.interpolation = PSTREAM_INTERPOLATION_HERMITE;
    options.sort = -1;
    EXPECT_ERROR(pstream_player_open(clips, 1, &options, &player), PSTREAM_ERROR_ARGUMENT, "unknown sort -1");
    options.sort = PSTREAM_SORT_BACK_TO_FRONT;
    options.memory_budget = 1024;
    EXPECT_ERROR(pstream_player_open(clips, 1, &options, &player), PSTREAM_ERROR_BUDGET, "memory budget");
    options.memory_budget = 0;
    EXPECT_ERROR(pstream_player_play(NULL), PSTREAM_ERROR_ARGUMENT, "NULL");
    CHECK(pstream_player_close(NULL) == PSTREAM_OK); /* as free(NULL) */
    CHECK(pstream_player_clip_count(NULL) == 0);

    /* A closed handle is an error code, never a crash: closed twice, or used after close. */
    CHECK(pstream_player_open(clips, 1, &options, &player) == PSTREAM_OK);
    CHECK(pstream_player_close(player) == PSTREAM_OK);
    EXPECT_ERROR(pstream_player_close(player), PSTREAM_ERROR_ARGUMENT, "is not open");
    EXPECT_ERROR(pstream_player_update(player, 0.01, NULL), PSTREAM_ERROR_ARGUMENT, "is not open");
    EXPECT_ERROR(pstream_player_play(player), PSTREAM_ERROR_ARGUMENT, "is not open");
    CHECK(pstream_player_clip_count(player) == 0);
    EXPECT_ERROR(pstream_player_close((pstream_player*)&options), PSTREAM_ERROR_ARGUMENT, "no open returned it");
  }

  /* ---- A clip whose frames are all empty (0 chunks) plays: it once divided by zero ---- */
  {
    pstream_player* player = NULL;
    pstream_player_options options;
    pstream_frame frame;
    const char* clips[1];
    int k, i;
    clips[0] = join(3, data, "pstream/empty_frames.pstream");
    pstream_player_options_init(&options);
    for (k = 0; k < 2; ++k) {
      options.blocking = k; /* blocking (offline) and real time */
      CHECK(pstream_player_open(clips, 1, &options, &player) == PSTREAM_OK);
      CHECK(pstream_player_play(player) == PSTREAM_OK);
      for (i = 0; i < 20; ++i) {
        CHECK(pstream_player_update(player, 1.0 / 60.0, NULL) == PSTREAM_OK);
        CHECK(pstream_player_frame(player, 0, &frame) == PSTREAM_OK && frame.count == 0);
      }
      CHECK(pstream_player_check(player) == PSTREAM_OK);
      CHECK(pstream_player_close(player) == PSTREAM_OK);
    }
  }

  /* ---- The allocator hook (tests/sdk/allocator.c checks what it sees) ---- */
  {
    pstream_allocator half;
    half.user = NULL;
    half.allocate = NULL;
    half.free = NULL;
    EXPECT_ERROR(pstream_set_allocator(&half), PSTREAM_ERROR_ARGUMENT, "allocate or free is NULL");
    CHECK(pstream_set_allocator(NULL) == PSTREAM_OK);
  }

  /* ---- IO callbacks: the same frames as the file; a failing backend puts the clip in error ---- */
  {
    pstream_player* player = NULL;
    pstream_player_options options;
    pstream_io io;
    memory_file file;
    uint64_t from_file, from_memory;
    const char* clips[1];
    clips[0] = join(2, work, "raw.pstream");
    pstream_player_options_init(&options);
    options.blocking = 1;
    CHECK(pstream_player_open(clips, 1, &options, &player) == PSTREAM_OK);
    pstream_player_play(player);
    from_file = play(player, 60);
    pstream_player_close(player);

    {
      /* The same frames with the IO and decoding on the host's jobs. */
      static job_queue q;
      pstream_tasks tasks;
      uint64_t from_jobs;
      pthread_mutex_init(&q.mutex, NULL);
      pthread_cond_init(&q.wake, NULL);
      CHECK(pthread_create(&q.worker, NULL, worker_main, &q) == 0);
      tasks.user = &q;
      tasks.submit = submit_job;
      options.tasks = &tasks;
      CHECK(pstream_player_open(clips, 1, &options, &player) == PSTREAM_OK);
      pstream_player_play(player);
      from_jobs = play(player, 60);
      pstream_player_close(player);
      CHECK(from_jobs == from_file);
      pthread_mutex_lock(&q.mutex);
      q.stop = 1;
      pthread_cond_signal(&q.wake);
      pthread_mutex_unlock(&q.mutex);
      pthread_join(q.worker, NULL);
      CHECK(q.ran > 0 && !q.overflow);
      tasks.submit = NULL;
      EXPECT_ERROR(pstream_player_open(clips, 1, &options, &player), PSTREAM_ERROR_ARGUMENT, "tasks->submit is NULL");
      options.tasks = NULL;
      pthread_cond_destroy(&q.wake);
      pthread_mutex_destroy(&q.mutex);
    }

    file.bytes = load(clips[0], &file.size);
    file.reads = 0;
    file.fail_after = -1;
    CHECK(file.bytes != NULL);
    io.user = &file;
    io.read = read_memory;
    io.size = file.size;
    io.name = "pak://fx/raw.pstream";
    io.read_async = NULL;
    options.io = &io;
    CHECK(pstream_player_open(NULL, 1, &options, &player) == PSTREAM_OK);
    pstream_player_play(player);
    from_memory = play(player, 60);
    CHECK(from_memory == from_file && file.reads > 0);
    pstream_player_close(player);

    file.reads = 0;
    file.fail_after = 2; /* the header and the tables, then the first chunk fails */
    CHECK(pstream_player_open(NULL, 1, &options, &player) == PSTREAM_OK);
    pstream_player_play(player);
    play(player, 5);
    EXPECT_ERROR(pstream_player_check(player), PSTREAM_ERROR_STATE, "pak://fx/raw.pstream");
    pstream_player_close(player);

    {
      /* The same frames through asynchronous reads completed on the host's IO thread, without
       * `read` (the header and tables too); then reads that complete with a failure. */
      static async_io aio;
      uint64_t from_async;
      pthread_mutex_init(&aio.mutex, NULL);
      pthread_cond_init(&aio.wake, NULL);
      aio.file = &file;
      aio.fail_from = -1;
      CHECK(pthread_create(&aio.thread, NULL, async_io_main, &aio) == 0);
      io.user = &aio;
      io.read = NULL;
      io.read_async = read_async;
      CHECK(pstream_player_open(NULL, 1, &options, &player) == PSTREAM_OK);
      pstream_player_play(player);
      from_async = play(player, 60);
      pstream_player_close(player);
      CHECK(from_async == from_file && aio.served > 2 && !aio.overflow);
      aio.fail_from = 1; /* the chunks fail; the header (at 0) and the tables (at the end) read */
      aio.fail_to = (int64_t)(file.size / 2);
      CHECK(pstream_player_open(NULL, 1, &options, &player) == PSTREAM_OK);
      pstream_player_play(player);
      play(player, 60);
      EXPECT_ERROR(pstream_player_check(player), PSTREAM_ERROR_STATE, "failed with status 5");
      pstream_player_close(player);
      pthread_mutex_lock(&aio.mutex);
      aio.stop = 1;
      pthread_cond_signal(&aio.wake);
      pthread_mutex_unlock(&aio.mutex);
      pthread_join(aio.thread, NULL);
      pthread_cond_destroy(&aio.wake);
      pthread_mutex_destroy(&aio.mutex);
      io.user = &file;
    }

    io.read_async = NULL;
    EXPECT_ERROR(pstream_player_open(NULL, 1, &options, &player), PSTREAM_ERROR_ARGUMENT,
                 "neither read nor read_async");

    /* A corrupt chunk: one byte changed in the middle of the raw clip's data. */
    file.bytes[file.size / 2] ^= 0x5a;
    CHECK(save(join(4, work, "corrupt.pstream"), file.bytes, file.size));
    free(file.bytes);
    clips[0] = join(4, work, "corrupt.pstream");
    options.io = NULL;
    CHECK(pstream_player_open(clips, 1, &options, &player) == PSTREAM_OK);
    pstream_player_play(player);
    play(player, 60);
    EXPECT_ERROR(pstream_player_check(player), PSTREAM_ERROR_STATE, "checksum");
    pstream_player_close(player);
  }

  if (failures) {
    fprintf(stderr, "%d check(s) failed\n", failures);
    return 1;
  }
  printf("every C API function checked\n");
  return 0;
}
