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
// Version 5: a word's survivors' residuals may be packed as nibbles (Packing::Nibbles): each
// below 15 in four bits, two a byte, and 15 an escape to 15 plus the next value of the escape
// planes. zstd then makes half the bytes and the encoder's optimal parser runs on half the input.
constexpr std::uint32_t kFirstNibbleVersion = 5;
constexpr std::uint32_t kNibbleEscape = 15;
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

// Survivors of one run: q = q1 + (d1 if linear) + r, and the step taken (r: the residual with its
// block's bias, SurvivorResiduals). Eight at a time, the last eight whole: it reads and writes up
// to 7 values past the run (kRunPad), which the next run or new particle overwrites; the runs
// between births and deaths are short (33 survivors on the sparks, 15 on the FLIP pour), and the
// compiler's 16-wide loop spent 43 % of its time in a scalar tail for each.
constexpr std::uint32_t kRunPad = 7;
inline void keep_run(std::uint32_t* __restrict q0, std::uint32_t* __restrict d0, const std::uint32_t* __restrict q1,
                     const std::uint32_t* __restrict d1, const std::uint32_t* __restrict r, std::uint32_t n,
                     std::uint32_t linear_mask) {
  using V = std::uint32_t __attribute__((vector_size(32)));
  for (std::uint32_t t = 0; t < n; t += 8) {
    V q, d, e;
    std::memcpy(&q, q1 + t, 32);
    std::memcpy(&d, d1 + t, 32);
    std::memcpy(&e, r + t, 32);
    const V step = (d & linear_mask) + e;
    q += step;
    std::memcpy(q0 + t, &q, 32);
    std::memcpy(d0 + t, &step, 32);
  }
}

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
// The escapes among n nibbles (whose padding nibble, for odd n, is 0).
inline std::uint64_t count_escapes(const std::uint8_t* packed, std::uint32_t n) {
  const std::size_t bytes = (std::size_t(n) + 1) / 2;
  std::uint64_t count = 0;
  std::size_t b = 0;
  for (; b + 8 <= bytes; b += 8) {
    std::uint64_t x;
    std::memcpy(&x, packed + b, 8);
    // One bit a nibble: the nibbles' sum in each byte (at most 2), then the bytes' sum (at most 16).
    const std::uint64_t bits = escape_bits(x), per_byte = (bits + (bits >> 4)) & 0x0F0F0F0F0F0F0F0Full;
    count += (per_byte * 0x0101010101010101ull) >> 56;
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

// The survivors' residuals as the prediction adds them: each unzigzagged plus the bias of its block
// of 1024, from `bytes` byte planes of n values or (packing kNibbles) from n nibbles and their
// `escapes` escape values, `bytes` byte planes after them. Made one block at a time, in order,
// so that they stay in cache between here and keep_run() (the demo fountain's frames hold up to
// 250,000 particles; the whole frame's residuals in one pass decoded it 7 % slower).
class SurvivorResiduals {
 public:
  SurvivorResiduals(const std::byte* keep, std::uint32_t n, std::uint8_t packing, unsigned bytes,
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

  // Block `block`'s values (the blocks in order) into out[0..kBlock); returns how many.
  std::uint32_t fill(std::uint32_t block, std::uint32_t* out) {
    const std::uint32_t b0 = block << kBlockShift, len = std::min(n_ - b0, kBlock), add = bias_[block];
    if (!nibbles_) {
      switch (bytes_) {
        case 0: std::fill_n(out, len, unzigzag(0) + add); break;
        case 1: from_planes<1>(keep_ + b0, n_, len, add, out); break;
        case 2: from_planes<2>(keep_ + b0, n_, len, add, out); break;
        case 3: from_planes<3>(keep_ + b0, n_, len, add, out); break;
        default: from_planes<4>(keep_ + b0, n_, len, add, out); break;
      }
      return len;
    }
    from_nibbles(keep_ + b0 / 2, len, add, out);  // blocks start on a byte: kBlock is even
    const auto patch = [&]<unsigned Bytes>() {
      EscapeScan scan = scan_;  // locals: stores through `out` might alias members
      std::uint32_t e = e_;
      for (; scan.next() < b0 + len; scan.pop(), ++e)
        out[scan.next() - b0] = unzigzag(kNibbleEscape + plane_value(escape_planes_, escapes_, e, Bytes)) + add;
      scan_ = scan;
      e_ = e;
    };
    switch (bytes_) {
      case 0: break;
      case 1: patch.template operator()<1>(); break;
      case 2: patch.template operator()<2>(); break;
      case 3: patch.template operator()<3>(); break;
      default: patch.template operator()<4>(); break;
    }
    return len;
  }

 private:
  // Vector loops, on pointers that do not alias (a store through `out` could otherwise change the
  // bytes, as far as the compiler knows, and it left the loops scalar).
  template <unsigned Bytes>
  static void from_planes(const std::uint8_t* __restrict planes, std::size_t stride, std::uint32_t len,
                          std::uint32_t add, std::uint32_t* __restrict out) {
    for (std::uint32_t t = 0; t < len; ++t) out[t] = unzigzag(plane_value(planes, stride, t, Bytes)) + add;
  }
  static void from_nibbles(const std::uint8_t* __restrict p, std::uint32_t len, std::uint32_t add,
                           std::uint32_t* __restrict out) {
    for (std::uint32_t t = 0; t < len / 2; ++t) {
      out[2 * t] = unzigzag(p[t] & 15u) + add;
      out[2 * t + 1] = unzigzag(std::uint32_t(p[t] >> 4)) + add;
    }
    if (len & 1) out[len - 1] = unzigzag(p[len / 2] & 15u) + add;
  }

  const std::uint8_t *keep_, *escape_planes_;
  const std::uint32_t* bias_;
  std::uint32_t n_, escapes_, e_ = 0;
  unsigned bytes_;
  bool nibbles_;
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
  const std::byte* ops = nullptr;
  const std::byte* ids = nullptr;
};

}  // namespace pstream::format::particle
