/* The adversarial tree's host: one hostile input through the C API, as an engine would use it.
 * Opens it as a clip (info, attributes, every frame's info, the first frames read), then plays
 * it in a blocking player reading the file, and in a real-time player reading through host IO
 * callbacks (read and read_async) over the file's bytes in memory, with GPU playback. Every call
 * must return a result code with a message, or succeed: the tree's runner fails on a signal, a
 * hang or a sanitizer report. Exits 0 whatever the codes were; 2 for a code outside the enum or
 * an error code with no message.
 *
 *   host_open FILE
 */
#define _POSIX_C_SOURCE 200809L
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include <particlestream/particlestream.h>

static int bad = 0;

/* Checks a call's result: PSTREAM_OK, or an error code with a message. */
static pstream_result checked(pstream_result r, const char* what) {
  const char* name = pstream_result_name(r);
  if (r != PSTREAM_OK) {
    const char* message = pstream_last_error();
    if (name == NULL || message == NULL || message[0] == '\0') {
      fprintf(stderr, "%s: result %d without a name or message\n", what, (int)r);
      bad = 1;
    } else {
      printf("%s: %s: %s\n", what, name, message);
    }
  }
  return r;
}

typedef struct memory_file {
  unsigned char* bytes;
  uint64_t size;
} memory_file;

static int read_now(void* user, uint64_t offset, void* out, uint64_t size) {
  const memory_file* f = (const memory_file*)user;
  if (offset > f->size || size > f->size - offset) return 5;
  if (size > 0) memcpy(out, f->bytes + offset, (size_t)size);
  return 0;
}

static int read_async(void* user, uint64_t offset, void* out, uint64_t size, pstream_io_done done, void* token) {
  done(token, read_now(user, offset, out, size));
  return 0;
}

static void read_clip(const char* path) {
  pstream_clip* clip = NULL;
  if (checked(pstream_clip_open(path, &clip), "clip_open") != PSTREAM_OK) return;
  pstream_clip_info info;
  if (checked(pstream_clip_info_get(clip, &info), "clip_info") == PSTREAM_OK) {
    for (uint32_t a = 0; a < info.attribute_count; ++a) {
      pstream_attribute attribute;
      checked(pstream_clip_attribute(clip, a, &attribute), "clip_attribute");
    }
    for (uint64_t f = 0; f < info.frame_count; ++f) {
      uint64_t count = 0;
      double time = 0;
      if (checked(pstream_clip_frame_info(clip, f, &count, &time), "clip_frame_info") != PSTREAM_OK) break;
      if (f >= 3) continue;
      /* The buffer the frame needs, as a host sizes it: at most 64 MiB here. */
      const uint64_t bytes = count * info.record_size;
      if (bytes > ((uint64_t)64 << 20)) continue;
      void* out = malloc(bytes ? (size_t)bytes : 1);
      if (out == NULL) continue;
      checked(pstream_clip_read_frame(clip, f, out, bytes), "clip_read_frame");
      free(out);
    }
  }
  checked(pstream_clip_close(clip), "clip_close");
}

static void play(const char* path, const pstream_io* io, int blocking) {
  pstream_player_options options;
  pstream_player_options_init(&options);
  options.blocking = blocking;
  options.io = io;
  options.io_timeout_seconds = 5;
  options.playback = blocking ? PSTREAM_PLAYBACK_CPU : PSTREAM_PLAYBACK_GPU;
  options.sort = PSTREAM_SORT_BACK_TO_FRONT;
  pstream_player* player = NULL;
  const char* paths[1] = {path};
  if (checked(pstream_player_open(io ? NULL : paths, 1, &options, &player), "player_open") != PSTREAM_OK) return;
  checked(pstream_player_play(player), "player_play");
  for (int i = 0; i < 4; ++i) {
    if (checked(pstream_player_update(player, 1.0 / 30, NULL), "player_update") != PSTREAM_OK) break;
    pstream_frame frame;
    if (blocking) {
      checked(pstream_player_frame(player, 0, &frame), "player_frame");
    } else {
      pstream_frame_pair pair;
      checked(pstream_player_frame_pair(player, 0, &pair), "player_frame_pair");
    }
  }
  checked(pstream_player_seek(player, 0.5), "player_seek");
  checked(pstream_player_set_speed(player, -1), "player_set_speed");
  checked(pstream_player_update(player, 1.0 / 30, NULL), "player_update");
  checked(pstream_player_check(player), "player_check");
  checked(pstream_player_close(player), "player_close");
}

int main(int argc, char** argv) {
  if (argc != 2) {
    fprintf(stderr, "usage: host_open FILE\n");
    return 1;
  }
  const char* path = argv[1];
  read_clip(path);
  play(path, NULL, 1);

  /* The same bytes through host IO callbacks (at most 64 MiB of them), from regular files only
   * (this host's own reading of a FIFO would wait for a writer). */
  struct stat st;
  if (stat(path, &st) != 0 || !S_ISREG(st.st_mode)) return bad ? 2 : 0;
  FILE* file = fopen(path, "rb");
  if (file == NULL) return bad ? 2 : 0; /* a folder or a FIFO: the opens above said so */
  memory_file memory = {NULL, 0};
  unsigned char buffer[65536];
  size_t n;
  while ((n = fread(buffer, 1, sizeof buffer, file)) > 0 && memory.size < ((uint64_t)64 << 20)) {
    unsigned char* grown = (unsigned char*)realloc(memory.bytes, (size_t)memory.size + n);
    if (grown == NULL) break;
    memory.bytes = grown;
    memcpy(memory.bytes + memory.size, buffer, n);
    memory.size += n;
  }
  fclose(file);
  pstream_io io;
  memset(&io, 0, sizeof io);
  io.user = &memory;
  io.read = read_now;
  io.read_async = read_async;
  io.size = memory.size;
  io.name = path;
  play(NULL, &io, 0);
  free(memory.bytes);
  return bad ? 2 : 0;
}
