/* An engine's own GPU path through the C API (PSTREAM_PLAYBACK_GPU): the frame pair that
 * pstream_player_frame_pair() hands out, interpolated here by the rules docs/embedding.md gives
 * (written out in C, as an engine would write them in its shaders), equals the CPU path's frame
 * from pstream_player_frame(): every float within 2 ulps or 1e-6 of its terms' magnitude, ids
 * and colours exact. On the sparks fixture (births and deaths, matched by id) played forwards,
 * in slow motion and backwards, with the particle codec (its own matching) and the records codec.
 *
 *   frame_pair DATA_DIR WORK_DIR */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <particlestream/particlestream.h>

#include "check.h"

static float word_f(const unsigned char* rec, uint32_t w) {
  float v;
  memcpy(&v, rec + 4 * w, 4);
  return v;
}
static uint32_t word_u(const unsigned char* rec, uint32_t w) {
  uint32_t v;
  memcpy(&v, rec + 4 * w, 4);
  return v;
}
static void put_f(unsigned char* rec, uint32_t w, float v) { memcpy(rec + 4 * w, &v, 4); }

/* The reference rules (docs/embedding.md), one particle of the pair table into `out`. */
static void interpolate(const pstream_frame_pair* p, uint64_t i, unsigned char* out) {
  const uint32_t ia = p->pairs[2 * i], ib = p->pairs[2 * i + 1], words = p->lane_count;
  const unsigned char* a = (const unsigned char*)p->a;
  const unsigned char* b = (const unsigned char*)p->b;
  const double t = p->t, dt = p->dt, t2 = t * t, t3 = t2 * t;
  const int vel = p->velocity_offset >= 0, hermite = p->hermite && vel;
  const uint32_t shift = vel ? (uint32_t)p->velocity_offset / 4 : 0;
  if (ia != PSTREAM_NO_PARTICLE && ib != PSTREAM_NO_PARTICLE) {
    const unsigned char* ra = a + (uint64_t)ia * p->record_size;
    const unsigned char* rb = b + (uint64_t)ib * p->record_size;
    const float la = (float)(1 - t), lb = (float)t;
    const float h00 = (float)(2 * t3 - 3 * t2 + 1), h01 = (float)(-2 * t3 + 3 * t2);
    const float h10 = (float)((t3 - 2 * t2 + t) * dt), h11 = (float)((t3 - t2) * dt);
    const float d00 = (float)((6 * t2 - 6 * t) / dt), d01 = (float)((6 * t - 6 * t2) / dt);
    const float d10 = (float)(3 * t2 - 4 * t + 1), d11 = (float)(3 * t2 - 2 * t);
    uint32_t w;
    for (w = 0; w < words; ++w) {
      int lane = p->lanes[w];
      if (!hermite && (lane == PSTREAM_LANE_POSITION || lane == PSTREAM_LANE_VELOCITY)) lane = PSTREAM_LANE_LERP;
      if (lane == PSTREAM_LANE_COPY) {
        memcpy(out + 4 * w, ra + 4 * w, 4);
      } else if (lane == PSTREAM_LANE_LERP) {
        put_f(out, w, la * word_f(ra, w) + lb * word_f(rb, w));
      } else if (lane == PSTREAM_LANE_POSITION) {
        put_f(
            out, w,
            (h00 * word_f(ra, w) + h01 * word_f(rb, w)) + (h10 * word_f(ra, w + shift) + h11 * word_f(rb, w + shift)));
      } else {
        put_f(
            out, w,
            (d10 * word_f(ra, w) + d11 * word_f(rb, w)) + (d00 * word_f(ra, w - shift) + d01 * word_f(rb, w - shift)));
      }
    }
    if (p->color_offset >= 0) { /* per byte, rounded */
      const uint32_t cw = (uint32_t)p->color_offset / 4, ca = word_u(ra, cw), cb = word_u(rb, cw);
      uint32_t c = 0, k;
      for (k = 0; k < 4; ++k) {
        const float x = (float)((ca >> (8 * k)) & 255u), y = (float)((cb >> (8 * k)) & 255u);
        c |= ((uint32_t)(int)(x + (y - x) * (float)t + 0.5f) & 255u) << (8 * k);
      }
      memcpy(out + 4 * cw, &c, 4);
    }
    return;
  }
  {
    /* Only in a (dies: goes on along its velocity, shrinking to nothing at b) or only in b (is
     * born: comes in along its velocity, growing); the nearer frame keeps its size. */
    const int from_a = ia != PSTREAM_NO_PARTICLE;
    const unsigned char* src = from_a ? a + (uint64_t)ia * p->record_size : b + (uint64_t)ib * p->record_size;
    const double seconds = from_a ? t * dt : -(1 - t) * dt;
    const float grow = p->nearer ? 1.0f : (float)(from_a ? 1 - t : t);
    uint32_t c;
    memcpy(out, src, p->record_size);
    if (p->nearer && !vel) return;
    if (vel) {
      for (c = 0; c < 3; ++c) put_f(out, c, (float)((double)word_f(src, c) + seconds * (double)word_f(src, shift + c)));
    }
    put_f(out, 3, word_f(src, 3) * grow); /* scale: word 3 of the record head */
  }
}

static int close_enough(float g, float c, double terms) {
  int32_t ig, ic;
  memcpy(&ig, &g, 4);
  memcpy(&ic, &c, 4);
  if (ig == ic) return 1;
  if (llabs((long long)ig - (long long)ic) <= 2) return 1;
  return fabs((double)g - (double)c) <= 1e-6 * (terms > fabs(c) ? terms : fabs(c));
}

