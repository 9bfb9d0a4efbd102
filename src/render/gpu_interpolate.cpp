// GpuInterpolator: the playback layer's interpolation between two cached frames
// (playback/interpolate.hpp) as one compute dispatch, one thread per particle of the pair table.
// The same rules as the CPU kernel, word by word (frame.hpp: RecordLane): copied, linear, Hermite
// through the velocities (positions) and its derivative (velocities); colours blended per byte;
// a particle only in the earlier frame goes on along its velocity and shrinks out, one only in
// the later frame comes in and grows; without a matching the nearer frame is moved along its
// velocities. Coefficients come from the host in the CPU's double arithmetic; advection is done
// in double as on the CPU; sums are `precise` (no fused multiply-add).
#include <algorithm>
#include <string>

#include <epoxy/gl.h>
#include <fmt/format.h>

#include "gl_program.hpp"
#include "particlestream/render.hpp"

namespace pstream::render {
namespace {

constexpr std::uint32_t kThreads = 64;

// After the version and work-group size (interpolate_source()).
constexpr const char* kInterpolate = R"(
layout(std430, binding = 0) readonly buffer A { uint wa[]; };
layout(std430, binding = 1) readonly buffer B { uint wb[]; };
layout(std430, binding = 2) readonly buffer Pairs { uvec2 pairs[]; };
layout(std430, binding = 3) readonly buffer Lanes { uint lanes[]; };
layout(std430, binding = 4) writeonly buffer Out { uint wo[]; };
const uint kNone = 0xFFFFFFFFu;
uniform uint u_count;
uniform uint u_words;
uniform uint u_shift;         // velocity word - position word (0: no velocity)
uniform int u_velocity_word;  // -1: none
uniform int u_color_word;     // -1: none
uniform uint u_scale_word;
uniform bool u_hermite;
uniform bool u_nearer;
uniform float u_t;
uniform float u_la, u_lb;                    // linear: 1 - t, t
uniform float u_h00, u_h01, u_h10, u_h11;    // position: a, b, a's and b's velocity
uniform float u_d00, u_d01, u_d10, u_d11;    // velocity: a's and b's position, a's and b's velocity
uniform double u_dead_seconds, u_born_seconds;
uniform float u_dead_grow, u_born_grow;

float fa(uint w) { return uintBitsToFloat(wa[w]); }
float fb(uint w) { return uintBitsToFloat(wb[w]); }

void main() {
  uint i = gl_GlobalInvocationID.x;
  if (i >= u_count) return;
  uvec2 p = pairs[i];
  uint o = i * u_words;
  if (p.x != kNone && p.y != kNone) {
    uint ia = p.x * u_words, ib = p.y * u_words;
    for (uint w = 0u; w < u_words; ++w) {
      uint kind = lanes[w];
      if (!u_hermite && (kind == 2u || kind == 3u)) kind = 1u;
      if (kind == 0u) {
        wo[o + w] = wa[ia + w];
        continue;
      }
      precise float v;
      if (kind == 1u) {
        v = u_la * fa(ia + w) + u_lb * fb(ib + w);
      } else if (kind == 2u) {
        precise float s = u_h00 * fa(ia + w) + u_h01 * fb(ib + w);
        precise float q = u_h10 * fa(ia + w + u_shift) + u_h11 * fb(ib + w + u_shift);
        v = s + q;
      } else {
        precise float s = u_d10 * fa(ia + w) + u_d11 * fb(ib + w);
        precise float q = u_d00 * fa(ia + w - u_shift) + u_d01 * fb(ib + w - u_shift);
        v = s + q;
      }
      wo[o + w] = floatBitsToUint(v);
    }
    if (u_color_word >= 0) {
      uint ca = wa[ia + uint(u_color_word)], cb = wb[ib + uint(u_color_word)], c = 0u;
      for (uint k = 0u; k < 4u; ++k) {
        float x = float((ca >> (8u * k)) & 255u), y = float((cb >> (8u * k)) & 255u);
        precise float m = x + (y - x) * u_t + 0.5;
        c |= (uint(int(m)) & 255u) << (8u * k);
      }
      wo[o + uint(u_color_word)] = c;
    }
    return;
  }
  bool from_a = p.x != kNone;
  uint src = (from_a ? p.x : p.y) * u_words;
  for (uint w = 0u; w < u_words; ++w) wo[o + w] = from_a ? wa[src + w] : wb[src + w];
  if (u_nearer && u_velocity_word < 0) return;  // shown as it is
  double seconds = from_a ? u_dead_seconds : u_born_seconds;
  if (u_velocity_word >= 0) {
    for (uint c = 0u; c < 3u; ++c) {
      float pos = uintBitsToFloat(from_a ? wa[src + c] : wb[src + c]);
      float vel = uintBitsToFloat(from_a ? wa[src + uint(u_velocity_word) + c] : wb[src + uint(u_velocity_word) + c]);
      precise double moved = double(pos) + seconds * double(vel);
      wo[o + c] = floatBitsToUint(float(moved));
    }
  }
  precise float scale = uintBitsToFloat(from_a ? wa[src + u_scale_word] : wb[src + u_scale_word]) *
                        (from_a ? u_dead_grow : u_born_grow);
  wo[o + u_scale_word] = floatBitsToUint(scale);
}
)";

std::string interpolate_source() {
  return fmt::format("#version 430\nlayout(local_size_x = {}) in;\n", kThreads) + kInterpolate;
}

}  // namespace

