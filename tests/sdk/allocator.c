/* The allocator hook (pstream_set_allocator) sees every allocation the library makes, and none
 * happen during playback. This program replaces malloc and its relatives for the whole process
 * and records who called them while the library works: a caller inside libparticlestream (or a
 * library it uses: libstdc++, fmt, zstd, lz4, xxhash) is an allocation that went around the
 * hook. Only the C library's own (thread stacks and TLS, stdio) are allowed. The hook itself
 * allocates with __libc_memalign, outside the record.
 *
 *   allocator DATA_DIR WORK_DIR     (DATA_DIR: tests/data; WORK_DIR: an empty folder)
 */
#define _GNU_SOURCE /* dladdr */
#include <dlfcn.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <particlestream/particlestream.h>

#include "check.h"

extern void* __libc_malloc(size_t size);
extern void* __libc_calloc(size_t count, size_t size);
extern void* __libc_realloc(void* block, size_t size);
extern void* __libc_memalign(size_t alignment, size_t size);
extern void __libc_free(void* block);

/* ---- Who calls malloc while we watch --------------------------------------------------------- */

static volatile int watching = 0;
static void* callers[8192];
static volatile int caller_count = 0;

static void note(void* caller) {
  if (watching) {
    const int at = __sync_fetch_and_add(&caller_count, 1);
    if (at < 8192) callers[at] = caller;
  }
}

void* malloc(size_t size) {
  note(__builtin_return_address(0));
  return __libc_malloc(size);
}
void* calloc(size_t count, size_t size) {
  note(__builtin_return_address(0));
  return __libc_calloc(count, size);
}
void* realloc(void* block, size_t size) {
  note(__builtin_return_address(0));
  return __libc_realloc(block, size);
}
void* memalign(size_t alignment, size_t size) {
  note(__builtin_return_address(0));
  return __libc_memalign(alignment, size);
}
void* aligned_alloc(size_t alignment, size_t size) {
  note(__builtin_return_address(0));
  return __libc_memalign(alignment, size);
}
int posix_memalign(void** out, size_t alignment, size_t size) {
  note(__builtin_return_address(0));
  *out = __libc_memalign(alignment, size);
  return *out != NULL ? 0 : 12; /* ENOMEM */
}
void free(void* block) { __libc_free(block); }

/* ---- The host's allocator ---------------------------------------------------------------------- */

typedef struct counting_allocator {
  uint64_t allocations, frees, bytes;
  int misaligned;
} counting_allocator;

static void* count_allocate(void* user, size_t size, size_t alignment) {
  counting_allocator* a = (counting_allocator*)user;
  void* block = __libc_memalign(alignment, size);
  __sync_fetch_and_add(&a->allocations, 1);
  __sync_fetch_and_add(&a->bytes, size);
  if (alignment < 16 || (alignment & (alignment - 1)) != 0) a->misaligned = 1;
  return block;
}
static void count_free(void* user, void* block) {
  counting_allocator* a = (counting_allocator*)user;
  __sync_fetch_and_add(&a->frees, 1);
  __libc_free(block);
}

static char paths[4][1024];
static const char* join(int slot, const char* dir, const char* name) {
  snprintf(paths[slot], sizeof paths[slot], "%s/%s", dir, name);
  return paths[slot];
}

/* The library's own allocations are the ones whose caller lies outside the C library. */
static int is_c_library(const char* file) {
  const char* base = strrchr(file, '/');
  base = base != NULL ? base + 1 : file;
  return strncmp(base, "libc.so", 7) == 0 || strncmp(base, "ld-linux", 8) == 0;
}

