// A DCC exporter's loop on the C++ API (particlestream.hpp): a simulation evaluated frame by frame
// (here a small fountain computed in place), each frame handed to a Spool as soon as it exists,
// then cooked into a .pstream with the particle codec. The spool keeps the frames on disk, so
// the exporter's memory stays one frame's however long the simulation runs. Prints the cook's
// report and reads the clip back.
//
//   cmake -S examples/cpp -B build-example -DCMAKE_PREFIX_PATH=/usr/local && cmake --build build-example
//   ./build-example/export_sim fountain.pstream
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <string>
#include <vector>

#include <particlestream/particlestream.hpp>

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s OUT.pstream\n", argv[0]);
    return 2;
  }
  const std::string output = argv[1];
  constexpr int kFrames = 48, kPerFrame = 50;  // 50 particles born a frame, each living 24 frames
  constexpr double kFps = 24.0;
  try {
    // The temporary lives beside the clip (empty: $TMPDIR, else /tmp).
    const auto slash = output.find_last_of('/');
    particlestream::Spool spool(slash == std::string::npos ? "." : output.substr(0, slash), "fountain example");
    std::vector<float> position, width, age;
    std::vector<std::uint64_t> id;
    for (int f = 0; f < kFrames; ++f) {
      position.clear(), width.clear(), age.clear(), id.clear();
      for (int born = std::max(0, f - 23); born <= f; ++born) {
        for (int k = 0; k < kPerFrame; ++k) {
          const double t = (f - born) / kFps, angle = k * 2.399963;  // golden-angle spray
          const double out = 0.4 + 0.2 * std::sin(k * 0.7);
          position.insert(position.end(), {float(out * std::cos(angle) * t), float(3.0 * t - 4.9 * t * t),
                                           float(out * std::sin(angle) * t)});
          width.push_back(0.02f);
          age.push_back(float(t));
          id.push_back(std::uint64_t(born) * kPerFrame + std::uint64_t(k));  // stable: what the codec matches
        }
      }
      particlestream::SpoolFrame frame;
      frame.time = (f + 1) / kFps;
      frame.count = id.size();
      frame.position = position.data();
      frame.width = width.data();
      frame.id = id.data();
      frame.floats = {{"age", 1, age.data()}};
      spool.add(frame);  // the arrays are ours again
    }
    particlestream::CookOptions options;
    options.output = output;
    options.fps = kFps;
    options.attributes = "age";  // stored; the ids order the frames and give the velocity
    const pstream_cook_report report = spool.cook(options);
    std::printf("%llu frames, %llu particles, %llu bytes\n", static_cast<unsigned long long>(report.frames),
                static_cast<unsigned long long>(report.particles), static_cast<unsigned long long>(report.file_bytes));
    const particlestream::Clip clip(output);
    const particlestream::ClipInfo info = clip.info();
    std::printf("read back: %llu frames at %g fps, at most %llu particles a frame, %u bytes a record\n",
                static_cast<unsigned long long>(info.frame_count), info.fps,
                static_cast<unsigned long long>(info.max_count), info.record_size);
  } catch (const particlestream::Error& e) {
    std::fprintf(stderr, "%s (%s)\n", e.what(), pstream_result_name(e.code()));
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
  }
  return 0;
}