struct GpuInterpolator::Impl {
  std::uint32_t words = 0, shift = 0;
  std::int32_t velocity_word = -1, color_word = -1;
  GLuint lanes = 0, program = 0;
  ~Impl() {
    glDeleteBuffers(1, &lanes);
    glDeleteProgram(program);
  }
};

GpuInterpolator::GpuInterpolator(std::span<const RecordLane> lanes, std::int32_t velocity_offset,
                                 std::int32_t color_offset)
    : impl_(std::make_unique<Impl>()) {
  Impl& d = *impl_;
  d.words = static_cast<std::uint32_t>(lanes.size());
  if (d.words < kRecordHeadSize / 4) throw Error("GpuInterpolator: a record has at least the record head");
  d.velocity_word = velocity_offset >= 0 ? velocity_offset / 4 : -1;
  d.color_word = color_offset >= 0 ? color_offset / 4 : -1;
  d.shift = d.velocity_word >= 0 ? std::uint32_t(d.velocity_word) - kPositionOffset / 4 : 0;
  std::vector<std::uint32_t> kinds(lanes.size());
  std::transform(lanes.begin(), lanes.end(), kinds.begin(), [](RecordLane l) { return std::uint32_t(l); });
  glCreateBuffers(1, &d.lanes);
  glNamedBufferStorage(d.lanes, GLsizeiptr(kinds.size() * 4), kinds.data(), 0);
  d.program = detail::link_compute_program(interpolate_source().c_str());
}

GpuInterpolator::~GpuInterpolator() = default;

void GpuInterpolator::run(std::uint32_t a, std::uint32_t b, std::uint32_t pairs, std::uint32_t count, double t,
                          double dt, bool hermite, bool nearer, std::uint32_t out, std::uint64_t out_offset) {
  const Impl& d = *impl_;
  if (count == 0) return;
  const GLuint p = d.program;
  const auto u = [&](const char* name) { return glGetUniformLocation(p, name); };
  glUseProgram(p);
  glUniform1ui(u("u_count"), count);
  glUniform1ui(u("u_words"), d.words);
  glUniform1ui(u("u_shift"), d.shift);
  glUniform1i(u("u_velocity_word"), d.velocity_word);
  glUniform1i(u("u_color_word"), d.color_word);
  glUniform1ui(u("u_scale_word"), kScaleOffset / 4);
  glUniform1i(u("u_hermite"), hermite && d.velocity_word >= 0 ? 1 : 0);
  glUniform1i(u("u_nearer"), nearer ? 1 : 0);
  glUniform1f(u("u_t"), float(t));
  // The coefficients as the CPU kernel makes them (playback/interpolate.cpp: set_fraction).
  const double t2 = t * t, t3 = t2 * t;
  glUniform1f(u("u_la"), float(1.0 - t));
  glUniform1f(u("u_lb"), float(t));
  glUniform1f(u("u_h00"), float(2 * t3 - 3 * t2 + 1));
  glUniform1f(u("u_h01"), float(-2 * t3 + 3 * t2));
  glUniform1f(u("u_h10"), float((t3 - 2 * t2 + t) * dt));
  glUniform1f(u("u_h11"), float((t3 - t2) * dt));
  glUniform1f(u("u_d00"), float((6 * t2 - 6 * t) / dt));
  glUniform1f(u("u_d01"), float((6 * t - 6 * t2) / dt));
  glUniform1f(u("u_d10"), float(3 * t2 - 4 * t + 1));
  glUniform1f(u("u_d11"), float(3 * t2 - 2 * t));
  // Nearer frame: moved to the playhead from whichever frame it is, not shrunk.
  glUniform1d(u("u_dead_seconds"), t * dt);
  glUniform1d(u("u_born_seconds"), -(1.0 - t) * dt);
  glUniform1f(u("u_dead_grow"), nearer ? 1.0f : float(1.0 - t));
  glUniform1f(u("u_born_grow"), nearer ? 1.0f : float(t));
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, a);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, b);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, pairs);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, d.lanes);
  glBindBufferRange(GL_SHADER_STORAGE_BUFFER, 4, out, GLintptr(out_offset),
                    GLsizeiptr(std::uint64_t(count) * d.words * 4));
  glDispatchCompute((count + kThreads - 1) / kThreads, 1, 1);
  glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
  glUseProgram(0);
}

std::vector<std::byte> GpuInterpolator::run_host(std::span<const std::byte> a, std::span<const std::byte> b,
                                                 std::span<const ParticlePair> pairs, double t, double dt, bool hermite,
                                                 bool nearer) {
  const std::size_t stride = std::size_t(impl_->words) * 4;
  std::vector<std::byte> out(pairs.size() * stride);
  if (pairs.empty()) return out;
  GLuint buffers[4] = {};
  glCreateBuffers(4, buffers);
  const std::byte zero[4] = {};
  const auto upload = [&](GLuint buffer, std::span<const std::byte> bytes) {
    glNamedBufferStorage(buffer, GLsizeiptr(std::max<std::size_t>(bytes.size(), 4)),
                         bytes.empty() ? zero : bytes.data(), 0);
  };
  upload(buffers[0], a);
  upload(buffers[1], b);
  upload(buffers[2], std::as_bytes(pairs));
  glNamedBufferStorage(buffers[3], GLsizeiptr(out.size()), nullptr, 0);
  run(buffers[0], buffers[1], buffers[2], std::uint32_t(pairs.size()), t, dt, hermite, nearer, buffers[3]);
  glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
  glGetNamedBufferSubData(buffers[3], 0, GLsizeiptr(out.size()), out.data());
  glDeleteBuffers(4, buffers);
  return out;
}

}  // namespace pstream::render
