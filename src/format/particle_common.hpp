// What the particle codec's encoder (particle_encoder.cpp) and decoder (particle_decoder.cpp)
// share: the packet's constants, the word plan, byte planes and the parsed body. The decoder
// builds without the encoder (docs/format.md, "The particle codec").
#pragma once

#include <algorithm>
#include <bit>
#include <cfloat>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <tuple>

#include <fmt/format.h>

#include "particlestream/codec.hpp"

namespace pstream::format::particle {

constexpr std::int64_t kGridLimit = (1 << 24) - 1;  // |q| below this converts to float exactly
constexpr std::size_t kBodyHeader = 16;             // count, prev_count, op_count, new_count
constexpr std::size_t kWordHeader = 8;              // predictor, keep/new/motion/bias bytes, reserved
constexpr std::uint32_t kBlockShift = 10;           // survivors share a bias per block of 1024
constexpr std::uint32_t kBlock = 1u << kBlockShift;
constexpr std::size_t kIdHeader = 4;
constexpr std::size_t kOpSize = 12;
constexpr std::uint32_t kTile = 256;  // particles written out at a time
// Version 4: a packet that begins with zstd's frame magic number starts a zstd frame (every
// keyframe's does); any other continues the frame of the packet before. Windows are at most 2^20
// bytes (the decoder's fixed buffer); each packet ends at a block boundary.
constexpr int kStreamWindowLog = 20;
constexpr std::uint32_t kFirstStreamedVersion = 4;
constexpr std::uint32_t kZstdMagic = 0xFD2FB528;  // little-endian in the packet's first 4 bytes

enum Predictor : std::uint8_t { kPrevious = 0, kLinear = 1 };

inline std::uint32_t zigzag(std::uint32_t v) { return (v << 1) ^ (0u - (v >> 31)); }
inline std::uint32_t unzigzag(std::uint32_t u) { return (u >> 1) ^ (0u - (u & 1u)); }
inline std::uint64_t zigzag64(std::uint64_t v) { return (v << 1) ^ (0ull - (v >> 63)); }
inline std::uint64_t unzigzag64(std::uint64_t u) { return (u >> 1) ^ (0ull - (u & 1ull)); }

template <class T>
inline unsigned bytes_for(T largest) {
  unsigned n = 0;
  while (largest != 0) {
    largest >>= 8;
    ++n;
  }
  return n;
}

// The decoded float of a grid value: two IEEE operations, each rounded once, the same on every
// machine (this file is built with -ffp-contract=off, so no fused multiply-add).
inline float dequantize(std::uint32_t q, float step, float origin) {
  const float scaled = static_cast<float>(static_cast<std::int32_t>(q)) * step;
  return scaled + origin;
}

inline float as_float(std::uint32_t bits) { return std::bit_cast<float>(bits); }

struct Op {
  std::uint32_t keep = 0, drop = 0, insert = 0;
};

// Value t of `bytes` byte planes `stride` values apart: byte b of the value at planes[b * stride + t].
template <class T = std::uint32_t>
inline T plane_value(const std::uint8_t* planes, std::size_t stride, std::size_t t, unsigned bytes) {
  T v = 0;
  for (unsigned b = 0; b < bytes; ++b) v |= T(planes[b * stride + t]) << (8 * b);
  return v;
}

// Survivors of one run: q = q1 + (d1 if linear) + bias + residual, and the step taken. The
// residuals are read straight from their `Bytes` byte planes.
template <unsigned Bytes>
inline void predict_run(std::uint32_t* __restrict q0, std::uint32_t* __restrict d0, const std::uint32_t* __restrict q1,
                        const std::uint32_t* __restrict d1, const std::uint8_t* __restrict planes, std::size_t stride,
                        std::uint32_t n, std::uint32_t linear_mask, std::uint32_t bias) {
  for (std::uint32_t t = 0; t < n; ++t) {
    const std::uint32_t step = (d1[t] & linear_mask) + bias + unzigzag(plane_value(planes, stride, t, Bytes));
    q0[t] = q1[t] + step;
    d0[t] = step;
  }
}
using PredictRun = void (*)(std::uint32_t*, std::uint32_t*, const std::uint32_t*, const std::uint32_t*,
                            const std::uint8_t*, std::size_t, std::uint32_t, std::uint32_t, std::uint32_t);
constexpr PredictRun kPredictRun[5] = {predict_run<0>, predict_run<1>, predict_run<2>, predict_run<3>, predict_run<4>};

// The coded words of a layout (quantised or exact), where the id's two words are, and the derived
// words with the coded word (index into `coded`) each is derived from.
struct WordPlan {
  std::vector<std::uint32_t> coded;  // record word indices
  std::int64_t id_word = -1;         // first of the id's two words, or -1
  std::uint32_t words = 0;
  struct Derived {
    std::uint32_t word = 0, from = 0;  // record word; index into `coded`
  };
  std::vector<Derived> derived;
  explicit WordPlan(const CodecInfo& info) : words(static_cast<std::uint32_t>(info.words.size())) {
    for (std::uint32_t w = 0; w < words; ++w) {
      const WordCoding c = info.words[w].coding;
      const WordCodingType* type = find_word_coding(c);
      if (type != nullptr && type->stored) coded.push_back(w);
      if (c == WordCoding::Id && id_word < 0) id_word = w;
    }
    for (std::uint32_t w = 0; w < words; ++w) {
      if (info.words[w].coding != WordCoding::Derived) continue;
      const auto k = std::find(coded.begin(), coded.end(), info.words[w].base);
      if (k != coded.end()) derived.push_back({w, static_cast<std::uint32_t>(k - coded.begin())});
    }
  }
};

// What a particle's decoder state says about its derived velocity (WordCoding::Derived): which of
// its last two steps d0, d1 are steps between decoded positions, and which a seed (a new
// particle's source velocity over one frame, in grid steps).
enum StepState : std::uint8_t {
  kNoStep = 0,     // nothing known: 0
  kOneStep = 1,    // d0: first order, 2·d0
  kTwoSteps = 2,   // d0 and d1: second order backward, 3·d0 − d1
  kSeeded = 3,     // d0 is the seed: 2·d0
  kAfterSeed = 4,  // d0 after the seed d1: the parabola through both, 4·d0 − 2·d1
};
// The state of a particle that survives into the next frame.
inline std::uint8_t after_step(std::uint8_t s) {
  return s == kNoStep ? kOneStep : s == kSeeded ? kAfterSeed : kTwoSteps;
}
inline bool has_step(std::uint8_t s) { return s == kOneStep || s == kTwoSteps || s == kAfterSeed; }
// The derived value: twice the velocity in grid steps per frame, times the word's step (the
// position step × fps / 2).
inline float derived_value(std::uint32_t d0, std::uint32_t d1, std::uint8_t state, float step) {
  const auto s0 = static_cast<std::int64_t>(static_cast<std::int32_t>(d0));
  const auto s1 = static_cast<std::int64_t>(static_cast<std::int32_t>(d1));
  const std::int64_t s = state == kTwoSteps                      ? 3 * s0 - s1
                         : state == kAfterSeed                   ? 4 * s0 - 2 * s1
                         : state == kOneStep || state == kSeeded ? 2 * s0
                                                                 : 0;
  return static_cast<float>(s) * step;
}

// derived_value() for the steps of a valid clip, |d0| and |d1| below 2^27 (grid values are
// below 2^24): the numerator fits 32 bits, so this is the same integer and the same float, in
// operations that vectorise. derive_run() checks the bound and takes derived_value() otherwise.
inline float derived_value_small(std::uint32_t d0, std::uint32_t d1, std::uint8_t state, float step) {
  const std::uint32_t two = d0 + d0;  // each case as a mask, so that the loop has no branch
  const std::uint32_t s = ((two + d0 - d1) & (0u - std::uint32_t(state == kTwoSteps))) |
                          ((two + two - d1 - d1) & (0u - std::uint32_t(state == kAfterSeed))) |
                          (two & (0u - std::uint32_t(state == kOneStep || state == kSeeded)));
  return static_cast<float>(static_cast<std::int32_t>(s)) * step;
}
constexpr std::uint32_t kSmallStep = 1u << 27;

// The derived values of n particles: out[t] from their steps d0[t] (this frame), d1[t] (the one
// before) and state[t].
inline void derive_run(std::uint32_t* __restrict out, const std::uint32_t* __restrict d0,
                       const std::uint32_t* __restrict d1, const std::uint8_t* __restrict state, std::uint32_t n,
                       float step) {
  std::uint32_t large = 0;
  for (std::uint32_t t = 0; t < n; ++t) large |= ((d0[t] + kSmallStep) | (d1[t] + kSmallStep)) & ~(2 * kSmallStep - 1);
  if (large == 0) {
    for (std::uint32_t t = 0; t < n; ++t)
      out[t] = std::bit_cast<std::uint32_t>(derived_value_small(d0[t], d1[t], state[t], step));
  } else {
    for (std::uint32_t t = 0; t < n; ++t)
      out[t] = std::bit_cast<std::uint32_t>(derived_value(d0[t], d1[t], state[t], step));
  }
}

inline std::uint64_t body_capacity(std::uint64_t max_count, std::size_t coded, bool ids) {
  // Header, at most prev + count ops (each moves at least one particle), keep + new + motion
  // planes of up to 4 bytes per word, up to 8 id bytes per new particle.
  return kBodyHeader + coded * kWordHeader + kIdHeader + kOpSize * (2 * max_count + 1) +
         coded * 4 * (2 * max_count + (max_count + kBlock - 1) / kBlock) + (ids ? 8 * max_count : 0);
}

// Byte planes: value t's byte b lives at planes[b * n + t].
inline void write_planes(std::vector<std::byte>& out, std::span<const std::uint32_t> values, unsigned bytes) {
  const std::size_t n = values.size(), at = out.size();
  out.resize(at + n * bytes);
  for (unsigned b = 0; b < bytes; ++b) {
    std::byte* plane = out.data() + at + b * n;
    for (std::size_t t = 0; t < n; ++t) plane[t] = static_cast<std::byte>(values[t] >> (8 * b));
  }
}

inline void read_planes(const std::byte* planes, std::size_t n, unsigned bytes, std::uint32_t* out) {
  if (bytes == 0) {
    std::fill_n(out, n, 0u);
    return;
  }
  const auto* p = reinterpret_cast<const std::uint8_t*>(planes);
  for (std::size_t t = 0; t < n; ++t) out[t] = p[t];
  for (unsigned b = 1; b < bytes; ++b) {
    const std::uint8_t* plane = p + b * n;
    const unsigned shift = 8 * b;
    for (std::size_t t = 0; t < n; ++t) out[t] |= std::uint32_t(plane[t]) << shift;
  }
}

template <class T>
inline void put(std::vector<std::byte>& out, T v) {
  const std::size_t at = out.size();
  out.resize(at + sizeof(T));
  std::memcpy(out.data() + at, &v, sizeof(T));
}

// Parsed, validated view of a packet body.
struct Body {
  std::uint32_t count = 0, prev_count = 0, op_count = 0, new_count = 0, keep_total = 0;
  bool keyframe = false;
  struct Word {
    std::uint8_t predictor = 0, keep_bytes = 0, new_bytes = 0, motion_bytes = 0, bias_bytes = 0, prior_bytes = 0;
    const std::byte *bias = nullptr, *keep = nullptr, *fresh = nullptr, *motion = nullptr, *prior = nullptr;
  };
  std::span<Word> words;
  unsigned id_bytes = 0;
  const std::byte* ops = nullptr;
  const std::byte* ids = nullptr;
};

}  // namespace pstream::format::particle
