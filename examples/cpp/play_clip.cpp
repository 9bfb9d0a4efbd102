// The C example (examples/c/play_clip.c) on the C++ API (particlestream.hpp): open a .pstream,
// play it at 60 Hz for its length, and print each host frame's particle count and the mean
// position of what it would draw. Same output as the C example, line for line.
//
//   cmake -S examples/cpp -B build-example -DCMAKE_PREFIX_PATH=/usr/local && cmake --build build-example
//   ./build-example/play_clip_cpp splash.pstream
// or, with pkg-config (the installed .pc carries an rpath, so it runs as built):
//   c++ -std=c++20 play_clip.cpp $(pkg-config --cflags --libs particlestream) -o play_clip_cpp
//   ./play_clip_cpp splash.pstream
#include <cstdio>
#include <exception>

#include <particlestream/particlestream.hpp>

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s CLIP.pstream\n", argv[0]);
    return 2;
  }
  if (!particlestream::compatible()) {
    std::fprintf(stderr, "libparticlestream %u does not match this header (%d)\n", particlestream::version(),
                 PSTREAM_VERSION);
    return 1;
  }
  try {
    particlestream::PlayerOptions options;
    options.blocking = true;  // every frame, not a real-time clock
    options.loop = false;
    particlestream::Player player({argv[1]}, options);
    const particlestream::ClipInfo info = player.clip_info(0);
    player.play();
    const int frames = static_cast<int>((info.end_time - info.start_time) * 60.0) + 1;
    for (int k = 0; k < frames; ++k) {
      player.update(k == 0 ? 0.0 : 1.0 / 60);
      player.check_clips();
      const particlestream::Frame frame = player.frame(0);
      double mean[3] = {0, 0, 0};
      for (std::uint64_t i = 0; i < frame.count(); ++i) {
        const auto p = frame.position(i);
        for (int c = 0; c < 3; ++c) mean[c] += p[c];
      }
      if (frame.count() > 0)
        for (double& m : mean) m /= static_cast<double>(frame.count());
      std::printf("%d %.4f %llu %.5f %.5f %.5f\n", k, frame.time(), static_cast<unsigned long long>(frame.count()),
                  mean[0], mean[1], mean[2]);
    }
  } catch (const particlestream::Error& e) {
    std::fprintf(stderr, "%s (%s)\n", e.what(), pstream_result_name(e.code()));
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
  }
  return 0;
}