static void compare(const char* clip, double speed) {
  pstream_player_options o;
  pstream_player *cpu = NULL, *gpu = NULL;
  const float view[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, -5, 1};
  unsigned char* mine = NULL;
  int k, between = 0;
  uint64_t checked = 0;
  pstream_player_options_init(&o);
  o.blocking = 1;
  o.loop = 0;
  CHECK(pstream_player_open(&clip, 1, &o, &cpu) == PSTREAM_OK);
  o.playback = PSTREAM_PLAYBACK_GPU;
  CHECK(pstream_player_open(&clip, 1, &o, &gpu) == PSTREAM_OK);
  if (!cpu || !gpu) return;
  {
    pstream_clip_info info;
    CHECK(pstream_player_clip_info(cpu, 0, &info) == PSTREAM_OK);
    mine = (unsigned char*)malloc((size_t)(2 * info.max_count * info.record_size + 1));
    if (speed < 0) {
      CHECK(pstream_player_seek(cpu, info.end_time) == PSTREAM_OK);
      CHECK(pstream_player_seek(gpu, info.end_time) == PSTREAM_OK);
    }
  }
  CHECK(pstream_player_set_speed(cpu, speed) == PSTREAM_OK);
  CHECK(pstream_player_set_speed(gpu, speed) == PSTREAM_OK);
  CHECK(pstream_player_play(cpu) == PSTREAM_OK);
  CHECK(pstream_player_play(gpu) == PSTREAM_OK);
  for (k = 0; k < 48; ++k) {
    pstream_frame f, g;
    pstream_frame_pair p;
    uint64_t i, n;
    const double dt = k == 0 ? 0.0 : 1.0 / 120;
    CHECK(pstream_player_update(cpu, dt, view) == PSTREAM_OK);
    CHECK(pstream_player_update(gpu, dt, view) == PSTREAM_OK);
    CHECK(pstream_player_frame(cpu, 0, &f) == PSTREAM_OK);
    CHECK(pstream_player_frame(gpu, 0, &g) == PSTREAM_OK);
    CHECK(g.records == NULL && g.order == NULL);
    CHECK(pstream_player_frame_pair(gpu, 0, &p) == PSTREAM_OK);
    n = p.pair_count ? p.pair_count : p.a_count;
    CHECK(n == f.count);
    if (n != f.count) break;
    CHECK(p.lane_count * 4 == p.record_size && p.record_size == f.record_size);
    between += p.pair_count > 0;
    for (i = 0; i < n; ++i) {
      unsigned char* out = mine + i * p.record_size;
      const unsigned char* want = (const unsigned char*)f.records + i * f.record_size;
      uint32_t w;
      double magnitude = 1;
      if (p.pair_count) {
        interpolate(&p, i, out);
      } else {
        memcpy(out, (const unsigned char*)p.a + i * p.record_size, p.record_size);
      }
      for (w = 0; w < 3; ++w) magnitude = fmax(magnitude, fabs(word_f(want, w)));
      for (w = 0; w < p.lane_count; ++w) {
        int ok = word_u(out, w) == word_u(want, w);
        if (!ok && p.lanes[w] != PSTREAM_LANE_COPY)
          ok = close_enough(word_f(out, w), word_f(want, w),
                            p.lanes[w] == PSTREAM_LANE_VELOCITY ? magnitude * 1.5 / p.dt : magnitude);
        if (!ok) {
          if (failures < 5)
            fprintf(stderr, "%s speed %g host frame %d particle %llu word %u: reference %g, library %g\n", clip, speed,
                    k, (unsigned long long)i, w, word_f(out, w), word_f(want, w));
          ++failures;
        }
        ++checked;
      }
    }
  }
  CHECK(between > 10);
  CHECK(checked > 10000);
  free(mine);
  /* The CPU player has no pair to give. */
  {
    pstream_frame_pair p;
    EXPECT_ERROR(pstream_player_frame_pair(cpu, 0, &p), PSTREAM_ERROR_ARGUMENT, "PSTREAM_PLAYBACK_GPU");
  }
  CHECK(pstream_player_close(cpu) == PSTREAM_OK);
  CHECK(pstream_player_close(gpu) == PSTREAM_OK);
}

int main(int argc, char** argv) {
  char input[1024], records[1024], particle[1024];
  pstream_cook_options o;
  if (argc < 3) return 2;
  snprintf(input, sizeof input, "%s/sims/blender_sparks.abc", argv[1]);
  snprintf(records, sizeof records, "%s/records.pstream", argv[2]);
  snprintf(particle, sizeof particle, "%s/particle.pstream", argv[2]);
  pstream_cook_options_init(&o);
  o.input = input;
  o.output = records;
  o.attributes = "velocity,id";
  CHECK(pstream_cook(&o, NULL) == PSTREAM_OK);
  o.output = particle;
  o.codec = PSTREAM_CODEC_PARTICLE;
  CHECK(pstream_cook(&o, NULL) == PSTREAM_OK);
  compare(records, 1.0);
  compare(records, -0.5);
  compare(particle, 0.25);
  {
    pstream_player_options bad;
    pstream_player* p = NULL;
    const char* clip = records;
    pstream_player_options_init(&bad);
    bad.playback = 7;
    EXPECT_ERROR(pstream_player_open(&clip, 1, &bad, &p), PSTREAM_ERROR_ARGUMENT, "unknown playback 7");
  }
  if (failures) fprintf(stderr, "%d failures\n", failures);
  return failures != 0;
}
