/* A clip in a window: the host's own GLFW + OpenGL loop, and the C API doing the streaming,
 * interpolation and depth sort. What an engine integration does, in one page: each host frame,
 * update the player with the frame's time step and the camera's view matrix, then draw the
 * records it hands out, in the order it hands out.
 *
 *   view_clip CLIP.pstream                       a window; Esc closes it
 *   view_clip CLIP.pstream --frames 90 --screenshot out.ppm
 *                                                90 host frames at 1/60 s each, waiting for data
 *                                                (a deterministic run), then the last as a PPM
 *
 * Built against the installed package with find_package (CMakeLists.txt here), or:
 *   cc -std=c99 view_clip.c $(pkg-config --cflags --libs particlestream glfw3 gl) -lm -o view_clip
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <GLFW/glfw3.h>
#include <particlestream/particlestream.h>

static int save_ppm(const char* path, int width, int height) {
  unsigned char* rgb = (unsigned char*)malloc((size_t)width * (size_t)height * 3);
  FILE* f = fopen(path, "wb");
  int y, ok = rgb != NULL && f != NULL;
  if (ok) {
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    glReadPixels(0, 0, width, height, GL_RGB, GL_UNSIGNED_BYTE, rgb);
    ok = fprintf(f, "P6\n%d %d\n255\n", width, height) > 0;
    for (y = height - 1; ok && y >= 0; --y) /* GL's rows run bottom-up */
      ok = fwrite(rgb + (size_t)y * (size_t)width * 3, 1, (size_t)width * 3, f) == (size_t)width * 3;
  }
  if (f != NULL && fclose(f) != 0) ok = 0;
  free(rgb);
  return ok;
}

int main(int argc, char** argv) {
  const char* screenshot = NULL;
  const char* clips[1];
  int frames = 0, k, i, width = 960, height = 540, status = 0;
  pstream_player* player = NULL;
  pstream_player_options options;
  pstream_clip_info info;
  GLFWwindow* window;
  float center[3], radius, view[16];
  double last;

  for (i = 2; i < argc; ++i) {
    if (strcmp(argv[i], "--frames") == 0 && i + 1 < argc) {
      frames = atoi(argv[++i]);
    } else if (strcmp(argv[i], "--screenshot") == 0 && i + 1 < argc) {
      screenshot = argv[++i];
    } else {
      break;
    }
  }
  if (argc < 2 || i != argc) {
    fprintf(stderr, "usage: %s CLIP.pstream [--frames N] [--screenshot FILE.ppm]\n", argv[0]);
    return 2;
  }

  clips[0] = argv[1];
  pstream_player_options_init(&options);
  options.blocking = frames > 0; /* a fixed number of frames: wait for data, as offline rendering does */
  if (pstream_player_open(clips, 1, &options, &player) != PSTREAM_OK ||
      pstream_player_clip_info(player, 0, &info) != PSTREAM_OK) {
    fprintf(stderr, "%s\n", pstream_last_error());
    return 1;
  }
  for (i = 0; i < 3; ++i) center[i] = 0.5f * (info.bounds[i] + info.bounds[i + 3]);
  radius = 0.5f * sqrtf((info.bounds[3] - info.bounds[0]) * (info.bounds[3] - info.bounds[0]) +
                        (info.bounds[4] - info.bounds[1]) * (info.bounds[4] - info.bounds[1]) +
                        (info.bounds[5] - info.bounds[2]) * (info.bounds[5] - info.bounds[2]));
  if (!(radius > 0)) radius = 1;

  if (!glfwInit()) {
    fprintf(stderr, "GLFW could not start (no display?)\n");
    pstream_player_close(player);
    return 1;
  }
  window = glfwCreateWindow(width, height, "ParticleStream: view_clip", NULL, NULL);
  if (window == NULL) {
    fprintf(stderr, "no OpenGL window\n");
    glfwTerminate();
    pstream_player_close(player);
    return 1;
  }
  glfwMakeContextCurrent(window);
  glfwSwapInterval(frames > 0 ? 0 : 1);
  pstream_player_play(player);
  last = glfwGetTime();

  for (k = 0; !glfwWindowShouldClose(window) && (frames == 0 || k < frames); ++k) {
    pstream_frame frame;
    const double now = glfwGetTime();
    const double dt = frames > 0 ? (k == 0 ? 0.0 : 1.0 / 60) : now - last;
    last = now;
    glfwGetFramebufferSize(window, &width, &height);

    /* The camera: a three-quarter view of the clip's bounds, turning slowly. */
    glViewport(0, 0, width, height);
    glMatrixMode(GL_PROJECTION);
    glLoadIdentity();
    {
      const double n = 0.05 * radius, aspect = (double)width / (double)(height > 0 ? height : 1);
      glFrustum(-n * 0.5 * aspect, n * 0.5 * aspect, -n * 0.5, n * 0.5, n, 10.0 * radius);
    }
    glMatrixMode(GL_MODELVIEW);
    glLoadIdentity();
    glTranslatef(0, 0, -2.6f * radius);
    glRotatef(20, 1, 0, 0);
    glRotatef(-35 + 6 * (float)(k / 60.0), 0, 1, 0);
    glTranslatef(-center[0], -center[1], -center[2]);
    glGetFloatv(GL_MODELVIEW_MATRIX, view); /* world -> view: the player sorts for it */

    if (pstream_player_update(player, dt, view) != PSTREAM_OK || pstream_player_check(player) != PSTREAM_OK ||
        pstream_player_frame(player, 0, &frame) != PSTREAM_OK) {
      fprintf(stderr, "%s\n", pstream_last_error());
      status = 1;
      break;
    }

    glClearColor(0.05f, 0.06f, 0.08f, 1);
    glClear(GL_COLOR_BUFFER_BIT);
    glEnable(GL_BLEND);
    glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
    glPointSize(3);
    if (frame.count > 0) {
      const char* records = (const char*)frame.records;
      glEnableClientState(GL_VERTEX_ARRAY);
      glVertexPointer(3, GL_FLOAT, (GLsizei)frame.record_size, records); /* position: float x3 at 0 */
      if (frame.color_offset >= 0) {
        glEnableClientState(GL_COLOR_ARRAY);
        glColorPointer(4, GL_UNSIGNED_BYTE, (GLsizei)frame.record_size, records + frame.color_offset);
      } else {
        glColor4f(0.45f, 0.7f, 1.0f, 0.9f);
      }
      if (frame.order != NULL) { /* back to front */
        glDrawElements(GL_POINTS, (GLsizei)frame.count, GL_UNSIGNED_INT, frame.order);
      } else {
        glDrawArrays(GL_POINTS, 0, (GLsizei)frame.count);
      }
      glDisableClientState(GL_COLOR_ARRAY);
      glDisableClientState(GL_VERTEX_ARRAY);
    }
    if (screenshot != NULL && frames > 0 && k == frames - 1 && !save_ppm(screenshot, width, height)) {
      fprintf(stderr, "%s: could not write the screenshot\n", screenshot);
      status = 1;
    }
    glfwSwapBuffers(window);
    glfwPollEvents();
    if (glfwGetKey(window, GLFW_KEY_ESCAPE) == GLFW_PRESS) glfwSetWindowShouldClose(window, 1);
  }
  if (frames > 0 && status == 0) printf("played %d host frames\n", k);

  glfwDestroyWindow(window);
  glfwTerminate();
  pstream_player_close(player);
  return status;
}
