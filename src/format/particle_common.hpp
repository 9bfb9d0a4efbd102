// What the particle codec's encoder (particle_encoder.cpp) and decoder (particle_decoder.cpp)
// share: the packet's constants, the word plan, byte planes and the parsed body. The decoder
// builds without the encoder (docs/format.md, "The particle codec").
#pragma once

#include <algorithm>
#include <array>
#include <bit>
#include <cfloat>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <span>
#include <tuple>
#include <type_traits>
#include <utility>

#include <fmt/format.h>

// SurvivorRuns::compact(), built for AVX2 on x86-64 outside the browser (the decoder picks it at
// run time); elsewhere the survivors are only walked run by run.
#if defined(__x86_64__) && !defined(__EMSCRIPTEN__)
#include <immintrin.h>
#define PSTREAM_COMPACT_SURVIVORS 1
#else
#define PSTREAM_COMPACT_SURVIVORS 0
#endif

#include "particlestream/codec.hpp"

namespace pstream::format::particle {

constexpr std::int64_t kGridLimit = (1 << 24) - 1;  // |q| below this converts to float exactly
constexpr std::size_t kBodyHeader = 16;             // count, prev_count, op_count, new_count
constexpr std::size_t kWordHeader = 8;              // predictor, keep/new/motion/bias bytes, reserved
constexpr std::uint32_t kBlockShift = 10;           // survivors share a bias per block of 1024
constexpr std::uint32_t kBlock = 1u << kBlockShift;
constexpr std::size_t kIdHeader = 4;
constexpr std::size_t kOpSize = 12;
// Version 4: a packet that begins with zstd's frame magic number starts a zstd frame (every
// keyframe's does); any other continues the frame of the packet before. Windows are at most 2^20
// bytes (the decoder's fixed buffer); each packet ends at a block boundary.
constexpr int kStreamWindowLog = 20;
constexpr std::uint32_t kFirstStreamedVersion = 4;
constexpr std::uint32_t kZstdMagic = 0xFD2FB528;  // little-endian in the packet's first 4 bytes
// Version 5: a word's survivors' residuals may be packed as nibbles (Packing::Nibbles): each
// below 15 in four bits, two a byte, and 15 an escape to 15 plus the next value of the escape
// planes. zstd then makes half the bytes and the encoder's optimal parser runs on half the input.
constexpr std::uint32_t kFirstNibbleVersion = 5;
constexpr std::uint32_t kNibbleEscape = 15;
// Version 6: a keyframe of a clip in id order may link its particles to the frame before with
// operations, as a predicted frame does: they decode nothing (every particle is still new) but
// give the matching across the keyframe, so that playback interpolates through it and an export
// keeps each particle's id there.
constexpr std::uint32_t kFirstKeyframeLinksVersion = 6;
enum Packing : std::uint8_t { kBytePlanes = 0, kNibbles = 1 };

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

// The least and the largest of values read as signed 32-bit numbers (grid values, residuals); `v`
// is not empty. The encoder's: its blocks' medians, its bounds and the matching's box.
inline std::pair<std::int32_t, std::int32_t> signed_extremes(std::span<const std::uint32_t> v) {
  std::int32_t lo = static_cast<std::int32_t>(v[0]), hi = lo;
  for (const std::uint32_t x : v) {
    lo = std::min(lo, static_cast<std::int32_t>(x));
    hi = std::max(hi, static_cast<std::int32_t>(x));
  }
  return {lo, hi};
}

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

// SurvivorRuns writes up to 7 values past a run (the state buffers carry this padding), and reads
// up to kReadPad bytes past a word's survivors' residuals (the body's buffer carries that).
constexpr std::uint32_t kRunPad = 7;
constexpr std::size_t kReadPad = 16;

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
// after_step() of n particles, 16 at a time, the last 16 whole: it reads and writes up to
// kStepPad bytes past the run (the state buffers carry them), which the next run or new particle
// overwrites. The runs between births and deaths are short, and a byte at a time this had taken
// 4 % of the default cook's decode on the sparks.
constexpr std::uint32_t kStepPad = 15;
inline void after_steps(std::uint8_t* __restrict out, const std::uint8_t* __restrict before, std::uint32_t n) {
  using B = std::uint8_t __attribute__((vector_size(16)));
  for (std::uint32_t t = 0; t < n; t += 16) {
    B s;
    std::memcpy(&s, before + t, 16);
    const B none = reinterpret_cast<B>(s == std::uint8_t{kNoStep});
    const B seeded = reinterpret_cast<B>(s == std::uint8_t{kSeeded});
    const B next = std::uint8_t{kTwoSteps} - (none & std::uint8_t{kTwoSteps - kOneStep}) +
                   (seeded & std::uint8_t{kAfterSeed - kTwoSteps});
    std::memcpy(out + t, &next, 16);
  }
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
[[gnu::always_inline]] inline void derive_run(std::uint32_t* __restrict out, const std::uint32_t* __restrict d0,
                                              const std::uint32_t* __restrict d1, const std::uint8_t* __restrict state,
                                              std::uint32_t n, float step) {
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

// Nibbles: value t in byte t / 2, the low four bits when t is even; the last byte's high nibble
// is 0 when n is odd. A value of 15 or more is the escape nibble, and its excess (value − 15) the
// next value of the escape planes that follow (write_planes, `escape_bytes` wide).
inline unsigned escape_bytes(std::span<const std::uint32_t> values) {
  std::uint32_t largest = 0;
  for (const std::uint32_t v : values) largest = std::max(largest, v >= kNibbleEscape ? v - kNibbleEscape : 0u);
  return bytes_for(largest);
}
inline void write_nibbles(std::vector<std::byte>& out, std::span<const std::uint32_t> values, unsigned escape_width) {
  const std::size_t n = values.size(), at = out.size();
  out.resize(at + (n + 1) / 2, std::byte{0});
  std::vector<std::uint32_t> escapes;
  for (std::size_t t = 0; t < n; ++t) {
    const std::uint32_t v = std::min(values[t], kNibbleEscape);
    if (v == kNibbleEscape) escapes.push_back(values[t] - kNibbleEscape);
    out[at + t / 2] |= static_cast<std::byte>(v << (4 * (t & 1)));
  }
  write_planes(out, escapes, escape_width);
}
// 64 bits of nibbles: one bit (the lowest of its nibble) for each escape nibble.
inline std::uint64_t escape_bits(std::uint64_t x) { return x & (x >> 1) & (x >> 2) & (x >> 3) & 0x1111111111111111ull; }
// The escapes among n nibbles (whose padding nibble, for odd n, is 0): 16 bytes at a time, each
// byte's escapes (0 to 2) summed in byte lanes for up to 127 steps, then the lanes added up.
inline std::uint64_t count_escapes(const std::uint8_t* packed, std::uint32_t n) {
  using U8 = std::uint8_t __attribute__((vector_size(16)));
  using U64 = std::uint64_t __attribute__((vector_size(16)));
  const std::size_t bytes = (std::size_t(n) + 1) / 2;
  std::uint64_t count = 0;
  std::size_t b = 0;
  while (b + 16 <= bytes) {
    U8 sum = {};
    for (int step = 0; step < 127 && b + 16 <= bytes; ++step, b += 16) {
      U8 v;
      std::memcpy(&v, packed + b, 16);
      sum -= reinterpret_cast<U8>((v & 15) == 15) + reinterpret_cast<U8>((v >> 4) == 15);  // -1 where true
    }
    const U64 wide = reinterpret_cast<U64>(sum);
    for (const std::uint64_t lanes : {wide[0], wide[1]}) {
      const std::uint64_t pairs = (lanes & 0x00FF00FF00FF00FFull) + ((lanes >> 8) & 0x00FF00FF00FF00FFull);
      count += (pairs * 0x0001000100010001ull) >> 48;
    }
  }
  for (; b < bytes; ++b) count += std::uint64_t((packed[b] & 15) == 15) + std::uint64_t((packed[b] >> 4) == 15);
  return count;
}
// The positions of the escapes among n nibbles, in order, 16 nibbles at a time (most have none).
class EscapeScan {
 public:
  static constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
  EscapeScan() = default;
  EscapeScan(const std::uint8_t* packed, std::uint32_t n) : packed_(packed), bytes_((std::size_t(n) + 1) / 2) {
    settle();
  }
  std::uint32_t next() const { return next_; }  // kNone when no escape is left
  void pop() {
    bits_ &= bits_ - 1;
    settle();
  }

 private:
  void settle() {
    while (bits_ == 0 && at_ + 8 <= bytes_) {
      std::uint64_t x;
      std::memcpy(&x, packed_ + at_, 8);
      bits_ = escape_bits(x);
      base_ = static_cast<std::uint32_t>(2 * at_);
      at_ += 8;
    }
    if (bits_ == 0 && at_ < bytes_) {  // the last bytes (the padding nibble is 0)
      std::uint64_t x = 0;
      std::memcpy(&x, packed_ + at_, bytes_ - at_);
      bits_ = escape_bits(x);
      base_ = static_cast<std::uint32_t>(2 * at_);
      at_ = bytes_;
    }
    next_ = bits_ == 0 ? kNone : base_ + static_cast<std::uint32_t>(std::countr_zero(bits_)) / 4;
  }
  const std::uint8_t* packed_ = nullptr;
  std::size_t bytes_ = 0, at_ = 0;
  std::uint64_t bits_ = 0;
  std::uint32_t base_ = 0, next_ = kNone;
};

// n values of `bytes` byte planes, unzigzagged (read_planes(), then one vector pass).
inline void read_values(const std::byte* planes, std::size_t n, unsigned bytes, std::uint32_t* out) {
  read_planes(planes, n, bytes, out);
  for (std::size_t t = 0; t < n; ++t) out[t] = unzigzag(out[t]);
}

// Whether the decoder predicts every frame whose survivors come first with SurvivorRuns::compact()
// where it can, not only frames past the word walk's size: in the fuzzing build (checksum.cpp,
// PSTREAM_FUZZING), so that the fuzz targets' small frames reach that loop too.
bool compact_every_frame();

#if PSTREAM_COMPACT_SURVIVORS
// For each of the 256 masks of eight lanes, the lanes it marks, lowest first, a byte each
// (SurvivorRuns::compact()).
constexpr auto kCompactLanes = [] {
  std::array<std::uint64_t, 256> lanes{};
  for (unsigned m = 0; m < 256; ++m) {
    unsigned at = 0;
    for (unsigned l = 0; l < 8; ++l)
      if (m >> l & 1) lanes[m] |= std::uint64_t(l) << (8 * at++);
  }
  return lanes;
}();
#endif

// The survivors of one word, predicted a run at a time straight from their residuals: survivor
// `at` of the frame's survivors (in order) is q = q1 + (d1 if linear) + r, and its step d = q - q1,
// where r is its residual unzigzagged plus the bias of its block of 1024. The residuals are `bytes`
// byte planes of n values or (packing kNibbles) n nibbles and their `escapes` escape values, `bytes`
// byte planes after them. Eight survivors at a time, the last eight whole: a run writes up to 7
// values past its end (kRunPad), which the next run or new particle overwrites, and reads up to
// kReadPad bytes past the residuals. The runs between births and deaths are short (33 survivors on
// the sparks, 15 on the FLIP pour): a scalar tail for each had taken 43 % of the loop, and the
// residuals made in a pass of their own, a block at a time, a third of its time. Where the
// survivors are the frame's first particles, compact() predicts them all in one pass over the
// previous particles instead, without the runs.
class SurvivorRuns {
 public:
  SurvivorRuns(const std::byte* keep, std::uint32_t n, std::uint8_t packing, unsigned bytes,
               const std::byte* escape_planes, std::uint32_t escapes, const std::uint32_t* bias)
      : keep_(reinterpret_cast<const std::uint8_t*>(keep)),
        escape_planes_(reinterpret_cast<const std::uint8_t*>(escape_planes)),
        bias_(bias),
        n_(n),
        escapes_(escapes),
        bytes_(bytes),
        nibbles_(packing == kNibbles) {
    if (nibbles_ && escapes_ != 0 && bytes_ != 0) scan_ = EscapeScan(keep_, n_);  // an escape of 0 is 15 itself
  }

  SurvivorRuns() = default;

#if PSTREAM_COMPACT_SURVIVORS
  // Every survivor in one pass over the previous particles (Reader::compact()), eight at a time,
  // for a caller built for AVX2.
  [[gnu::target("avx2"), gnu::always_inline]] void compact(unsigned kind, const std::uint8_t* alive, std::uint32_t prev,
                                                           std::uint32_t* q0, std::uint32_t* d0,
                                                           const std::uint32_t* q1, const std::uint32_t* d1,
                                                           std::uint32_t linear) {
    switch (kind) {
      case 0: return compact_as<false, 0>(alive, prev, q0, d0, q1, d1, linear);
      case 1: return compact_as<false, 1>(alive, prev, q0, d0, q1, d1, linear);
      case 2: return compact_as<false, 2>(alive, prev, q0, d0, q1, d1, linear);
      case 3: return compact_as<false, 3>(alive, prev, q0, d0, q1, d1, linear);
      case 4: return compact_as<false, 4>(alive, prev, q0, d0, q1, d1, linear);
      case 5: return compact_as<true, 0>(alive, prev, q0, d0, q1, d1, linear);
      case 6: return compact_as<true, 1>(alive, prev, q0, d0, q1, d1, linear);
      case 7: return compact_as<true, 2>(alive, prev, q0, d0, q1, d1, linear);
      case 8: return compact_as<true, 3>(alive, prev, q0, d0, q1, d1, linear);
      default: return compact_as<true, 4>(alive, prev, q0, d0, q1, d1, linear);
    }
  }
  template <bool Nibbles, unsigned Bytes>
  [[gnu::target("avx2"), gnu::always_inline]] void compact_as(const std::uint8_t* alive, std::uint32_t prev,
                                                              std::uint32_t* q0, std::uint32_t* d0,
                                                              const std::uint32_t* q1, const std::uint32_t* d1,
                                                              std::uint32_t linear) {
    if (linear != 0) return Reader<8, Nibbles, Bytes>{this}.template compact<true>(alive, prev, q0, d0, q1, d1);
    Reader<8, Nibbles, Bytes>{this}.template compact<false>(alive, prev, q0, d0, q1, d1);
  }
#endif

  // Which reader the residuals need: 0-4 for byte planes of that many bytes, 5-9 for nibbles with
  // escapes of kind - 5 bytes.
  unsigned kind() const { return (nibbles_ ? 5u : 0u) + std::min(bytes_, 4u); }

  // Predicts survivors [at, at + len), all in one block, the runs in order: q0/d0 from q1/d1 with
  // the steps masked by `linear` (0 or ~0). `kind` is kind(); `Lanes` the vector width in 32-bit
  // values, 4 (16-byte vectors: x86-64's baseline SSE2, WebAssembly's SIMD128) or 8 (32-byte,
  // for a caller built for AVX2). Everything here inlines into the caller, so the 8-lane code is
  // only ever compiled for one built for AVX2.
  template <unsigned Lanes>
  [[gnu::always_inline]] void run(unsigned kind, std::uint32_t at, std::uint32_t len, std::uint32_t* q0,
                                  std::uint32_t* d0, const std::uint32_t* q1, const std::uint32_t* d1,
                                  std::uint32_t linear) {
    switch (kind) {
      case 0: return Reader<Lanes, false, 0>{this}.run(at, len, q0, d0, q1, d1, linear);
      case 1: return Reader<Lanes, false, 1>{this}.run(at, len, q0, d0, q1, d1, linear);
      case 2: return Reader<Lanes, false, 2>{this}.run(at, len, q0, d0, q1, d1, linear);
      case 3: return Reader<Lanes, false, 3>{this}.run(at, len, q0, d0, q1, d1, linear);
      case 4: return Reader<Lanes, false, 4>{this}.run(at, len, q0, d0, q1, d1, linear);
      case 5: return Reader<Lanes, true, 0>{this}.run(at, len, q0, d0, q1, d1, linear);
      case 6: return Reader<Lanes, true, 1>{this}.run(at, len, q0, d0, q1, d1, linear);
      case 7: return Reader<Lanes, true, 2>{this}.run(at, len, q0, d0, q1, d1, linear);
      case 8: return Reader<Lanes, true, 3>{this}.run(at, len, q0, d0, q1, d1, linear);
      default: return Reader<Lanes, true, 4>{this}.run(at, len, q0, d0, q1, d1, linear);
    }
  }

 private:
  // 16-byte vectors for four lanes: with a wider type where the target has none, the widening
  // became scalar stores and a reload.
  using V = std::uint32_t __attribute__((vector_size(16)));
  using V8 = std::uint32_t __attribute__((vector_size(32)));
  using U16 = std::uint16_t __attribute__((vector_size(16)));
  using U8 = std::uint8_t __attribute__((vector_size(16)));
  using U64 = std::uint64_t __attribute__((vector_size(16)));

  // Eight bytes, the first lowest, widened to two vectors of four values.
  [[gnu::always_inline]] static void widen(U8 b, V& lo, V& hi) {
    const U8 zero8 = {};
    const U16 zero16 = {};
    const auto w = reinterpret_cast<U16>(
        __builtin_shufflevector(b, zero8, 0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23));
    lo = reinterpret_cast<V>(__builtin_shufflevector(w, zero16, 0, 8, 1, 9, 2, 10, 3, 11));
    hi = reinterpret_cast<V>(__builtin_shufflevector(w, zero16, 4, 12, 5, 13, 6, 14, 7, 15));
  }
  // The same as one vector of eight (GCC made a conversion of eight bytes into scalar moves).
  [[gnu::always_inline]] static void widen(U8 b, V8& all) {
    V lo, hi;
    widen(b, lo, hi);
    all = __builtin_shufflevector(lo, hi, 0, 1, 2, 3, 4, 5, 6, 7);
  }
  [[gnu::always_inline]] static U8 bytes8(std::uint64_t x) {
    const U64 v = {x, 0};
    return reinterpret_cast<U8>(v);
  }
  [[gnu::always_inline]] static std::uint64_t load8(const std::uint8_t* p) {
    std::uint64_t x;
    std::memcpy(&x, p, 8);
    return x;
  }
  // Eight nibbles from nibble `at` on, a nibble a byte: the low and high halves of four bytes,
  // interleaved.
  [[gnu::always_inline]] static U8 nibbles8(const std::uint8_t* packed, std::uint32_t at) {
    const U8 b = bytes8(load8(packed + at / 2) >> (4 * (at & 1)));
    return __builtin_shufflevector(b & 15, b >> 4, 0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
  }
  // Survivors t to t + Lanes - 1 of a run from their residuals u (zigzagged, before the bias).
  template <class W>
  [[gnu::always_inline]] static void predict(std::uint32_t* __restrict q0, std::uint32_t* __restrict d0,
                                             const std::uint32_t* __restrict q1, const std::uint32_t* __restrict d1,
                                             const W& u, std::uint32_t add, std::uint32_t linear) {
    const W r = ((u >> 1) ^ (0u - (u & 1u))) + add;  // unzigzag(), lane by lane
    W q, d;
    std::memcpy(&q, q1, sizeof(W));
    std::memcpy(&d, d1, sizeof(W));
    const W step = (d & linear) + r;
    q += step;
    std::memcpy(q0, &q, sizeof(W));
    std::memcpy(d0, &step, sizeof(W));
  }

  // Nibbles with escapes `Bytes` wide, or `Bytes` byte planes, `Lanes` survivors a vector.
  template <unsigned Lanes, bool Nibbles, unsigned Bytes>
  struct Reader {
    SurvivorRuns* s;
    using W = std::conditional_t<Lanes == 4, V, V8>;
    // The residuals of survivors at to at + 7 (zigzagged, before the bias): all eight in `lo` for
    // eight lanes, else the first four in `lo` and the others in `hi`.
    [[gnu::always_inline]] void load(std::uint32_t at, W& lo, W& hi) const {
      const std::uint8_t* __restrict keep = s->keep_;
      lo = W{};
      hi = W{};
      if constexpr (Nibbles) {
        if constexpr (Lanes == 4) {
          widen(nibbles8(keep, at), lo, hi);
        } else {
          widen(nibbles8(keep, at), lo);
        }
      } else {
        for (unsigned b = 0; b < Bytes; ++b) {
          W l{};
          [[maybe_unused]] W h{};
          if constexpr (Lanes == 4) {
            widen(bytes8(load8(keep + b * std::size_t(s->n_) + at)), l, h);
          } else {
            widen(bytes8(load8(keep + b * std::size_t(s->n_) + at)), l);
          }
          lo |= l << (8 * b);
          if constexpr (Lanes == 4) hi |= h << (8 * b);
        }
      }
    }
    [[gnu::always_inline]] void run(std::uint32_t at, std::uint32_t len, std::uint32_t* __restrict q0,
                                    std::uint32_t* __restrict d0, const std::uint32_t* __restrict q1,
                                    const std::uint32_t* __restrict d1, std::uint32_t linear) {
      static_assert(Lanes == 4 || Lanes == 8);
      const std::uint32_t add = s->bias_[at >> kBlockShift];
      for (std::uint32_t t = 0; t < len; t += 8) {
        W lo, hi;
        load(at + t, lo, hi);
        predict(q0 + t, d0 + t, q1 + t, d1 + t, lo, add, linear);
        if constexpr (Lanes == 4) predict(q0 + t + 4, d0 + t + 4, q1 + t + 4, d1 + t + 4, hi, add, linear);
      }
      if constexpr (Nibbles && Bytes != 0) {  // an escape of 0 is 15 itself
        if (s->scan_.next() < at + len) s->template patch<Bytes>(at, len, q0, d0);
      }
    }
#if PSTREAM_COMPACT_SURVIVORS
    // Every survivor, when they are the frame's first particles: survivor t continues the t-th
    // previous particle that `alive` marks (a bit each, the lowest first). Eight previous particles
    // at a time, those marked moved into the lowest lanes (kCompactLanes) and predicted there.
    template <bool Linear>
    [[gnu::target("avx2"), gnu::always_inline]] void compact(const std::uint8_t* __restrict alive, std::uint32_t prev,
                                                             std::uint32_t* __restrict q0, std::uint32_t* __restrict d0,
                                                             const std::uint32_t* __restrict q1,
                                                             const std::uint32_t* __restrict d1) {
      static_assert(Lanes == 8);
      const std::uint32_t blocks = (s->n_ + kBlock - 1) >> kBlockShift;
      const W lane = {0, 1, 2, 3, 4, 5, 6, 7};
      std::uint32_t at = 0;
      // A chunk of previous particles at a time, then its escapes while its survivors are in cache.
      constexpr std::uint32_t kChunk = 512;
      for (std::uint32_t c = 0; c < prev; c += kChunk) {
        const std::uint32_t chunk_at = at;
        for (std::uint32_t i = c; i < std::min(prev, c + kChunk); i += 8) {
          const unsigned m = alive[i / 8];
          if (m == 0) continue;
          const __m256i lanes = _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(static_cast<long long>(kCompactLanes[m])));
          W q, d{};
          const __m256i q_moved =
              _mm256_permutevar8x32_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(q1 + i)), lanes);
          std::memcpy(&q, &q_moved, sizeof(W));
          if constexpr (Linear) {
            const __m256i d_moved =
                _mm256_permutevar8x32_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(d1 + i)), lanes);
            std::memcpy(&d, &d_moved, sizeof(W));
          }
          W u, unused;
          load(at, u, unused);
          const std::uint32_t b = at >> kBlockShift, next = std::min(b + 1, blocks - 1);
          const W border = W{} + ((b + 1) << kBlockShift);
          const W add =
              (W{} + s->bias_[b]) + (reinterpret_cast<W>(at + lane >= border) & (s->bias_[next] - s->bias_[b]));
          const W step = d + ((u >> 1) ^ (0u - (u & 1u))) + add;
          q += step;
          std::memcpy(q0 + at, &q, sizeof(W));
          std::memcpy(d0 + at, &step, sizeof(W));
          at += static_cast<std::uint32_t>(std::popcount(m));
        }
        if constexpr (Nibbles && Bytes != 0) {
          if (s->scan_.next() < at) s->template patch<Bytes>(chunk_at, at - chunk_at, q0 + chunk_at, d0 + chunk_at);
        }
      }
    }
#endif
  };

  // The escapes among survivors [at, at + len): each was predicted with 15, and takes the
  // difference its excess makes to the residual.
  template <unsigned Bytes>
  void patch(std::uint32_t at, std::uint32_t len, std::uint32_t* q0, std::uint32_t* d0) {
    EscapeScan scan = scan_;  // locals: stores through q0 and d0 might alias members
    std::uint32_t e = e_;
    for (; scan.next() < at + len; scan.pop(), ++e) {
      const std::uint32_t x = kNibbleEscape + plane_value(escape_planes_, escapes_, e, Bytes);
      const std::uint32_t delta = unzigzag(x) - unzigzag(kNibbleEscape), t = scan.next() - at;
      q0[t] += delta;
      d0[t] += delta;
    }
    scan_ = scan;
    e_ = e;
  }

  const std::uint8_t *keep_ = nullptr, *escape_planes_ = nullptr;
  const std::uint32_t* bias_ = nullptr;
  std::uint32_t n_ = 0, escapes_ = 0, e_ = 0;
  unsigned bytes_ = 0;
  bool nibbles_ = false;
  EscapeScan scan_;
};

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
    std::uint8_t keep_packing = kBytePlanes;  // kNibbles: keep_bytes is the escape planes' width
    std::uint32_t keep_escapes = 0;           // escape values after the nibbles
    const std::byte *bias = nullptr, *keep = nullptr, *fresh = nullptr, *motion = nullptr, *prior = nullptr;
    const std::byte* keep_escape_planes = nullptr;
  };
  std::span<Word> words;
  unsigned id_bytes = 0;
  const std::byte* ops = nullptr;  // op_count operations; a keyframe has none (its links are below)
  // A keyframe's links to the frame before (version 6 on): link_count operations at `links`
  // pairing its particles with this frame's; 0 when it has none.
  const std::byte* links = nullptr;
  std::uint32_t link_count = 0;
  const std::byte* ids = nullptr;
};

}  // namespace pstream::format::particle
