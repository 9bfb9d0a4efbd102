/* A host that breaks the C API's rules gets error codes, never a crash or a hang (issue #25):
 * a read_async completion called twice, one that never comes, handles closed twice. Each case
 * must also end quickly: the program runs under a CTest timeout.
 *
 *   misuse DATA_DIR WORK_DIR     (DATA_DIR: tests/data; WORK_DIR: an empty folder)
 */
#define _POSIX_C_SOURCE 200809L
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <particlestream/particlestream.h>

#include "check.h"

typedef struct host_file {
  unsigned char* bytes;
  uint64_t size;
  int mode; /* 0: complete twice, 1: never complete */
  int async_reads;
} host_file;

static int read_now(void* user, uint64_t offset, void* out, uint64_t size) {
  host_file* f = (host_file*)user;
  memcpy(out, f->bytes + offset, (size_t)size);
  return 0;
}

static int read_async(void* user, uint64_t offset, void* out, uint64_t size, pstream_io_done done, void* token) {
  host_file* f = (host_file*)user;
  ++f->async_reads;
  if (f->mode == 1) return 0; /* accepted, and forgotten */
  memcpy(out, f->bytes + offset, (size_t)size);
  done(token, 0);
  done(token, 0); /* the bug: a second completion of the same read */
  return 0;
}

static double now_seconds(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + (double)t.tv_nsec / 1e9;
}

static unsigned char* load(const char* path, uint64_t* size) {
  FILE* f = fopen(path, "rb");
  unsigned char* bytes;
  long n;
  if (f == NULL) return NULL;
  fseek(f, 0, SEEK_END);
  n = ftell(f);
  fseek(f, 0, SEEK_SET);
  bytes = (unsigned char*)malloc((size_t)n);
  if (bytes == NULL || fread(bytes, 1, (size_t)n, f) != (size_t)n) {
    fclose(f);
    free(bytes);
    return NULL;
  }
  fclose(f);
  *size = (uint64_t)n;
  return bytes;
}

/* Plays until the player reports an error or `seconds` pass; returns the seconds it took, or -1. */
static double play_until_error(pstream_player* player, double seconds, pstream_result* result) {
  const double start = now_seconds();
  *result = PSTREAM_OK;
  while (now_seconds() - start < seconds) {
    *result = pstream_player_update(player, 1.0 / 60.0, NULL);
    if (*result == PSTREAM_OK) *result = pstream_player_check(player);
    if (*result != PSTREAM_OK) return now_seconds() - start;
  }
  return -1.0;
}

int main(int argc, char** argv) {
  char path[1024];
  host_file file;
  int blocking;
  if (argc < 3) return 2;
  snprintf(path, sizeof path, "%s/pstream_v1/points_varying_lz4.pstream", argv[1]);
  memset(&file, 0, sizeof file);
  file.bytes = load(path, &file.size);
  CHECK(file.bytes != NULL);
  if (file.bytes == NULL) return 1;

  for (blocking = 0; blocking < 2; ++blocking) {
    int mode;
    for (mode = 0; mode < 2; ++mode) {
      pstream_player* player = NULL;
      pstream_player_options options;
      pstream_io io;
      pstream_result result;
      double took, closed_at;
      const char* expected = mode == 0 ? "more than once" : "did not complete within 0.5 s";
      file.mode = mode;
      file.async_reads = 0;
      memset(&io, 0, sizeof io);
      io.user = &file;
      io.read = read_now; /* the header and tables at open */
      io.read_async = read_async;
      io.size = file.size;
      io.name = "host.pstream";
      pstream_player_options_init(&options);
      options.io = &io;
      options.blocking = blocking;
      options.io_timeout_seconds = 0.5;
      CHECK(pstream_player_open(NULL, 1, &options, &player) == PSTREAM_OK);
      CHECK(pstream_player_play(player) == PSTREAM_OK);
      took = play_until_error(player, 10.0, &result);
      CHECK(file.async_reads > 0);
      CHECK(took >= 0.0); /* the error came, within seconds, in blocking mode too */
      CHECK(result == PSTREAM_ERROR_STATE);
      CHECK(strstr(pstream_last_error(), expected) != NULL);
      CHECK(strstr(pstream_last_error(), "host.pstream") != NULL);
      if (took < 0.0 || strstr(pstream_last_error(), expected) == NULL)
        fprintf(stderr, "  blocking %d, mode %d: %s after %.2f s\n", blocking, mode, pstream_last_error(), took);
      /* Close returns although a read is still with the host (mode 1), and a second close is
       * an error code. */
      closed_at = now_seconds();
      CHECK(pstream_player_close(player) == PSTREAM_OK);
      CHECK(now_seconds() - closed_at < 5.0);
      EXPECT_ERROR(pstream_player_close(player), PSTREAM_ERROR_ARGUMENT, "is not open");
    }
  }

  {
    /* A timeout that is not a number is refused. */
    pstream_player_options options;
    pstream_player* player = NULL;
    const char* clips[1];
    clips[0] = path;
    pstream_player_options_init(&options);
    options.io_timeout_seconds = -1.0;
    EXPECT_ERROR(pstream_player_open(clips, 1, &options, &player), PSTREAM_ERROR_ARGUMENT, "io_timeout_seconds");
    /* Nor a negative number of saved states. */
    pstream_player_options_init(&options);
    options.saved_states = -1;
    EXPECT_ERROR(pstream_player_open(clips, 1, &options, &player), PSTREAM_ERROR_ARGUMENT, "saved_states is -1");
    /* A struct from an older release (without io_timeout_seconds) is still taken. */
    pstream_player_options_init(&options);
    options.struct_size = sizeof options - sizeof(double);
    CHECK(pstream_player_open(clips, 1, &options, &player) == PSTREAM_OK);
    CHECK(pstream_player_close(player) == PSTREAM_OK);
  }
  free(file.bytes);
  if (failures) fprintf(stderr, "%d checks failed\n", failures);
  printf("misuse: %s\n", failures ? "FAILED" : "all checks passed");
  return failures != 0;
}
