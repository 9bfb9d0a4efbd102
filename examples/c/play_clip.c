/* The smallest engine loop on the C API: open a .pstream, play it at 60 Hz for its length, and
 * print each host frame's particle count and the mean position of what it would draw. Built
 * against the installed package (CMakeLists.txt here, or pkg-config):
 *
 *   cmake -S examples/c -B build-example -DCMAKE_PREFIX_PATH=/usr/local && cmake --build build-example
 *   cc -std=c99 play_clip.c $(pkg-config --cflags --libs particlestream) -o play_clip
 *   ./play_clip splash.pstream
 */
#include <stdio.h>
#include <string.h>

#include <particlestream/particlestream.h>

int main(int argc, char** argv) {
  pstream_player* player = NULL;
  pstream_player_options options;
  pstream_clip_info info;
  const char* clips[1];
  int frames, k;
  if (argc != 2) {
    fprintf(stderr, "usage: %s CLIP.pstream\n", argv[0]);
    return 2;
  }
  if (pstream_version() / 10000 != PSTREAM_VERSION_MAJOR) {
    fprintf(stderr, "libparticlestream %u does not match this header (%d)\n", pstream_version(), PSTREAM_VERSION);
    return 1;
  }
  clips[0] = argv[1];
  pstream_player_options_init(&options);
  options.blocking = 1; /* every frame, not a real-time clock */
  options.loop = 0;
  if (pstream_player_open(clips, 1, &options, &player) != PSTREAM_OK ||
      pstream_player_clip_info(player, 0, &info) != PSTREAM_OK) {
    fprintf(stderr, "%s\n", pstream_last_error());
    return 1;
  }
  pstream_player_play(player);
  frames = (int)((info.end_time - info.start_time) * 60.0) + 1;
  for (k = 0; k < frames; ++k) {
    pstream_frame frame;
    double mean[3] = {0, 0, 0};
    uint64_t i;
    if (pstream_player_update(player, k == 0 ? 0.0 : 1.0 / 60, NULL) != PSTREAM_OK ||
        pstream_player_check(player) != PSTREAM_OK || pstream_player_frame(player, 0, &frame) != PSTREAM_OK) {
      fprintf(stderr, "%s\n", pstream_last_error());
      pstream_player_close(player);
      return 1;
    }
    for (i = 0; i < frame.count; ++i) {
      float p[3];
      memcpy(p, (const char*)frame.records + i * frame.record_size, sizeof p);
      mean[0] += p[0], mean[1] += p[1], mean[2] += p[2];
    }
    if (frame.count) mean[0] /= (double)frame.count, mean[1] /= (double)frame.count, mean[2] /= (double)frame.count;
    printf("%d %.4f %llu %.5f %.5f %.5f\n", k, frame.time, (unsigned long long)frame.count, mean[0], mean[1], mean[2]);
  }
  pstream_player_close(player);
  return 0;
}
