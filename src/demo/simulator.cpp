#include <algorithm>
#include <cmath>
#include <numbers>
#include <thread>

#include <fmt/format.h>

#include "particlestream/demo.hpp"
#include "particlestream/error.hpp"

namespace pstream::demo {
namespace {

// A counter-based random number: the same particle gets the same numbers whatever the threads.
std::uint64_t mix(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}
float random01(std::uint64_t seed, std::uint64_t id, std::uint64_t k) {
  return float(mix(seed ^ mix(id * 16 + k)) >> 40) / float(1ull << 24);
}

struct PresetData {
  const char* name;
  float life_min, life_max;
  float gravity, drag, buoyancy;
  float wind[3];
  float turbulence, turbulence_scale;
  float bounce, friction;
  float color_start[4], color_end[4];
  float width_start, width_end;
  bool burst;      // explosion: most particles are born in the first moments
  float showcase;  // seconds: the moment that shows the effect best (the demo's contact sheet)
};

constexpr PresetData kPresets[] = {
    {"fountain",
     2.4f,
     3.6f,
     9.81f,
     0.15f,
     0.0f,
     {0.6f, 0, 0.15f},
     0.8f,
     1.3f,
     0.35f,
     0.25f,
     {0.75f, 0.9f, 1.0f, 0.9f},
     {0.1f, 0.35f, 0.95f, 0.6f},
     0.07f,
     0.04f,
     false,
     5.0f},
    {"explosion",
     1.5f,
     3.5f,
     4.0f,
     1.1f,
     0.0f,
     {0.3f, 0, 0},
     1.5f,
     0.9f,
     0.25f,
     0.4f,
     {1.0f, 0.85f, 0.35f, 1.0f},
     {0.35f, 0.08f, 0.05f, 0.5f},
     0.05f,
     0.03f,
     true,
     0.4f},
    {"smoke",
     4.0f,
     7.0f,
     0.0f,
     0.6f,
     1.2f,
     {0.5f, 0, 0.1f},
     1.1f,
     0.7f,
     0.0f,
     0.0f,
     {0.55f, 0.55f, 0.58f, 0.35f},
     {0.25f, 0.25f, 0.28f, 0.0f},
     0.08f,
     0.55f,
     false,
     3.0f},
};

const PresetData& find_preset(const std::string& name) {
  for (const auto& p : kPresets) {
    if (name == p.name) return p;
  }
  throw Error(fmt::format("unknown preset '{}': choose fountain, explosion or smoke", name));
}

}  // namespace

double Simulator::showcase_seconds(const std::string& preset) { return find_preset(preset).showcase; }

std::vector<std::string> Simulator::presets() {
  std::vector<std::string> out;
  for (const auto& p : kPresets) out.emplace_back(p.name);
  return out;
}

Simulator::Simulator(SimulationOptions options) : options_(std::move(options)) {
  (void)find_preset(options_.preset);
  if (!(options_.fps > 0) || !(options_.seconds > 0))
    throw OptionError("seconds", "`seconds` and `fps` must be positive");
  threads_ = options_.threads ? options_.threads : std::max(1u, std::thread::hardware_concurrency());
}

void Simulator::step() {
  const PresetData& p = find_preset(options_.preset);
  const float dt = float(1.0 / options_.fps);
  const float t = float(time());
  ParticleState& s = state_;
  const std::uint64_t seed = options_.seed;

  // Births. A steady emitter holds about `particles` alive at once; a burst emits most of them
  // in the first 0.3 s and trickles embers after.
  const double mean_life = 0.5 * (p.life_min + p.life_max);
  double births = 0;
  if (p.burst) {
    births = t < 0.3 ? double(options_.particles) * 0.85 * dt / 0.3 : double(options_.particles) * 0.03 * dt;
  } else {
    births = double(options_.particles) / mean_life * dt;
  }
  birth_debt_ += births;
  const auto born = static_cast<std::uint64_t>(birth_debt_);
  birth_debt_ -= double(born);
  for (std::uint64_t b = 0; b < born; ++b) {
    const std::uint64_t id = next_id_++;
    const float r1 = random01(seed, id, 0), r2 = random01(seed, id, 1), r3 = random01(seed, id, 2),
                r4 = random01(seed, id, 3);
    const float angle = 2 * std::numbers::pi_v<float> * r1;
    float pos[3], vel[3];
    if (options_.preset == "fountain") {
      const float radius = 0.12f * std::sqrt(r2), spread = 0.9f + 0.5f * r3;
      pos[0] = radius * std::cos(angle), pos[1] = 0.05f, pos[2] = radius * std::sin(angle);
      vel[0] = spread * std::cos(angle), vel[1] = 7.0f + 1.5f * r4, vel[2] = spread * std::sin(angle);
    } else if (options_.preset == "explosion") {
      const float z = 2 * r2 - 1, rxy = std::sqrt(std::max(0.0f, 1 - z * z)), speed = 4.0f + 10.0f * r3 * r3;
      const float dir[3] = {rxy * std::cos(angle), std::abs(z) * 0.8f + 0.2f, rxy * std::sin(angle)};
      for (int c = 0; c < 3; ++c) pos[c] = dir[c] * 0.2f + (c == 1 ? 1.0f : 0.0f), vel[c] = dir[c] * speed;
    } else {  // smoke: a wide vent near the ground
      const float radius = 0.5f * std::sqrt(r2);
      pos[0] = radius * std::cos(angle), pos[1] = 0.05f, pos[2] = radius * std::sin(angle);
      vel[0] = 0.2f * (r3 - 0.5f), vel[1] = 0.6f + 0.5f * r4, vel[2] = 0.2f * (r1 - 0.5f);
    }
    s.position.insert(s.position.end(), pos, pos + 3);
    s.velocity.insert(s.velocity.end(), vel, vel + 3);
    s.width.push_back(p.width_start);
    s.color.insert(s.color.end(), p.color_start, p.color_start + 4);
    s.age.push_back(0.0f);
    s.id.push_back(id);
    life_.push_back(p.life_min + (p.life_max - p.life_min) * random01(seed, id, 4));
  }

  // Forces and integration, split across threads (each particle on its own: deterministic).
  const std::size_t n = s.size();
  const auto work = [&](std::size_t begin, std::size_t end) {
    const float damp = std::exp(-p.drag * dt);
    const float k = p.turbulence_scale;
    for (std::size_t i = begin; i < end; ++i) {
      float* x = &s.position[i * 3];
      float* v = &s.velocity[i * 3];
      // A divergence-free turbulence: each component varies only with the other two coordinates.
      const float turb[3] = {std::sin(k * x[1] + 1.3f * t) + std::cos(k * x[2] - 0.7f * t),
                             std::sin(k * x[2] + 0.9f * t) + std::cos(k * x[0] + 1.1f * t),
                             std::sin(k * x[0] - 1.2f * t) + std::cos(k * x[1] + 0.5f * t)};
      const float up = p.buoyancy - p.gravity;
      for (int c = 0; c < 3; ++c) {
        v[c] += (p.wind[c] + p.turbulence * turb[c] + (c == 1 ? up : 0.0f)) * dt;
        v[c] *= damp;
        x[c] += v[c] * dt;
      }
      if (x[1] < 0.0f && p.bounce > 0.0f) {  // the ground: bounce and friction
        x[1] = -x[1] * p.bounce;
        v[1] = -v[1] * p.bounce;
        v[0] *= 1 - p.friction;
        v[2] *= 1 - p.friction;
      } else if (x[1] < 0.0f) {
        x[1] = 0.0f;
        v[1] = std::max(v[1], 0.0f);
      }
      s.age[i] += dt;
      const float life = std::clamp(s.age[i] / life_[i], 0.0f, 1.0f);  // colour and size over life
      s.width[i] = p.width_start + (p.width_end - p.width_start) * life;
      for (int c = 0; c < 4; ++c) s.color[i * 4 + c] = p.color_start[c] + (p.color_end[c] - p.color_start[c]) * life;
    }
  };
  const std::size_t chunks = n < 20000 ? 1 : threads_;
  std::vector<std::thread> pool;
  for (std::size_t c = 1; c < chunks; ++c) pool.emplace_back(work, n * c / chunks, n * (c + 1) / chunks);
  work(0, n / chunks);
  for (auto& th : pool) th.join();

  // Deaths, keeping birth order.
  std::size_t kept = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (s.age[i] >= life_[i]) continue;
    if (kept != i) {
      std::copy_n(&s.position[i * 3], 3, &s.position[kept * 3]);
      std::copy_n(&s.velocity[i * 3], 3, &s.velocity[kept * 3]);
      std::copy_n(&s.color[i * 4], 4, &s.color[kept * 4]);
      s.width[kept] = s.width[i], s.age[kept] = s.age[i], s.id[kept] = s.id[i], life_[kept] = life_[i];
    }
    ++kept;
  }
  s.position.resize(kept * 3), s.velocity.resize(kept * 3), s.color.resize(kept * 4);
  s.width.resize(kept), s.age.resize(kept), s.id.resize(kept), life_.resize(kept);
  ++frame_;
}

}  // namespace pstream::demo