int main(int argc, char** argv) {
  counting_allocator host = {0, 0, 0, 0};
  pstream_allocator allocator;
  uint64_t at_open, during_playback = 0;
  int i, outside = 0, in_libc = 0;
  if (argc != 3) {
    fprintf(stderr, "usage: %s DATA_DIR WORK_DIR\n", argv[0]);
    return 2;
  }
  allocator.user = &host;
  allocator.allocate = count_allocate;
  allocator.free = count_free;
  CHECK(pstream_set_allocator(&allocator) == PSTREAM_OK);

  watching = 1;
  { /* read an archive, cook it with the particle codec and with zstd, read a frame back */
    pstream_archive* archive = NULL;
    pstream_clip* clip = NULL;
    pstream_cook_options cook;
    pstream_clip_info info;
    size_t count = 0;
    float positions[3 * 64];
    static unsigned char frame[1 << 20];
    CHECK(pstream_archive_open(join(0, argv[1], "alembic/points_varying.abc"), &archive) == PSTREAM_OK);
    CHECK(pstream_archive_points_count(archive, &count) == PSTREAM_OK && count == 1);
    CHECK(pstream_archive_read_positions(archive, 0, 1, positions, 3 * 64) == PSTREAM_OK);
    pstream_archive_close(archive);

    pstream_cook_options_init(&cook);
    cook.input = paths[0];
    cook.output = join(1, argv[2], "particle.pstream");
    cook.attributes = "velocity,id";
    cook.codec = PSTREAM_CODEC_PARTICLE;
    CHECK(pstream_cook(&cook, NULL) == PSTREAM_OK);
    cook.output = join(2, argv[2], "zstd.pstream");
    cook.codec = PSTREAM_CODEC_ZSTD;
    CHECK(pstream_cook(&cook, NULL) == PSTREAM_OK);

    CHECK(pstream_clip_open(paths[1], &clip) == PSTREAM_OK);
    CHECK(pstream_clip_info_get(clip, &info) == PSTREAM_OK);
    CHECK(info.max_count * info.record_size <= sizeof frame);
    CHECK(pstream_clip_read_frame(clip, info.frame_count - 1, frame, sizeof frame) == PSTREAM_OK);
    pstream_clip_close(clip);
  }
  { /* play both clips together: allocations at open only */
    pstream_player* player = NULL;
    pstream_player_options options;
    const char* clips[2];
    float view[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, -5, 1};
    clips[0] = paths[1];
    clips[1] = paths[2];
    pstream_player_options_init(&options);
    options.blocking = 1;
    CHECK(pstream_player_open(clips, 2, &options, &player) == PSTREAM_OK);
    CHECK(pstream_player_play(player) == PSTREAM_OK);
    at_open = host.allocations;
    for (i = 0; i < 300; ++i) {
      pstream_frame frame;
      CHECK(pstream_player_update(player, i == 0 ? 0.0 : 1.0 / 96, view) == PSTREAM_OK);
      CHECK(pstream_player_frame(player, 0, &frame) == PSTREAM_OK);
    }
    during_playback = host.allocations - at_open;
    CHECK(pstream_player_check(player) == PSTREAM_OK);
    pstream_player_close(player);
  }
  watching = 0;

  CHECK(host.allocations > 100); /* the cook alone makes thousands */
  CHECK(during_playback == 0);
  CHECK(host.frees == host.allocations); /* everything returned once the handles closed */
  CHECK(!host.misaligned);
  for (i = 0; i < caller_count && i < 8192; ++i) {
    Dl_info where;
    if (dladdr(callers[i], &where) != 0 && where.dli_fname != NULL && is_c_library(where.dli_fname)) {
      ++in_libc;
      continue;
    }
    ++outside;
    if (outside <= 10)
      fprintf(stderr, "malloc around the hook from %s (%s)\n", where.dli_fname ? where.dli_fname : "?",
              where.dli_sname ? where.dli_sname : "?");
  }
  CHECK(caller_count <= 8192);
  CHECK(outside == 0);
  /* Back to malloc/free; a half-set allocator is refused. */
  allocator.free = NULL;
  CHECK(pstream_set_allocator(&allocator) == PSTREAM_ERROR_ARGUMENT);
  CHECK(pstream_set_allocator(NULL) == PSTREAM_OK);
  printf(
      "hook: %llu allocations (%llu bytes), all freed; 0 during 300 playback updates; "
      "%d malloc calls by the C library itself, %d around the hook\n",
      (unsigned long long)host.allocations, (unsigned long long)host.bytes, in_libc, outside);
  if (failures) {
    fprintf(stderr, "%d check(s) failed\n", failures);
    return 1;
  }
  return 0;
}
