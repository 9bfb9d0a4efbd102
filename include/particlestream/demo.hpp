// A small offline particle simulator, so a newcomer can run the whole pipeline without a
// Houdini or RealFlow licence: its frames go through exactly the path a studio cache would.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace pstream::demo {

struct SimulationOptions {
  std::string preset = "fountain";   // fountain, explosion, smoke
  std::uint64_t particles = 250000;  // about the peak count
  double seconds = 10.0, fps = 30.0;
  std::uint64_t seed = 1;
  unsigned threads = 0;  // 0: one per core
};

// The particles alive after a step, in birth order (ids increase; dead ones are removed).
struct ParticleState {
  std::vector<float> position;  // 3 per particle
  std::vector<float> velocity;  // 3 per particle
  std::vector<float> width;     // a diameter
  std::vector<float> color;     // RGBA per particle (alpha fades for smoke)
  std::vector<float> age;       // seconds
  std::vector<std::uint64_t> id;
  std::size_t size() const { return id.size(); }
};

class Simulator {
 public:
  explicit Simulator(SimulationOptions options);  // throws pstream::Error for an unknown preset
  void step();                                    // one frame: births, forces, integration, ground, deaths
  const ParticleState& state() const { return state_; }
  std::uint64_t frame() const { return frame_; }
  double time() const { return double(frame_) / options_.fps; }
  std::uint64_t frame_count() const { return static_cast<std::uint64_t>(options_.seconds * options_.fps + 0.5); }
  static std::vector<std::string> presets();
  // The moment that shows a preset best (seconds): the fountain's arcs over its pool, the
  // explosion's glowing burst, the smoke's risen plume. Throws pstream::Error for an unknown one.
  static double showcase_seconds(const std::string& preset);

 private:
  SimulationOptions options_;
  ParticleState state_;
  std::vector<float> life_;  // lifetime per particle
  std::uint64_t frame_ = 0, next_id_ = 0;
  double birth_debt_ = 0.0;
  unsigned threads_ = 1;
};

}  // namespace pstream::demo
