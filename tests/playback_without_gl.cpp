// The playback library by itself: a program that opens a clip, plays it and takes the frame's
// draw data, linked against pstream_playback alone — no renderer, no OpenGL, EGL or GLFW, and no
// encoder (CTest also checks the executable needs none of those libraries and holds none of the
// encoder's symbols). What an engine with its own renderer links.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <vector>

#include "particlestream/playback.hpp"

// Each file given is played on its own: format versions 1, 2 and 3, the records codec and the
// particle codec (whose decoder is all of the codec this program links).
int main(int argc, char** argv) {
  using namespace pstream;
  if (argc < 2) return 2;
  bool all = true;
  for (int a = 1; a < argc; ++a) {
    const std::vector<std::filesystem::path> files{argv[a]};
    playback::PlayerOptions options;
    options.stream.blocking = true;
    const auto player = playback::Player::open(files, std::move(options));
    const render::Camera camera = playback::framing_camera(files, 16.0f / 9.0f);
    player->play();
    std::uint64_t particles = 0;
    for (int k = 0; k < 10; ++k)
      particles += player->advance(1.0 / 60, camera.view(), sort::SortMode::BackToFront).particles;
    const render::DrawData& frame = player->draw_data(playback::DrawStyle{});
    const bool ok = particles > 0 && frame.batches.size() == 1 && frame.batches[0].count > 0 &&
                    frame.batches[0].order.size() == frame.batches[0].count && std::isfinite(frame.sprites.bounds[0]) &&
                    frame.sprites.bounds[0] < frame.sprites.bounds[3];
    std::printf("%s (format version %u): %llu particles in 10 frames, %zu batch(es), light bounds x %g..%g: %s\n",
                argv[a], player->clip(0).metadata().version, static_cast<unsigned long long>(particles),
                frame.batches.size(), frame.sprites.bounds[0], frame.sprites.bounds[3], ok ? "ok" : "FAILED");
    all = all && ok;
  }
  return all ? 0 : 1;
}
