// The particle codec's encoder (docs/format.md, "The particle codec"): quantisation, frames
// ordered so that persisting particles are predicted from the frame before, residuals in byte
// planes compressed by zstd. Its reconstruction is the decoder's output, bit for bit.
#define ZSTD_STATIC_LINKING_ONLY  // ZSTD_c_useBlockSplitter and ZSTD_getCParams (exported by libzstd)
#include <zstd.h>

#include <array>
#include <bit>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#include <span>

#include "format/particle_common.hpp"
#include "format/zstd_memory.hpp"
#include "particlestream/sort.hpp"

namespace pstream::format {
namespace {

using namespace particle;

constexpr std::size_t kOwnFrameBody = std::size_t{1} << 19;  // a body this large starts a zstd frame
// zstd's match tables at most (log2 of their entries): with ids, and without, where the residuals
// are noise that earlier bodies rarely repeat (GroupEncoder's constructor).
constexpr int kChainLog = 17, kHashLog = 18, kMatchedChainLog = 12, kMatchedHashLog = 15;
// The shortest match zstd may use in a lossy body (GroupEncoder's constructor).
constexpr int kLossyMinMatch = 6;

// ---- encoding -------------------------------------------------------------------------------

// 21 bits of each coordinate interleaved.
std::uint64_t morton(std::uint32_t x, std::uint32_t y, std::uint32_t z) {
  const auto spread = [](std::uint64_t v) {
    v &= 0x1fffff;
    v = (v | v << 32) & 0x1f00000000ffffull;
    v = (v | v << 16) & 0x1f0000ff0000ffull;
    v = (v | v << 8) & 0x100f00f00f00f00full;
    v = (v | v << 4) & 0x10c30c30c30c30c3ull;
    v = (v | v << 2) & 0x1249249249249249ull;
    return v;
  };
  return spread(x) | spread(y) << 1 | spread(z) << 2;
}

// a / b rounded down (b > 0): the cell a grid coordinate falls in.
std::int64_t floordiv(std::int64_t a, std::int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }
// A cell's key where the matching sorts cells: 21 bits of each cell coordinate (cells that share
// a key are told apart by the distance every candidate is checked against).
std::uint64_t cell_key(std::int64_t x, std::int64_t y, std::int64_t z) {
  return (std::uint64_t(x & 0x1fffff) << 42) | (std::uint64_t(y & 0x1fffff) << 21) | std::uint64_t(z & 0x1fffff);
}
// The squared distance between two grid positions (below 2^52: grid values are below 2^24).
std::int64_t squared_distance(const std::int64_t* a, const std::int64_t* b) {
  return (a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]);
}

// The least and the largest of values read as signed 32-bit numbers (grid values, residuals); `v`
// is not empty.
std::pair<std::int32_t, std::int32_t> signed_extremes(std::span<const std::uint32_t> v) {
  std::int32_t lo = static_cast<std::int32_t>(v[0]), hi = lo;
  for (const std::uint32_t x : v) {
    lo = std::min(lo, static_cast<std::int32_t>(x));
    hi = std::max(hi, static_cast<std::int32_t>(x));
  }
  return {lo, hi};
}

// Whether Relative code `code` decodes within word `e`'s bound of the float with bits `bits`, by
// the decoder's exact arithmetic (subnormals: within the smallest normal's bound).
bool relative_within(std::uint32_t bits, std::uint32_t code, const WordCodingEntry& e) {
  const float x = as_float(bits), y = as_float(relative_decode(code, e.base));
  const double allowed = double(e.error) * std::max(double(std::abs(x)), double(FLT_MIN));
  return std::isfinite(x) && std::isfinite(y) && std::abs(double(y) - double(x)) <= allowed;
}

// Of the Relative codes within the bound of a value (a run around its nearest code, `nearest`),
// the one nearest `target`, the prediction: quantised in the loop, a value that follows its
// prediction within the bound costs a residual of 0. The plan's grid is two bits finer than the
// bound needs, so that about five codes are within it (frame_plan.cpp).
std::uint32_t relative_toward(std::uint32_t bits, std::uint32_t nearest, std::uint32_t target,
                              const WordCodingEntry& e) {
  constexpr int kMostSteps = 8;  // the codes within the bound: at most 2 x 2.56 on the plan's grid
  const std::uint32_t dir = static_cast<std::int32_t>(target - nearest) > 0 ? 1u : ~0u;
  std::uint32_t code = nearest;
  for (int s = 0; s < kMostSteps && code != target && relative_within(bits, code + dir, e); ++s) code += dir;
  return code;
}

// A particle's nearest candidates, at most N, sorted by key (distance, then current index): `key`
// goes in unless they are full and it is not below the last, which it then pushes out.
template <class Key, std::size_t N>
void keep_nearest(Key (&best)[N], int& found, const Key& key) {
  if (found == int(N) && !(key < best[N - 1])) return;
  int slot = found < int(N) ? found++ : int(N) - 1;
  for (; slot > 0 && key < best[slot - 1]; --slot) best[slot] = best[slot - 1];
  best[slot] = key;
}

// The median of residuals read as signed numbers: the value nth_element would put at size / 2.
// Residuals usually span a few hundred values, so a histogram over their range finds it in two
// passes (the demo fountain's cook spent a fifth of its time on nth_element); a wide span falls
// back to nth_element on a copy in `scratch`.
std::uint32_t median_of(std::span<const std::uint32_t> v, std::vector<std::uint32_t>& scratch) {
  if (v.empty()) return 0;
  const auto [lo, hi] = signed_extremes(v);
  constexpr std::uint32_t kSpan = 4096;
  const std::uint32_t span = static_cast<std::uint32_t>(hi) - static_cast<std::uint32_t>(lo);
  const std::size_t rank = v.size() / 2;  // values before the median
  if (span < kSpan) {
    std::array<std::uint32_t, kSpan> count;
    std::fill_n(count.begin(), span + 1, 0u);
    for (const std::uint32_t x : v) ++count[x - static_cast<std::uint32_t>(lo)];
    std::size_t below = 0;
    for (std::uint32_t t = 0;; ++t) {
      below += count[t];
      if (below > rank) return static_cast<std::uint32_t>(lo) + t;
    }
  }
  scratch.assign(v.begin(), v.end());
  const auto mid = scratch.begin() + static_cast<std::ptrdiff_t>(rank);
  std::nth_element(scratch.begin(), mid, scratch.end(), [](std::uint32_t a, std::uint32_t b) {
    return static_cast<std::int32_t>(a) < static_cast<std::int32_t>(b);
  });
  return *mid;
}

// std::bit_width, written so that the compiler vectorises a sum of them (x86-64's baseline has no
// vector count of leading zeros): the exponent of a float made from the top or bottom 16 bits,
// which it holds exactly. The predictors' costs were a sixth of the demo fountain's cook.
inline std::uint32_t bit_width_of(std::uint32_t x) {
  const std::uint32_t high = x >> 16;
  const auto v = static_cast<std::int32_t>(high != 0 ? high : x);
  const auto exponent = static_cast<std::int32_t>(std::bit_cast<std::uint32_t>(static_cast<float>(v)) >> 23);
  return static_cast<std::uint32_t>(std::max(exponent - 126, 0)) + (high != 0 ? 16u : 0u);
}

// The encoder's mirror of the decoder's state, plus what it needs to match particles.
struct EncoderState {
  std::uint32_t count = 0;
  std::vector<std::vector<std::uint32_t>> q, d;  // per coded word
  std::vector<std::uint64_t> ids;
  std::vector<std::uint8_t> steps;  // per particle, with derived words: the decoder's step count
};

class GroupEncoder {
 public:
  explicit GroupEncoder(const CodecInfo& info) : info_(info), plan_(info) {
    record_size_ = static_cast<std::uint32_t>(info.words.size() * 4);
    for (std::size_t k = 0; k < plan_.coded.size(); ++k) {
      for (int c = 0; c < 3; ++c) {
        if (plan_.coded[k] == std::uint32_t(c)) position_k_[c] = static_cast<int>(k);
        if (info.velocity_word >= 0 && info.frame_seconds > 0 &&
            plan_.coded[k] == std::uint32_t(info.velocity_word + c))
          velocity_k_[c] = static_cast<int>(k);
      }
    }
    if (velocity_k_[0] < 0 || velocity_k_[1] < 0 || velocity_k_[2] < 0)
      velocity_k_[0] = velocity_k_[1] = velocity_k_[2] = -1;
    state_.q.resize(plan_.coded.size());
    state_.d.resize(plan_.coded.size());
    nibbles_.assign(plan_.coded.size(), info.nibbles ? 1 : 0);
    zstd_ = make_zstd_cctx();
    if (zstd_ == nullptr) throw Error("cannot create a zstd encoder");
    ZSTD_CCtx_setParameter(zstd_, ZSTD_c_compressionLevel, info.zstd_level);
    ZSTD_CCtx_setParameter(zstd_, ZSTD_c_checksumFlag, 0);
    // Small bodies continue one zstd frame (format version 4 on): later frames reuse the entropy
    // tables and refer back to earlier bodies. On Blender's sparks this made the survivors'
    // residual planes 9 % smaller and the new particles' 35 % (their values recur).
    ZSTD_CCtx_setParameter(zstd_, ZSTD_c_windowLog, kStreamWindowLog);
    // Split blocks where the statistics change (between planes): zstd does this by itself only
    // from level 16 on, and it is most of that level's gain on byte planes.
    ZSTD_CCtx_setParameter(zstd_, ZSTD_c_useBlockSplitter, ZSTD_ps_enable);
    // A stream's size is unknown, so zstd sizes its match tables for a large input (level 16:
    // 2^22 entries each, 32 MiB, made afresh at every keyframe and mostly cache misses). Bodies
    // are small: with at most 2^17 and 2^18 entries the sparks cooked about 3x as fast for 0.7 %
    // more bytes, the demo fountain 1.2-1.7x as fast at the same size. Without ids, 2^12 and 2^15
    // entries made the FLIP pour's cook 1.1x as fast for 0.1 % more bytes (the sparks' 1.8 % more).
    const bool matched = info.order == FrameOrder::Matched;
    const ZSTD_compressionParameters p = ZSTD_getCParams(info.zstd_level, ZSTD_CONTENTSIZE_UNKNOWN, 0);
    ZSTD_CCtx_setParameter(zstd_, ZSTD_c_chainLog,
                           std::min<int>(int(p.chainLog), matched ? kMatchedChainLog : kChainLog));
    ZSTD_CCtx_setParameter(zstd_, ZSTD_c_hashLog, std::min<int>(int(p.hashLog), matched ? kMatchedHashLog : kHashLog));
    // A lossy body's planes hold small residuals, 2 to 8 of them in 5 bytes: a match that short
    // repeats little beyond chance, and costs the encoder's parser time. With matches of 6 bytes
    // or more (levels 3-16 allow 5, 17-19 fewer) the sparks cooked 0.4 % smaller and 13 % faster,
    // the FLIP pour 0.1 % smaller in the same time, and the demo fountain's 300 frames 15 % faster
    // for 0.6 % more bytes (its first 120 0.05 % smaller; its large bodies, each a zstd frame of
    // its own, gain from 5: 6 for the others only made it 0.1 % smaller than before, at the speed
    // before). At levels 3 and 19 the sparks were 2.1 % and 1.0 % smaller. Lossless bodies hold
    // float bits, where 6 made the sparks 1.0 % larger.
    if (!info.lossless) ZSTD_CCtx_setParameter(zstd_, ZSTD_c_minMatch, std::max<int>(int(p.minMatch), kLossyMinMatch));
  }
  ~GroupEncoder() { ZSTD_freeCCtx(zstd_); }
  GroupEncoder(const GroupEncoder&) = delete;
  GroupEncoder& operator=(const GroupEncoder&) = delete;

  EncodedFrame encode(const SourceFrame& frame, bool keyframe, std::uint64_t index) {
    load(frame, index);
    const std::uint32_t n = static_cast<std::uint32_t>(frame.count);
    // match[j] = index in the previous frame's order, or -1; order = output order of source particles.
    std::vector<std::int64_t> match(n, -1);
    std::vector<std::uint32_t> order(n);
    std::iota(order.begin(), order.end(), 0u);
    switch (info_.order) {
      case FrameOrder::Source:
        for (std::uint32_t j = 0; j < std::min(n, state_.count); ++j) match[j] = j;
        break;
      case FrameOrder::Id: {
        const std::span<const std::uint64_t> ids = frame.ids;
        // Sources usually write their particles in id order already (a check is a tenth of a sort).
        if (!std::is_sorted(ids.begin(), ids.end()))
          std::stable_sort(order.begin(), order.end(),
                           [&](std::uint32_t a, std::uint32_t b) { return ids[a] < ids[b]; });
        std::uint32_t i = 0;
        for (std::uint32_t j : order) {
          while (i < state_.count && state_.ids[i] < ids[j]) ++i;
          if (i < state_.count && state_.ids[i] == ids[j]) match[j] = i++;
        }
        break;
      }
      case FrameOrder::Matched: match_by_position(frame, match); break;
    }
    if (info_.order == FrameOrder::Matched) {
      // Persisting particles in the previous frame's order (each previous index pairs with one
      // particle at most, so they are placed, not sorted), then the new ones in Morton order.
      std::vector<std::int64_t> by_prev(keyframe ? 0 : state_.count, -1);
      std::vector<std::pair<std::uint64_t, std::uint32_t>> fresh;  // (Morton code, index): ties by index
      for (std::uint32_t j = 0; j < n; ++j) {
        if (!keyframe && match[j] >= 0)
          by_prev[std::size_t(match[j])] = j;
        else
          fresh.emplace_back(morton_of(j), j);
      }
      std::sort(fresh.begin(), fresh.end());
      std::size_t at = 0;
      for (const std::int64_t j : by_prev)
        if (j >= 0) order[at++] = static_cast<std::uint32_t>(j);
      for (const auto& f : fresh) order[at++] = f.second;
    }
    EncodedFrame out;
    out.keyframe = keyframe;
    out.count = n;
    out.predictable = std::min(n, state_.count);
    for (std::uint32_t j = 0; j < n; ++j) out.matched += match[j] >= 0 ? 1 : 0;
    std::vector<std::byte> body = keyframe ? keyframe_body(order, match) : predicted_body(order, match);
    follows_a_frame_ = true;
    // A keyframe starts a zstd frame, and so does a large body: continuing a frame paid 1.4-8 %
    // for bodies up to 512 KiB and cost 1.5-2.3 % above (the demo fountain's frames, each
    // against a frame of its own). Every packet ends with a flush, at a block boundary, so the
    // decoder gets the whole body from it.
    if (keyframe || body.size() >= kOwnFrameBody) ZSTD_CCtx_reset(zstd_, ZSTD_reset_session_only);
    out.packet.resize(ZSTD_compressBound(body.size()) + 64);
    ZSTD_inBuffer in{body.data(), body.size(), 0};
    ZSTD_outBuffer packet{out.packet.data(), out.packet.size(), 0};
    for (std::size_t left = 1; left != 0;) {
      left = ZSTD_compressStream2(zstd_, &packet, &in, ZSTD_e_flush);
      if (ZSTD_isError(left)) throw Error(fmt::format("zstd compression failed: {}", ZSTD_getErrorName(left)));
      if (left != 0 && packet.pos == packet.size) {
        out.packet.resize(packet.size * 2);
        packet.dst = out.packet.data();
        packet.size = out.packet.size();
      }
    }
    out.packet.resize(packet.pos);
    out.bounds = bounds();
    return out;
  }

 private:
  // The frame's coded words (quantised, checked against their bound) and ids, in source order.
  void load(const SourceFrame& frame, std::uint64_t index) {
    const std::uint32_t n = static_cast<std::uint32_t>(frame.count);
    if (frame.records.size() < std::size_t(n) * record_size_)
      throw Error(fmt::format("frame {}: {} bytes of records for {} particles", index, frame.records.size(), n));
    if (info_.order == FrameOrder::Id && frame.ids.size() != n)
      throw Error(fmt::format("frame {}: the clip is ordered by id, but the frame has {} ids for {} particles", index,
                              frame.ids.size(), n));
    source_.resize(plan_.coded.size());
    raw_.resize(plan_.coded.size());
    for (std::size_t k = 0; k < plan_.coded.size(); ++k) {
      const std::uint32_t w = plan_.coded[k];
      const WordCodingEntry& e = info_.words[w];
      std::vector<std::uint32_t>& v = source_[k];
      v.resize(n);
      for (std::uint32_t j = 0; j < n; ++j)
        std::memcpy(&v[j], frame.records.data() + std::size_t(j) * record_size_ + 4 * w, 4);
      if (e.coding == WordCoding::Relative) {
        raw_[k].assign(v.begin(), v.end());  // the floats, for the codes chosen in the loop
        for (std::uint32_t j = 0; j < n; ++j) {
          const std::uint32_t q = relative_code(v[j], e.base);
          if (!relative_within(v[j], q, e)) {
            throw Error(
                fmt::format("frame {}: particle {}: record word {} is {}, which a relative bound of {} "
                            "cannot hold (not a finite number)",
                            index, j, w, as_float(v[j]), e.error));
          }
          v[j] = q;
        }
        continue;
      }
      if (e.coding != WordCoding::Quantized) continue;
      const float origin = as_float(e.base);
      for (std::uint32_t j = 0; j < n; ++j) {
        const float x = as_float(v[j]);
        const double t = std::nearbyint((double(x) - double(origin)) / double(e.step));
        bool ok = std::abs(t) < double(kGridLimit);
        std::int32_t q = ok ? static_cast<std::int32_t>(t) : 0;
        // The nearest grid value is within the bound by the step's construction; check the
        // decoder's exact arithmetic anyway, and its neighbours.
        if (ok && !(std::abs(double(dequantize(std::uint32_t(q), e.step, origin)) - double(x)) <= double(e.error))) {
          ok = false;
          for (const std::int32_t c : {q - 1, q + 1}) {
            if (std::abs(double(dequantize(std::uint32_t(c), e.step, origin)) - double(x)) <= double(e.error)) {
              q = c;
              ok = true;
              break;
            }
          }
        }
        if (!ok) {
          throw Error(
              fmt::format("frame {}: particle {}: record word {} is {}, which the grid (origin {}, step {}) "
                          "cannot hold within {} (not finite, or outside the clip's range)",
                          index, j, w, x, origin, e.step, e.error));
        }
        v[j] = static_cast<std::uint32_t>(q);
      }
    }
    ids_in_ = frame.ids;
    // A particle with no predecessor starts with one step: its source velocity over a frame, in
    // grid steps, for each position word a velocity is derived from (0 when the source has none).
    birth_.assign(plan_.coded.size(), {});
    for (const WordPlan::Derived& dw : plan_.derived) {
      std::vector<std::uint32_t>& b = birth_[dw.from];
      b.assign(n, 0);
      const double per_step = 2.0 * double(info_.words[dw.word].step);
      for (std::uint32_t j = 0; j < n; ++j) {
        float v;
        std::memcpy(&v, frame.records.data() + std::size_t(j) * record_size_ + 4 * dw.word, 4);
        const double t = std::nearbyint(double(v) / per_step);
        if (std::isfinite(t) && std::abs(t) < double(kGridLimit))
          b[j] = static_cast<std::uint32_t>(static_cast<std::int32_t>(t));
      }
    }
  }

  std::uint32_t birth(std::size_t k, std::uint32_t source_index) const {
    return birth_[k].empty() ? 0u : birth_[k][source_index];
  }

  std::uint64_t morton_of(std::uint32_t j) const {
    std::uint32_t c[3] = {0, 0, 0};
    for (int a = 0; a < 3; ++a) {
      if (position_k_[a] >= 0) {
        const auto v = static_cast<std::int32_t>(source_[std::size_t(position_k_[a])][j]);
        c[a] = static_cast<std::uint32_t>(std::max(v, 0)) >> 3;  // coarse cells of 8 grid steps
      }
    }
    return morton(c[0], c[1], c[2]);
  }

  // Previous particle i's stored velocity over a frame on axis a, in grid steps (bounded: a step
  // beyond any grid finds no candidates).
  std::int32_t velocity_step(std::uint32_t i, int a) const {
    const WordCodingEntry& v = info_.words[std::size_t(info_.velocity_word + a)];
    const double velocity = dequantize(state_.q[std::size_t(velocity_k_[a])][i], v.step, as_float(v.base));
    const double steps = velocity * info_.frame_seconds / double(info_.words[std::size_t(a)].step);
    constexpr double kFar = 1 << 24;
    return static_cast<std::int32_t>(std::llround(std::clamp(steps, -kFar, kFar)));
  }

  // A candidate pair of match_by_position(): squared distance, previous and current index.
  struct Pair {
    std::int64_t distance;
    std::uint32_t prev, cur;
  };
  // Kept for each previous particle: 6 rather than 8 makes the FLIP pour 0.6 % larger and its
  // encode about 1.13x as fast (docs/compression-experiments.md, "Six candidates a
  // particle").
  static constexpr int kCandidates = 6;
  // The most candidates one search reads (the FLIP pour's read 68 on average, 566 at most). A
  // clump far denser than the frame's average (particles a grid step apart, beside a stray one far
  // away that makes the cells large) would otherwise have each search read the whole clump: 8,000
  // particles took 6.8 s to cook, 40,000 5 minutes. A search that stops keeps the nearest of
  // what it read.
  static constexpr std::uint32_t kMostRead = 4096;
  struct Offset {  // a cell offset, and the least squared distance across it
    std::int64_t bound;
    int d[3];
  };
  // A current particle left over by the pairing: its cell's key, its position and index (kept
  // beside the key: read through `at` instead, with a binary search for each cell in place of
  // CellRanges, the pairing took 280-300 us a frame of the FLIP pour where it takes 225).
  struct Spare {
    std::uint64_t key;
    std::int64_t q[3];
    std::uint32_t j;
    bool operator<(const Spare& o) const { return std::tie(key, j) < std::tie(o.key, o.j); }
  };
  // Where each cell's particles are in a list sorted by cell key: an open-addressed table from a
  // key to the range of its particles (one probe or two where a binary search took ten steps).
  struct CellRanges {
    static constexpr std::uint64_t kEmpty = ~std::uint64_t{0};  // cell_key() is below 2^63
    std::vector<std::uint64_t> keys;
    std::vector<std::pair<std::uint32_t, std::uint32_t>> ranges;
    std::uint64_t mask = 0;
    int shift = 64;
    void build(std::span<const Spare> sorted) {
      const std::size_t size = std::bit_ceil(std::max<std::size_t>(16, 2 * sorted.size()));
      keys.assign(size, kEmpty);
      ranges.resize(size);
      mask = size - 1;
      shift = 64 - std::countr_zero(size);
      for (std::size_t t = 0; t < sorted.size();) {
        std::size_t u = t + 1;
        while (u < sorted.size() && sorted[u].key == sorted[t].key) ++u;
        std::uint64_t h = slot(sorted[t].key);
        while (keys[h] != kEmpty) h = (h + 1) & mask;
        keys[h] = sorted[t].key;
        ranges[h] = {std::uint32_t(t), std::uint32_t(u)};
        t = u;
      }
    }
    std::pair<std::uint32_t, std::uint32_t> find(std::uint64_t key) const {
      for (std::uint64_t h = slot(key); keys[h] != kEmpty; h = (h + 1) & mask)
        if (keys[h] == key) return ranges[h];
      return {0, 0};
    }
    std::uint64_t slot(std::uint64_t key) const { return (key * 0x9E3779B97F4A7C15ull) >> shift; }
  };
  // This frame's particles by their exact quantised place, in an open-addressed table: the lowest
  // index at each place. `at` holds each particle's place in its first 3 of every 6 numbers.
  struct ExactPlaces {
    static constexpr std::uint32_t kNone = ~std::uint32_t{0};
    std::vector<std::uint32_t> slot;
    std::uint64_t mask = 0;
    const std::int64_t* at = nullptr;
    void build(std::uint32_t n, const std::int64_t* places) {
      const std::size_t size = std::bit_ceil(std::max<std::size_t>(16, 2 * std::size_t(n)));
      slot.assign(size, kNone);
      mask = size - 1;
      at = places;
      for (std::uint32_t j = 0; j < n; ++j) {
        std::uint32_t& s = slot[probe(&at[std::size_t(j) * 6])];
        if (s == kNone) s = j;  // else an earlier particle holds the place
      }
    }
    std::uint32_t find(const std::int64_t* q) const { return slot[probe(q)]; }
    // The slot that holds q's place, or the empty one where it would go.
    std::uint64_t probe(const std::int64_t* q) const {
      const std::uint64_t k = (std::uint64_t(std::uint32_t(q[0])) * 0x9E3779B97F4A7C15ull) ^
                              (std::uint64_t(std::uint32_t(q[1])) * 0xC2B2AE3D27D4EB4Full) ^
                              (std::uint64_t(std::uint32_t(q[2])) * 0x165667B19E3779F9ull);
      std::uint64_t h = (k ^ (k >> 29)) & mask;
      for (; slot[h] != kNone; h = (h + 1) & mask) {
        const std::int64_t* o = &at[std::size_t(slot[h]) * 6];
        if (o[0] == q[0] && o[1] == q[1] && o[2] == q[2]) break;
      }
      return h;
    }
  };
  // match_by_position()'s working memory, kept from frame to frame: made afresh, its larger arrays
  // were pages the kernel mapped and cleared for every frame.
  struct MatchScratch {
    std::vector<std::int64_t> at, sorted;
    std::vector<Pair> slots, saved, pairs;
    std::vector<std::uint8_t> kept, saved_kept, prev_taken, claimed;
    std::vector<std::int32_t> steps, e;
    std::vector<std::uint32_t> start, order, fill, visit_start, visit, all, rest, sample, by_distance;
    ExactPlaces places;  // this frame's particles by their exact place
    std::vector<float> xs, ys, zs;
    std::vector<Offset> offsets;
    std::vector<std::pair<std::uint64_t, std::uint32_t>> sorted_cells;
    std::vector<std::size_t> cell_of_particle;
    std::vector<std::uint64_t> nearest_prev, items, scratch;
    std::vector<Spare> spare;         // pair_leftovers()'s current particles
    std::vector<std::uint32_t> left;  // and its previous ones
    CellRanges spare_cells;           // where `spare` holds each cell's
    std::vector<std::uint8_t> known;  // and what it knows of each previous particle's candidates
  };

  // Without ids: previous and current particles are paired closest first, within about one
  // particle spacing. Measured on the Mantaflow FLIP fixture, pairing plain positions beats
  // pairing positions moved on by the last step (2.29 against 2.41 bytes per particle) or
  // moved back along the velocity (3.04): a FLIP solver re-samples its particles every frame and
  // most move less than a spacing; the motion is left to the predictor. Particles that persist
  // and move further than a spacing are paired from where their stored velocity takes them, when
  // a sample finds them nearer that way (below). Otherwise the particles left over are paired
  // among themselves (pair_leftovers()).
  void match_by_position(const SourceFrame& frame, std::vector<std::int64_t>& match) {
    const std::uint32_t n = static_cast<std::uint32_t>(frame.count);
    if (state_.count == 0 || n == 0 || position_k_[0] < 0 || position_k_[1] < 0 || position_k_[2] < 0) return;
    std::int64_t lo[3], hi[3];
    for (int a = 0; a < 3; ++a)
      std::tie(lo[a], hi[a]) = signed_extremes(std::span(source_[std::size_t(position_k_[a])]).first(n));
    const double volume = double(hi[0] - lo[0] + 1) * double(hi[1] - lo[1] + 1) * double(hi[2] - lo[2] + 1);
    const std::int64_t cell = std::max<std::int64_t>(2, std::llround(std::cbrt(volume / n)));
    // Each current particle's position and cell (of side `cell`), six numbers together.
    MatchScratch& m = match_;
    std::vector<std::int64_t>& at = m.at;
    at.resize(std::size_t(n) * 6);
    for (std::uint32_t j = 0; j < n; ++j) {
      for (int a = 0; a < 3; ++a) {
        at[std::size_t(j) * 6 + a] = static_cast<std::int32_t>(source_[std::size_t(position_k_[a])][j]);
        at[std::size_t(j) * 6 + 3 + a] = floordiv(at[std::size_t(j) * 6 + a], cell);
      }
    }
    // A particle's candidates are the current particles in the 3x3x3 cells (of side `cell`) around
    // it, within `reach`; of those, its kCandidates nearest (ties by index) are kept. The result
    // depends on nothing else, so the search may visit them in any order and stop early.
    // Each previous particle's kept candidates in its own slots, so that the searches may run in
    // any order and the pairs still come out in previous-index order.
    std::vector<Pair>& slots = m.slots;
    std::vector<std::uint8_t>& kept = m.kept;
    slots.resize(std::size_t(state_.count) * kCandidates);
    kept.assign(state_.count, 0);
    const std::int64_t reach = cell * cell * 2;  // squared: about 1.4 spacings
    // Where each previous particle is searched from: where it was, or moved on by its stored
    // velocity (below), 3 numbers a particle.
    const std::uint32_t* const was[3] = {state_.q[std::size_t(position_k_[0])].data(),
                                         state_.q[std::size_t(position_k_[1])].data(),
                                         state_.q[std::size_t(position_k_[2])].data()};
    std::vector<std::int32_t>& steps = m.steps;  // 3 a previous particle: its velocity's step (below)
    const std::int32_t* moved = nullptr;         // steps.data() while searching from the moved places
    const auto from = [&](std::uint32_t i, int a) {
      const std::int64_t q = static_cast<std::int32_t>(was[a][i]);
      return moved == nullptr ? q : q + moved[std::size_t(i) * 3 + std::size_t(a)];
    };
    const auto search = [&](std::uint32_t i, const auto& visit_cells) {
      const std::int64_t p[3] = {from(i, 0), from(i, 1), from(i, 2)};
      const std::int64_t home[3] = {floordiv(p[0], cell), floordiv(p[1], cell), floordiv(p[2], cell)};
      std::pair<std::int64_t, std::uint32_t> best[kCandidates];  // (distance, current index)
      int found = 0;
      std::uint32_t read = 0;
      const auto consider = [&](std::uint32_t j, const std::int64_t* s) {  // s: position and cell
        ++read;
        const std::int64_t e = squared_distance(s, p);
        if (e > reach) return;
        for (int a = 0; a < 3; ++a) {
          if (s[3 + a] < home[a] - 1 || s[3 + a] > home[a] + 1) return;
        }
        keep_nearest(best, found, std::pair{e, j});
      };
      // The worst distance kept, once there are enough candidates: cells that cannot hold a
      // closer particle are not visited. -1 once kMostRead candidates are read: the search stops.
      const auto worst = [&] {
        return read >= kMostRead ? -1 : found == kCandidates ? best[kCandidates - 1].first : reach;
      };
      visit_cells(p, home, consider, worst);
      for (int b = 0; b < found; ++b)
        slots[std::size_t(i) * kCandidates + std::size_t(b)] = Pair{best[b].first, i, best[b].second};
      kept[i] = static_cast<std::uint8_t>(found);
    };
    // A dense grid over this frame's box only when it is not much larger than the frame.
    const double most_cells = 16.0 * n + 4096.0;
    // This frame's particles by cell, as the search below reads them: made by the first
    // searches() and kept for the next.
    std::vector<std::uint32_t>&start = m.start, &order = m.order;
    std::vector<float>&xs = m.xs, &ys = m.ys, &zs = m.zs;
    std::vector<std::int32_t>& e = m.e;
    std::vector<std::int64_t>& sorted = m.sorted;
    std::vector<Offset>& offsets = m.offsets;
    std::vector<std::pair<std::uint64_t, std::uint32_t>>& sorted_cells = m.sorted_cells;
    offsets.clear();
    bool prepared = false;
    // The searches of the previous particles `previous` (indices), into their slots.
    const auto searches = [&](std::span<const std::uint32_t> previous, bool in_cell_order) {
      const auto searched = static_cast<std::uint32_t>(previous.size());
      // Particles 0..count-1 by their cells (a counting sort, stable): `order` lists them, and cell
      // c's are order[start[c]] to order[start[c + 1] - 1]. Each particle's cell is found once.
      std::vector<std::size_t>& cell_of_particle = m.cell_of_particle;
      const auto by_cell = [&](std::size_t cells, std::uint32_t count, const auto& cell_of,
                               std::vector<std::uint32_t>& start, std::vector<std::uint32_t>& order) {
        start.assign(cells + 1, 0);
        cell_of_particle.resize(count);
        for (std::uint32_t j = 0; j < count; ++j) {
          cell_of_particle[j] = cell_of(j);
          ++start[cell_of_particle[j] + 1];
        }
        for (std::size_t c = 1; c < start.size(); ++c) start[c] += start[c - 1];
        std::vector<std::uint32_t>& fill = m.fill;
        fill.assign(start.begin(), start.end() - 1);
        order.resize(count);
        for (std::uint32_t j = 0; j < count; ++j) order[fill[cell_of_particle[j]]++] = j;
      };
      // Where the frame's box holds few enough cells of side `cell`, and `cell` is below 2048, each
      // search reads exactly its candidates' cells, the 3x3x3 around its home, as runs along z of
      // this frame's particles sorted by cell (skipping those farther than the worst distance kept),
      // and measures them in float in loops the compiler vectorises: the FLIP pour's encode is
      // 1.4x as fast as through the half-size cells below, with the same pairs. The floats are
      // exact: coordinates are below 2^24, a difference within the 3x3x3 is below 4096 and its
      // square below 2^24, and a sum that can be within the reach (below 2^23) has only exact partial
      // sums (a larger one rounds to 2^24 or more).
      std::int64_t c0[3], cdims[3];
      double cells = 1;
      for (int a = 0; a < 3; ++a) {
        c0[a] = floordiv(lo[a], cell);
        cdims[a] = floordiv(hi[a], cell) - c0[a] + 1;
        cells *= double(cdims[a]);
      }
      if (cell < 2048 && cells <= most_cells) {
        if (!prepared) {
          by_cell(
              std::size_t(cells), n,
              [&](std::uint32_t j) {
                const std::int64_t* q = &at[std::size_t(j) * 6 + 3];
                return std::size_t(((q[0] - c0[0]) * cdims[1] + (q[1] - c0[1])) * cdims[2] + (q[2] - c0[2]));
              },
              start, order);
          xs.resize(n), ys.resize(n), zs.resize(n), e.resize(n);
          for (std::uint32_t t = 0; t < n; ++t) {
            const std::int64_t* q = &at[std::size_t(order[t]) * 6];
            xs[t] = static_cast<float>(q[0]);
            ys[t] = static_cast<float>(q[1]);
            zs[t] = static_cast<float>(q[2]);
          }
        }
        // The previous particles by home cell (outside the box: its nearest), so that searches one
        // after another read the same cells (a sample is searched in its own order).
        const auto home_of = [&](std::uint32_t i, int a) { return floordiv(from(i, a), cell) - c0[a]; };
        std::vector<std::uint32_t>&visit_start = m.visit_start, &visit = m.visit;
        if (in_cell_order) {
          by_cell(
              std::size_t(cells), searched,
              [&](std::uint32_t u) {
                std::int64_t c[3];
                for (int a = 0; a < 3; ++a) c[a] = std::clamp<std::int64_t>(home_of(previous[u], a), 0, cdims[a] - 1);
                return std::size_t((c[0] * cdims[1] + c[1]) * cdims[2] + c[2]);
              },
              visit_start, visit);
        } else {
          visit.resize(searched);
          std::iota(visit.begin(), visit.end(), 0u);
        }
        // The 3x3x3 as runs of cells along z (x and y offsets, first and last z offset): the home
        // cell first, so that the 8 kept are near soon and few candidates after them are kept.
        constexpr int kRuns[11][4] = {{0, 0, 0, 0},   {0, 0, -1, -1}, {0, 0, 1, 1},  {-1, 0, -1, 1},
                                      {1, 0, -1, 1},  {0, -1, -1, 1}, {0, 1, -1, 1}, {-1, -1, -1, 1},
                                      {-1, 1, -1, 1}, {1, -1, -1, 1}, {1, 1, -1, 1}};
        // The arrays as local pointers: a store through `kept` (bytes) might, for the compiler,
        // change anything reached through this lambda's references, and the loop below would
        // reload them (the FLIP pour's cook took 3 % longer).
        const float *const px = xs.data(), *const py = ys.data(), *const pz = zs.data();
        std::int32_t* const pe = e.data();
        const std::uint32_t *const pstart = start.data(), *const porder = order.data();
        const std::uint32_t* const where[3] = {was[0], was[1], was[2]};
        const std::int32_t* const shift = moved;
        Pair* const pslots = slots.data();
        std::uint8_t* const pkept = kept.data();
        const std::int64_t side = cell, most = reach;
        // A search first reads only the candidates within twice the squared distance of the last
        // search's 8th (the searches go cell by cell, so neighbours' are alike), and again within
        // the reach when that finds fewer than 8. Those it skipped are farther than the 8 it kept,
        // so the pairs are the same; the FLIP pour's matching took 4-5 % less time (medians of five
        // alternating cooks: 87.0 against 91.1 ms).
        auto guess = static_cast<std::int32_t>(most);
        for (const std::uint32_t u : visit) {
          const std::uint32_t i = previous[u];
          float p[3];
          std::int64_t home[3], gap[3][3];  // gap[a][d + 1]: squared, to the cells d along axis a
          for (int a = 0; a < 3; ++a) {
            const std::int64_t q = static_cast<std::int32_t>(where[a][i]) +
                                   (shift == nullptr ? 0 : shift[std::size_t(i) * 3 + std::size_t(a)]);
            p[a] = static_cast<float>(q);
            home[a] = floordiv(q, side) - c0[a];
            const std::int64_t into = q - (home[a] + c0[a]) * side;  // 0..cell-1
            gap[a][0] = (into + 1) * (into + 1);
            gap[a][1] = 0;
            gap[a][2] = (side - into) * (side - into);
          }
          // The kept candidates as distance << 32 | current index: one comparison orders them as
          // (distance, index) does (distances within the reach are below 2^23).
          std::uint64_t best[kCandidates];
          int found = 0;
          std::int32_t within = 0;  // the scan's bound, then the worst distance kept
          const auto scan = [&](std::int32_t bound) {
            found = 0;
            within = bound;
            std::uint32_t unread = kMostRead;
            for (const auto& run : kRuns) {
              // Runs, and a run's end cells, farther from the particle than the worst distance kept
              // cannot hold a closer candidate.
              const std::int64_t x = home[0] + run[0], y = home[1] + run[1];
              const std::int64_t row_gap = gap[0][run[0] + 1] + gap[1][run[1] + 1], limit = std::int64_t(within);
              if (x < 0 || x >= cdims[0] || y < 0 || y >= cdims[1] || row_gap > limit) continue;
              const int first = run[2] == -1 && row_gap + gap[2][0] > limit ? 0 : run[2];
              const int last = run[3] == 1 && row_gap + gap[2][2] > limit ? 0 : run[3];
              const std::int64_t z0 = std::max<std::int64_t>(home[2] + first, 0);
              const std::int64_t z1 = std::min(home[2] + last, cdims[2] - 1);
              if (first > last || z0 > z1) continue;
              const std::size_t k = std::size_t((x * cdims[1] + y) * cdims[2] + z0);
              const std::uint32_t t0 = pstart[k], t1 = t0 + std::min(pstart[k + std::size_t(z1 - z0) + 1] - t0, unread);
              unread -= t1 - t0;
              for (std::uint32_t t = t0; t < t1; ++t) {
                const float dx = px[t] - p[0], dy = py[t] - p[1], dz = pz[t] - p[2];
                pe[t] = static_cast<std::int32_t>(dx * dx + dy * dy + dz * dz);  // below 3 x 4096^2
              }
              // The candidates within the bound, 64 at a time as bits of a mask (4 compared at once
              // with SSE2), then kept one after another: a branch on each candidate's distance went
              // either way unpredictably, and the FLIP pour's encode took 1.07x as long (28.2 against
              // 30.3 MB/s, medians of four alternating runs of `bench codec`; the same pairs). A
              // candidate that passed against a bound that has shrunk since is refused by
              // keep_nearest(), which compares with the worst kept.
              for (std::uint32_t t = t0; t < t1; t += 64) {
                const std::uint32_t end = std::min(t1, t + 64);
                std::uint64_t pass = 0;
                std::uint32_t u = t;
#if defined(__SSE2__)
                const __m128i limit4 = _mm_set1_epi32(within);
                for (; u + 4 <= end; u += 4) {
                  const __m128i d = _mm_loadu_si128(reinterpret_cast<const __m128i*>(pe + u));
                  const int over = _mm_movemask_ps(_mm_castsi128_ps(_mm_cmpgt_epi32(d, limit4)));
                  pass |= std::uint64_t(~over & 15) << (u - t);
                }
#endif
                for (; u < end; ++u) pass |= std::uint64_t(pe[u] <= within) << (u - t);
                for (; pass != 0; pass &= pass - 1) {
                  const std::uint32_t v = t + static_cast<std::uint32_t>(std::countr_zero(pass));
                  keep_nearest(best, found, std::uint64_t(pe[v]) << 32 | porder[v]);
                  if (found == kCandidates) within = static_cast<std::int32_t>(best[kCandidates - 1] >> 32);
                }
              }
            }
          };
          scan(guess);
          if (found < kCandidates && guess < most) scan(static_cast<std::int32_t>(most));
          guess = found == kCandidates
                      ? static_cast<std::int32_t>(std::min<std::int64_t>(most, 2 * std::int64_t(within) + 1))
                      : static_cast<std::int32_t>(most);
          for (int b = 0; b < found; ++b) {
            pslots[std::size_t(i) * kCandidates + std::size_t(b)] =
                Pair{std::int64_t(best[b] >> 32), i, static_cast<std::uint32_t>(best[b])};
          }
          pkept[i] = static_cast<std::uint8_t>(found);
        }
      } else {
        // Otherwise (sparse frames, or grid steps much finer than the spacing) a dense grid of cells
        // of half the candidates' side (a liquid fills a small part of its box, so a side-`cell`
        // cell holds about ten particles), or of their side, visited nearest first until the 8 kept
        // are closer than any cell left; a cell's particles are one range found by indexing.
        std::int64_t side = std::max<std::int64_t>(1, cell / 2), g0[3], dims[3];
        double total = 1;
        for (int pass = 0; pass < 2; ++pass) {
          total = 1;
          for (int a = 0; a < 3; ++a) {
            g0[a] = floordiv(lo[a], side);
            dims[a] = floordiv(hi[a], side) - g0[a] + 1;
            total *= double(dims[a]);
          }
          if (total <= most_cells || side == cell) break;
          side = cell;
        }
        if (total <= most_cells) {
          const auto index = [&](const std::int64_t* q) {
            return std::size_t(((floordiv(q[0], side) - g0[0]) * dims[1] + (floordiv(q[1], side) - g0[1])) * dims[2] +
                               (floordiv(q[2], side) - g0[2]));
          };
          if (!prepared) {
            // This frame's particles in cell order, their positions and cells copied beside them.
            by_cell(
                std::size_t(total), n, [&](std::uint32_t j) { return index(&at[std::size_t(j) * 6]); }, start, order);
            sorted.resize(std::size_t(n) * 6);
            for (std::uint32_t t = 0; t < n; ++t)
              std::copy_n(&at[std::size_t(order[t]) * 6], 6, &sorted[std::size_t(t) * 6]);
            // Cell offsets by the least squared distance a particle in one can be from a particle in
            // the other (whole cells between them), up to the reach.
            const int far = static_cast<int>(std::sqrt(double(reach)) / double(side)) + 2;
            for (int x = -far; x <= far; ++x)
              for (int y = -far; y <= far; ++y)
                for (int z = -far; z <= far; ++z) {
                  std::int64_t bound = 0;
                  for (int d : {x, y, z}) {
                    const std::int64_t gap = std::int64_t(std::max(0, std::abs(d) - 1)) * side;  // cells between
                    bound += gap * gap;
                  }
                  if (bound <= reach) offsets.push_back({bound, {x, y, z}});
                }
            std::stable_sort(offsets.begin(), offsets.end(),
                             [](const Offset& u, const Offset& v) { return u.bound < v.bound; });
          }
          // The previous particles by cell (outside the box: its nearest cell), so that searches one
          // after another visit the same cells.
          std::vector<std::uint32_t>&visit_start = m.visit_start, &visit = m.visit;
          const auto home_cell = [&](std::uint32_t u) {
            std::int64_t c[3];
            for (int a = 0; a < 3; ++a) {
              const std::int64_t v = from(previous[u], a);
              c[a] = std::clamp<std::int64_t>(floordiv(v, side) - g0[a], 0, dims[a] - 1);
            }
            return static_cast<std::size_t>((c[0] * dims[1] + c[1]) * dims[2] + c[2]);
          };
          if (in_cell_order) {
            by_cell(std::size_t(total), searched, home_cell, visit_start, visit);
          } else {
            visit.resize(searched);
            std::iota(visit.begin(), visit.end(), 0u);
          }
          for (const std::uint32_t u : visit) {
            search(previous[u],
                   [&](const std::int64_t* p, const std::int64_t*, const auto& consider, const auto& worst) {
                     const std::int64_t c[3] = {floordiv(p[0], side) - g0[0], floordiv(p[1], side) - g0[1],
                                                floordiv(p[2], side) - g0[2]};
                     for (const Offset& o : offsets) {
                       if (o.bound > worst()) break;
                       const std::int64_t x = c[0] + o.d[0], y = c[1] + o.d[1], z = c[2] + o.d[2];
                       if (x < 0 || x >= dims[0] || y < 0 || y >= dims[1] || z < 0 || z >= dims[2]) continue;
                       const std::size_t k = std::size_t((x * dims[1] + y) * dims[2] + z);
                       for (std::uint32_t t = start[k]; t < start[k + 1] && worst() >= 0; ++t)
                         consider(order[t], &sorted[std::size_t(t) * 6]);
                     }
                   });
          }
        } else {
          // Otherwise this frame's particles sorted by cell: a cell's particles are one range, found
          // by a binary search.
          if (!prepared) {
            sorted_cells.resize(n);
            for (std::uint32_t j = 0; j < n; ++j) {
              const std::int64_t* q = &at[std::size_t(j) * 6 + 3];
              sorted_cells[j] = {cell_key(q[0], q[1], q[2]), j};
            }
            std::sort(sorted_cells.begin(), sorted_cells.end());
          }
          for (const std::uint32_t i : previous) {
            search(i, [&](const std::int64_t*, const std::int64_t* home, const auto& consider, const auto& worst) {
              for (std::int64_t dx = -1; dx <= 1; ++dx)
                for (std::int64_t dy = -1; dy <= 1; ++dy)
                  for (std::int64_t dz = -1; dz <= 1; ++dz) {
                    const std::uint64_t k = cell_key(home[0] + dx, home[1] + dy, home[2] + dz);
                    auto it =
                        std::lower_bound(sorted_cells.begin(), sorted_cells.end(), std::pair{k, std::uint32_t{0}});
                    for (; it != sorted_cells.end() && it->first == k && worst() >= 0; ++it)
                      consider(it->second, &at[std::size_t(it->second) * 6]);
                  }
            });
          }
        }
      }
      prepared = true;
    };
    // The steps of the previous particles `previous` along their stored velocities.
    const auto step_along = [&](std::span<const std::uint32_t> previous) {
      steps.resize(std::size_t(state_.count) * 3);
      for (const std::uint32_t i : previous)
        for (int a = 0; a < 3; ++a) steps[std::size_t(i) * 3 + std::size_t(a)] = velocity_step(i, a);
    };
    std::vector<std::uint32_t>& all = m.all;
    all.resize(state_.count);
    std::iota(all.begin(), all.end(), 0u);
    // A previous particle with a current one at exactly its place (a FLIP inflow re-seeds its
    // particles where it seeded them: a fifth of the pour's, and more in its first frames) keeps
    // that one alone as its candidate, without a search: it is the nearest of the six a search
    // would keep, and the pairing below takes it first. A second previous particle at the same
    // place is searched, as the ones without are. The FLIP pour cooks to the same bytes, its
    // `[x y z scale]` encode 1.07-1.13x as fast (docs/compression-experiments.md, "Particles that
    // stay put, paired without a search"); a clip with none costs a table lookup a particle.
    std::vector<std::uint32_t>& rest = m.rest;
    rest.clear();
    ExactPlaces& places = m.places;
    places.build(n, at.data());
    std::vector<std::uint8_t>& claimed = m.claimed;
    claimed.assign(n, 0);
    for (std::uint32_t i = 0; i < state_.count; ++i) {
      const std::int64_t q[3] = {from(i, 0), from(i, 1), from(i, 2)};  // where it was (moved is null)
      const std::uint32_t j = places.find(q);
      if (j == ExactPlaces::kNone || claimed[j]) {  // a later one at a shared place is searched
        rest.push_back(i);
        continue;
      }
      claimed[j] = 1;
      slots[std::size_t(i) * kCandidates] = Pair{0, i, j};
      kept[i] = 1;
    }
    searches(rest, true);  // from where they were
    // A cache without ids whose particles persist (a particle system without its ids) moves them
    // further than their spacing: the nearest particle is another one, and the clip costs about
    // 4x what it does with ids. Moved on by their stored velocities they are found again; a FLIP
    // liquid's are not (its solver re-samples them: moved, they land no nearer). So on a sample of
    // up to kVelocitySample previous particles, the nearest candidates from both places are
    // compared, and the frame is matched from where they land nearer by more than half (in the
    // sum of squared distances).
    if (velocity_k_[0] >= 0 && state_.count > 0) {
      // The encoder's own sample (playback's kMotionSample is another test, of a decoded pair).
      constexpr std::uint32_t kVelocitySample = 256;
      const std::uint32_t every = (state_.count + kVelocitySample - 1) / kVelocitySample;
      std::vector<std::uint32_t>& sample = m.sample;
      sample.clear();
      for (std::uint32_t i = every / 2; i < state_.count; i += every) sample.push_back(i);
      const auto cost = [&] {
        std::int64_t sum = 0;
        for (const std::uint32_t i : sample)
          sum += kept[i] != 0 ? slots[std::size_t(i) * kCandidates].distance : reach + 1;
        return sum;
      };
      const std::int64_t still = cost();
      std::vector<Pair>& saved = m.saved;
      std::vector<std::uint8_t>& saved_kept = m.saved_kept;
      saved.resize(sample.size() * kCandidates);
      saved_kept.resize(sample.size());
      for (std::size_t u = 0; u < sample.size(); ++u) {
        std::copy_n(&slots[std::size_t(sample[u]) * kCandidates], kCandidates, &saved[u * kCandidates]);
        saved_kept[u] = kept[sample[u]];
      }
      step_along(sample);
      moved = steps.data();
      searches(sample, false);
      if (2 * cost() < still) {
        step_along(all);
        moved = steps.data();
        searches(all, true);
      } else {
        for (std::size_t u = 0; u < sample.size(); ++u) {
          std::copy_n(&saved[u * kCandidates], kCandidates, &slots[std::size_t(sample[u]) * kCandidates]);
          kept[sample[u]] = saved_kept[u];
        }
        moved = nullptr;  // the pairs are from where the particles were
      }
    }
    // The pairs are taken closest first, ties by previous then current index, each previous and
    // current particle once. A previous particle whose nearest candidate has it as its own nearest (by distance, then
    // previous index) makes the first pair, in that order, of either: it is taken, and every later
    // pair of either would be passed over. Only the others' pairs are sorted (on the FLIP pour two
    // thirds of the particles pair this way, and a sixth of the candidate pairs are left).
    std::vector<std::uint8_t>& prev_taken = m.prev_taken;
    prev_taken.assign(state_.count, 0);
    if (reach < (std::int64_t{1} << 32)) {                        // distance << 32 | index keys
      std::vector<std::uint64_t>& nearest_prev = m.nearest_prev;  // per current particle
      nearest_prev.assign(n, ~std::uint64_t{0});
      for (std::uint32_t i = 0; i < state_.count; ++i) {
        for (std::uint32_t b = 0; b < kept[i]; ++b) {
          const Pair& pair = slots[std::size_t(i) * kCandidates + b];
          nearest_prev[pair.cur] = std::min(nearest_prev[pair.cur], std::uint64_t(pair.distance) << 32 | i);
        }
      }
      for (std::uint32_t i = 0; i < state_.count; ++i) {
        if (kept[i] == 0) continue;
        const Pair& first = slots[std::size_t(i) * kCandidates];
        if (nearest_prev[first.cur] != (std::uint64_t(first.distance) << 32 | i)) continue;
        prev_taken[i] = 1;
        match[first.cur] = i;
      }
    }
    // The rest: the pairs were made in previous-index order, each particle's by (distance, current
    // index), so a stable sort by distance is that order. Every distance is within the reach, so
    // the depth sorter's radix sort does it (a comparison sort here was about 15 % of a FLIP cook).
    std::vector<Pair>& pairs = m.pairs;
    pairs.clear();
    for (std::uint32_t i = 0; i < state_.count; ++i) {
      if (prev_taken[i]) continue;
      for (std::uint32_t b = 0; b < kept[i]; ++b) {
        const Pair& pair = slots[std::size_t(i) * kCandidates + b];
        if (match[pair.cur] < 0) pairs.push_back(pair);
      }
    }
    take_closest_first(pairs, reach, match);
    // Particles that persist (matched along their velocities) are born and die: what is left over
    // is not one particle in both frames, and paired it would jump from one to the other.
    if (moved == nullptr) pair_leftovers(n, cell, reach, from, match);
  }

  // Takes `pairs` closest first, each previous and current particle once (the previous ones marked
  // in prev_taken, the current ones' matches set). The pairs are made in previous-index order,
  // each particle's by (distance, current index), so a stable sort by distance is (distance,
  // previous, current) order. Every distance is within the reach, so the depth sorter's radix sort
  // does it (a comparison sort here was about 15 % of a FLIP cook).
  void take_closest_first(const std::vector<Pair>& pairs, std::int64_t reach, std::vector<std::int64_t>& match) {
    MatchScratch& m = match_;
    std::vector<std::uint32_t>& by_distance = m.by_distance;
    by_distance.resize(pairs.size());
    if (reach < (std::int64_t{1} << 32) && pairs.size() < (std::size_t{1} << 32)) {
      std::vector<std::uint64_t>&items = m.items, &scratch = m.scratch;
      items.resize(pairs.size());
      scratch.resize(pairs.size());
      for (std::size_t t = 0; t < pairs.size(); ++t) items[t] = std::uint64_t(pairs[t].distance) << 32 | t;
      const auto radix = reach < (std::int64_t{1} << 16) ? sort::radix_sort_pairs16 : sort::radix_sort_pairs;
      radix(items.data(), scratch.data(), items.size(), by_distance.data());
    } else {
      std::iota(by_distance.begin(), by_distance.end(), 0u);
      std::stable_sort(by_distance.begin(), by_distance.end(),
                       [&](std::uint32_t x, std::uint32_t y) { return pairs[x].distance < pairs[y].distance; });
    }
    for (const std::uint32_t t : by_distance) {
      const Pair& pair = pairs[t];
      if (m.prev_taken[pair.prev] || match[pair.cur] >= 0) continue;
      m.prev_taken[pair.prev] = 1;
      match[pair.cur] = pair.prev;
    }
  }

  // The particles left over by the pairing of plain positions (a liquid's re-sampled particles),
  // paired among themselves within the same reach, closest first. A previous particle is left
  // over when closer pairs took each of its kCandidates nearest; a current one when no previous
  // particle kept it. Each round pairs each leftover with its kCandidates nearest remaining
  // current particles (the closest of all those pairs is always made), until a round finds none
  // within the reach or kLeftoverRounds have run (the FLIP pour needs 3 or 4). They are looked for
  // in the 2x2x2 cells of twice the side nearest each previous particle, which reach at least
  // `cell` from it on every side as the 3x3x3 around its home cell do (8 lookups a particle where
  // there were 27, and take_closest_first()'s radix sort, took this from 340 to 225 us a frame of
  // the pour, about a tenth of its encode).
  //
  // Each such pair would otherwise be a drop and a new particle. On the FLIP pour a tenth of the
  // previous particles were left over (337 a frame of 3,431): their drops split the survivors into
  // runs of 11 and cost the decoder a branch it mispredicts per run and coded word, and a new
  // particle costs about what a survivor's larger residual does. Paired, the pour has 54 operations
  // a frame instead of 262, is 2.9 % smaller and decodes about 1.4x as fast (docs/compression-experiments.md,
  // "The leftovers paired").
  static constexpr int kLeftoverRounds = 16;
  static constexpr std::uint32_t kLeftoverReads = 64;
  template <class From>
  void pair_leftovers(std::uint32_t n, std::int64_t cell, std::int64_t reach, const From& from,
                      std::vector<std::int64_t>& match) {
    MatchScratch& m = match_;
    const std::int64_t side = 2 * cell;
    std::vector<Spare>& spare = m.spare;
    spare.clear();
    for (std::uint32_t j = 0; j < n; ++j) {
      if (match[j] >= 0) continue;
      const std::int64_t* q = &m.at[std::size_t(j) * 6];
      spare.push_back(
          Spare{cell_key(floordiv(q[0], side), floordiv(q[1], side), floordiv(q[2], side)), {q[0], q[1], q[2]}, j});
    }
    std::sort(spare.begin(), spare.end());
    std::vector<std::uint32_t>& left = m.left;  // the previous particles left over
    left.clear();
    for (std::uint32_t i = 0; i < state_.count; ++i)
      if (!m.prev_taken[i]) left.push_back(i);
    std::vector<Pair>& pairs = m.pairs;
    CellRanges& cells = m.spare_cells;
    // Candidates read in all rounds, at most kLeftoverReads a particle of the frame.
    const std::uint64_t budget = std::uint64_t(kLeftoverReads) * n;
    std::uint64_t read = 0;
    // A search that read its cells whole and kept fewer than kCandidates found every current
    // particle within the reach of it: later rounds take those of its candidates still left over
    // (current particles only leave `spare`), the same pairs its search would find, without
    // searching again, and one that found none is dropped. `known[i]` is then 1 + its count of
    // candidates, kept in its slots (the pairing before no longer needs them). At the pour's
    // resolution 120 the later rounds had made 45 % of the reads, nearly all finding nothing: its
    // encode is about 1.07x as fast (docs/compression-experiments.md, "The leftovers' complete
    // searches kept").
    std::vector<std::uint8_t>& known = m.known;
    known.assign(state_.count, 0);
    Pair* const slots = m.slots.data();
    for (int round = 0; round < kLeftoverRounds && !left.empty() && !spare.empty() && read < budget; ++round) {
      cells.build(spare);
      pairs.clear();
      for (const std::uint32_t i : left) {
        if (known[i] != 0) {
          for (int b = 0; b < known[i] - 1; ++b) {
            const Pair& pair = slots[std::size_t(i) * kCandidates + std::size_t(b)];
            if (match[pair.cur] < 0) pairs.push_back(pair);
          }
          continue;
        }
        if (read == budget) break;
        const std::int64_t p[3] = {from(i, 0), from(i, 1), from(i, 2)};
        std::int64_t first[3];  // the 2x2x2 cells' lowest corner: the particle in the nearer half of its cell
        for (int a = 0; a < 3; ++a) {
          const std::int64_t c = floordiv(p[a], side);
          first[a] = p[a] - c * side < cell ? c - 1 : c;
        }
        std::pair<std::int64_t, std::uint32_t> best[kCandidates];  // (distance, current index)
        int found = 0;
        const auto most = static_cast<std::uint32_t>(std::min<std::uint64_t>(kMostRead, budget - read));
        std::uint32_t unread = most;
        for (int d = 0; d < 8 && unread > 0; ++d) {
          auto [t0, t1] = cells.find(cell_key(first[0] + (d & 1), first[1] + (d >> 1 & 1), first[2] + (d >> 2)));
          t1 = t0 + std::min(t1 - t0, unread);
          unread -= t1 - t0;
          for (std::uint32_t t = t0; t < t1; ++t) {
            const std::int64_t e = squared_distance(spare[t].q, p);
            if (e <= reach) keep_nearest(best, found, std::pair{e, spare[t].j});
          }
        }
        for (int b = 0; b < found; ++b) pairs.push_back(Pair{best[b].first, i, best[b].second});
        if (unread > 0 && found < kCandidates) {
          known[i] = static_cast<std::uint8_t>(1 + found);
          for (int b = 0; b < found; ++b) slots[std::size_t(i) * kCandidates + std::size_t(b)] = pairs.end()[b - found];
        }
        read += most - unread;
      }
      if (pairs.empty()) break;
      take_closest_first(pairs, reach, match);
      std::erase_if(left, [&](std::uint32_t i) { return m.prev_taken[i] != 0 || known[i] == 1; });
      std::erase_if(spare, [&](const Spare& c) { return match[c.j] >= 0; });
    }
  }

  void header(std::vector<std::byte>& body, std::uint32_t count, std::uint32_t prev, std::uint32_t ops,
              std::uint32_t fresh) {
    put(body, count);
    put(body, prev);
    put(body, ops);
    put(body, fresh);
  }

  // New particle values: spatial deltas in output order.
  static std::vector<std::uint32_t> spatial(std::span<const std::uint32_t> values) {
    std::vector<std::uint32_t> r(values.size());
    std::uint32_t before = 0;
    for (std::size_t t = 0; t < values.size(); ++t) {
      r[t] = zigzag(values[t] - before);
      before = values[t];
    }
    return r;
  }

  static unsigned width(std::span<const std::uint32_t> zz) {
    std::uint32_t m = 0;
    for (std::uint32_t v : zz) m |= v;
    return bytes_for(m);
  }

  // The operations that take the previous frame (the state) to the output `order`: walking the
  // output, a survivor of previous index i drops what lies before it, a new particle is inserted.
  struct Operations {
    std::vector<Op> ops;
    std::vector<std::uint8_t> is_new;          // per output particle
    std::vector<std::uint32_t> survivor_prev;  // per kept particle, in output order
  };
  Operations operations_of(const std::vector<std::uint32_t>& order, const std::vector<std::int64_t>& match) const {
    const auto n = static_cast<std::uint32_t>(order.size());
    Operations out;
    std::vector<Op>& ops = out.ops;
    out.is_new.assign(n, 0);
    std::uint32_t cursor = 0;
    const auto add = [&](std::uint32_t keep, std::uint32_t drop, std::uint32_t insert) {
      if (ops.empty() || (keep && (ops.back().drop || ops.back().insert)) || (drop && ops.back().insert))
        ops.push_back({});
      ops.back().keep += keep;
      ops.back().drop += drop;
      ops.back().insert += insert;
    };
    for (std::uint32_t j = 0; j < n; ++j) {
      const std::int64_t i = match[order[j]];
      if (i < 0) {
        out.is_new[j] = 1;
        add(0, 0, 1);
        continue;
      }
      const auto ui = static_cast<std::uint32_t>(i);
      if (ui < cursor) throw Error("particle codec: survivors out of the previous frame's order (internal)");
      if (ui > cursor) add(0, ui - cursor, 0);
      add(1, 0, 0);
      out.survivor_prev.push_back(ui);
      cursor = ui + 1;
    }
    if (cursor < state_.count) add(0, state_.count - cursor, 0);
    return out;
  }

  void put_ops(std::vector<std::byte>& body, const std::vector<Op>& ops) {
    for (const Op& op : ops) {
      put(body, op.keep);
      put(body, op.drop);
      put(body, op.insert);
    }
  }

  std::vector<std::byte> keyframe_body(const std::vector<std::uint32_t>& order,
                                       const std::vector<std::int64_t>& match) {
    const auto n = static_cast<std::uint32_t>(order.size());
    EncoderState next;
    next.count = n;
    next.q.resize(plan_.coded.size());
    next.d.resize(plan_.coded.size());
    std::vector<std::vector<std::uint32_t>> fresh(plan_.coded.size()), motion(plan_.coded.size());
    for (std::size_t k = 0; k < plan_.coded.size(); ++k) {
      next.q[k].resize(n);
      next.d[k].resize(n);
      for (std::uint32_t j = 0; j < n; ++j) {
        const std::uint32_t s = order[j];
        next.q[k][j] = source_[k][s];
        next.d[k][j] = match[s] >= 0 ? source_[k][s] - state_.q[k][std::size_t(match[s])] : birth(k, s);
      }
      fresh[k] = spatial(next.q[k]);
      motion[k] = spatial(next.d[k]);
    }
    // Derived words (particle_decoder.cpp, derive()): a particle that continues one from before has
    // its step as motion and the step before it as its prior step, when the decoder would have
    // known one (a step after a step, and not standing still); a new one has motion 0 and its seed
    // (the source velocity's step) as its prior step.
    std::vector<std::vector<std::uint32_t>> prior(plan_.coded.size());
    if (!plan_.derived.empty()) {
      std::vector<std::uint8_t> moving(n, 0);
      for (const WordPlan::Derived& dw : plan_.derived)
        for (std::uint32_t j = 0; j < n; ++j) moving[j] |= (match[order[j]] >= 0 && next.d[dw.from][j] != 0) ? 1 : 0;
      std::vector<std::uint8_t> two(n, 0), seeded(n, 0);
      for (const WordPlan::Derived& dw : plan_.derived) {
        std::vector<std::uint32_t> before(n, 0), step(next.d[dw.from]);
        for (std::uint32_t j = 0; j < n; ++j) {
          const std::int64_t i = match[order[j]];
          if (i < 0) {
            before[j] = step[j];  // the seed
            step[j] = 0;
            seeded[j] |= before[j] != 0 ? 1 : 0;
          } else if (moving[j] && has_step(state_.steps[std::size_t(i)])) {
            before[j] = state_.d[dw.from][std::size_t(i)];
            two[j] |= before[j] != 0 ? 1 : 0;
          } else if (moving[j] && state_.steps[std::size_t(i)] == kSeeded) {
            // A step after its seed: the prior that makes the keyframe's second-order difference
            // (3·d0 − prior) the parabola through both (4·d0 − 2·seed).
            before[j] = 2u * state_.d[dw.from][std::size_t(i)] - step[j];
            two[j] |= before[j] != 0 ? 1 : 0;
          }
        }
        motion[dw.from] = spatial(step);
        prior[dw.from] = spatial(before);
      }
      next.steps.resize(n);
      for (std::uint32_t j = 0; j < n; ++j)
        next.steps[j] = moving[j] ? (two[j] ? kTwoSteps : kOneStep) : seeded[j] ? kSeeded : kNoStep;
    }
    // Links to the frame before (version 6, id order): its matching, for playback and export; the
    // particles still decode as new. The clip's first frame has none before it.
    std::vector<Op> links;
    if (info_.keyframe_links && info_.order == FrameOrder::Id && follows_a_frame_)
      links = operations_of(order, match).ops;
    std::vector<std::byte> body;
    header(body, n, links.empty() ? 0 : state_.count, static_cast<std::uint32_t>(links.size()), n);
    for (std::size_t k = 0; k < plan_.coded.size(); ++k) {
      put(body, std::uint8_t{kPrevious});
      put(body, std::uint8_t{0});
      put(body, static_cast<std::uint8_t>(width(fresh[k])));
      put(body, static_cast<std::uint8_t>(width(motion[k])));
      put(body, std::uint8_t{0});  // no bias: a keyframe predicts nothing from before
      put(body, static_cast<std::uint8_t>(width(prior[k])));
      put(body, std::uint16_t{0});
    }
    if (plan_.id_word >= 0) put(body, std::uint32_t{0});
    put_ops(body, links);
    std::vector<std::uint64_t> id_residual = ids_for(order, next, std::vector<std::uint8_t>(n, 1));
    for (std::size_t k = 0; k < plan_.coded.size(); ++k) {
      write_planes(body, fresh[k], width(fresh[k]));
      write_planes(body, motion[k], width(motion[k]));
      write_planes(body, prior[k], width(prior[k]));
    }
    write_id_planes(body, id_residual);
    state_ = std::move(next);
    return body;
  }

  // Ids of the output order; returns the zigzagged deltas of the new ones (is_new[j]).
  std::vector<std::uint64_t> ids_for(const std::vector<std::uint32_t>& order, EncoderState& next,
                                     const std::vector<std::uint8_t>& is_new) {
    // The encoder keeps ids whenever it matches by them; the packet holds them only when the
    // record does.
    std::vector<std::uint64_t> residual;
    if (ids_in_.size() != order.size()) return residual;
    next.ids.resize(order.size());
    std::uint64_t before = 0;
    for (std::size_t j = 0; j < order.size(); ++j) {
      next.ids[j] = ids_in_[order[j]];
      if (is_new[j] && plan_.id_word >= 0) residual.push_back(zigzag64(next.ids[j] - before));
      before = next.ids[j];
    }
    return residual;
  }

  void write_id_planes(std::vector<std::byte>& body, const std::vector<std::uint64_t>& residual) {
    if (plan_.id_word < 0) return;
    std::uint64_t m = 0;
    for (std::uint64_t v : residual) m |= v;
    const unsigned bytes = bytes_for(m);
    // The id header sits after the word headers; patch it now that the width is known.
    const std::size_t at = kBodyHeader + plan_.coded.size() * kWordHeader;
    body[at] = static_cast<std::byte>(bytes);
    const std::size_t n = residual.size(), start = body.size();
    body.resize(start + n * bytes);
    for (unsigned b = 0; b < bytes; ++b) {
      for (std::size_t t = 0; t < n; ++t) body[start + b * n + t] = static_cast<std::byte>(residual[t] >> (8 * b));
    }
  }

  std::vector<std::byte> predicted_body(const std::vector<std::uint32_t>& order,
                                        const std::vector<std::int64_t>& match) {
    const auto n = static_cast<std::uint32_t>(order.size());
    const Operations operations = operations_of(order, match);
    const std::vector<Op>& ops = operations.ops;
    const std::vector<std::uint8_t>& is_new = operations.is_new;
    const std::vector<std::uint32_t>& survivor_prev = operations.survivor_prev;
    std::uint32_t new_count = 0;
    for (std::uint8_t v : is_new) new_count += v;

    EncoderState next;
    next.count = n;
    next.q.resize(plan_.coded.size());
    next.d.resize(plan_.coded.size());
    struct Choice {
      std::uint8_t predictor;
      std::vector<std::uint32_t> bias, keep, fresh, motion;  // bias: zigzagged deltas, one per block
    };
    std::vector<Choice> choices(plan_.coded.size());
    const std::size_t kept = survivor_prev.size();
    std::vector<std::uint32_t> prev_r(kept), lin_r(kept), prev_q, lin_q, scratch;
    // Per block of survivors, its median residual as the bias; the residuals it leaves, zigzagged.
    const auto biased = [&](const std::vector<std::uint32_t>& r, std::vector<std::uint32_t>& bias,
                            std::vector<std::uint32_t>& out) {
      bias.clear();
      out.resize(r.size());
      std::uint32_t before = 0;
      std::uint64_t cost = 0;
      for (std::size_t b0 = 0; b0 < r.size(); b0 += kBlock) {
        const std::size_t b1 = std::min(r.size(), b0 + kBlock);
        const std::uint32_t m = median_of(std::span(r).subspan(b0, b1 - b0), scratch);
        bias.push_back(zigzag(m - before));
        before = m;
        cost += std::bit_width(bias.back());
        std::uint32_t block_cost = 0;  // at most 1024 x 32
        for (std::size_t t = b0; t < b1; ++t) {
          out[t] = zigzag(r[t] - m);
          block_cost += bit_width_of(out[t]);
        }
        cost += block_cost;
      }
      return cost;
    };
    std::vector<std::uint32_t> lin_bias, lin_keep;
    for (std::size_t k = 0; k < plan_.coded.size(); ++k) {
      std::vector<std::uint32_t>& q = next.q[k];
      q.resize(n);
      for (std::uint32_t j = 0; j < n; ++j) q[j] = source_[k][order[j]];
      std::size_t t = 0;
      const WordCodingEntry& entry = info_.words[plan_.coded[k]];
      // A Relative word's survivors get each predictor's own codes: of those within the bound, the
      // nearest to its prediction. Other words' codes are the nearest, whatever the predictor.
      const bool in_loop = entry.coding == WordCoding::Relative;
      prev_q.resize(in_loop ? kept : 0);
      lin_q.resize(in_loop ? kept : 0);
      for (std::uint32_t j = 0; j < n; ++j) {
        if (is_new[j]) continue;
        const std::uint32_t i = survivor_prev[t], previous = state_.q[k][i], linear = previous + state_.d[k][i];
        std::uint32_t for_previous = q[j], for_linear = q[j];
        if (in_loop) {
          const std::uint32_t bits = raw_[k][order[j]];
          prev_q[t] = for_previous = relative_toward(bits, q[j], previous, entry);
          lin_q[t] = for_linear = relative_toward(bits, q[j], linear, entry);
        }
        prev_r[t] = for_previous - previous;
        lin_r[t] = for_linear - linear;
        ++t;
      }
      // Both predictors with their block biases; keep the one with the smaller residuals.
      Choice& ch = choices[k];
      const std::uint64_t prev_cost = biased(prev_r, ch.bias, ch.keep);
      const std::uint64_t lin_cost = biased(lin_r, lin_bias, lin_keep);
      ch.predictor = kPrevious;
      if (lin_cost < prev_cost) {
        ch.predictor = kLinear;
        ch.bias.swap(lin_bias);
        ch.keep.swap(lin_keep);
      }
      if (in_loop) {  // the chosen predictor's codes and steps
        const std::vector<std::uint32_t>& codes = ch.predictor == kLinear ? lin_q : prev_q;
        t = 0;
        for (std::uint32_t j = 0; j < n; ++j) {
          if (is_new[j]) continue;
          q[j] = codes[t];
          prev_r[t] = q[j] - state_.q[k][survivor_prev[t]];
          ++t;
        }
      }
      // The decoder's state: a survivor's step is its residual plus the prediction's step.
      next.d[k].resize(n);
      t = 0;
      std::uint32_t before = 0, step_before = 0;
      for (std::uint32_t j = 0; j < n; ++j) {
        if (is_new[j]) {
          // A Relative word's code in the loop here too: the one nearest the particle before it
          // (the demo fountain's first 120 frames 0.3 % smaller, the sparks' random radii 0.03 %
          // larger; in a keyframe it made the demo larger).
          if (in_loop) q[j] = relative_toward(raw_[k][order[j]], q[j], before, entry);
          ch.fresh.push_back(zigzag(q[j] - before));
          next.d[k][j] = birth(k, order[j]);
          ch.motion.push_back(zigzag(next.d[k][j] - step_before));
          step_before = next.d[k][j];
        } else {
          next.d[k][j] = prev_r[t++];
        }
        before = q[j];
      }
    }
    if (!plan_.derived.empty()) {  // the decoder's step counts (particle_decoder.cpp, derive())
      next.steps.resize(n);
      std::size_t t = 0;
      for (std::uint32_t j = 0; j < n; ++j) {
        if (is_new[j]) {
          bool one = false;
          for (const WordPlan::Derived& dw : plan_.derived) one = one || next.d[dw.from][j] != 0;
          next.steps[j] = one ? kSeeded : kNoStep;
        } else {
          next.steps[j] = after_step(state_.steps[survivor_prev[t++]]);
        }
      }
    }
    // Survivors' residuals as nibbles (format version 5) while most are below 15: zstd makes half
    // the bytes and its optimal parser runs on half the input (the sparks and the demo fountain
    // cook about 2.3 times as fast, 1.2 % and 0.2 % smaller). A word keeps its packing through the
    // group unless its share of escapes leaves a band, judged on frames of 1024 survivors or
    // more: to byte planes above 25 %, back to nibbles at 10 % or less. A change costs zstd the
    // match history of the frames before: changing with every frame either side of 12.5 % made
    // the sparks 2.7 % larger; the FLIP pour, whose residuals grow from 0 to 55 % escapes over
    // its first 20 frames, changes once (0.16 % larger than with planes throughout, where nibbles
    // throughout were 7 % larger).
    // Per word: its packing, and the keep_bytes its header states (the escape planes' width with
    // nibbles, the planes' otherwise).
    std::vector<std::uint8_t> packing(choices.size(), kBytePlanes), keep_bytes(choices.size());
    for (std::size_t k = 0; k < choices.size(); ++k) {
      const std::vector<std::uint32_t>& keep = choices[k].keep;
      keep_bytes[k] = static_cast<std::uint8_t>(width(keep));
      if (keep_bytes[k] == 0) continue;  // nothing stored either way
      const std::size_t escapes =
          std::size_t(std::count_if(keep.begin(), keep.end(), [](std::uint32_t v) { return v >= kNibbleEscape; }));
      if (keep.size() >= kBlock && info_.nibbles) {
        if (nibbles_[k] != 0 && escapes * 4 > keep.size()) nibbles_[k] = 0;
        if (nibbles_[k] == 0 && escapes * 10 <= keep.size()) nibbles_[k] = 1;
      }
      if (nibbles_[k] == 0) continue;
      // Never more than 4 bytes a survivor, as the body's bound counts (only escapes of 4 bytes
      // could take more).
      const unsigned escape_width = escape_bytes(keep);
      if ((keep.size() + 1) / 2 + escapes * escape_width <= keep.size() * 4) {
        packing[k] = kNibbles;
        keep_bytes[k] = static_cast<std::uint8_t>(escape_width);
      }
    }
    std::vector<std::byte> body;
    header(body, n, state_.count, static_cast<std::uint32_t>(ops.size()), new_count);
    for (std::size_t k = 0; k < choices.size(); ++k) {
      const Choice& ch = choices[k];
      put(body, ch.predictor);
      put(body, keep_bytes[k]);
      put(body, static_cast<std::uint8_t>(width(ch.fresh)));
      put(body, static_cast<std::uint8_t>(width(ch.motion)));
      put(body, static_cast<std::uint8_t>(width(ch.bias)));
      put(body, std::uint8_t{0});
      put(body, packing[k]);
      put(body, std::uint8_t{0});
    }
    std::vector<std::uint64_t> id_residual = ids_for(order, next, is_new);
    if (plan_.id_word >= 0) put(body, std::uint32_t{0});
    put_ops(body, ops);
    for (std::size_t k = 0; k < choices.size(); ++k) {
      const Choice& ch = choices[k];
      write_planes(body, ch.bias, width(ch.bias));
      if (packing[k] == kNibbles)
        write_nibbles(body, ch.keep, keep_bytes[k]);
      else
        write_planes(body, ch.keep, keep_bytes[k]);
      write_planes(body, ch.fresh, width(ch.fresh));
      write_planes(body, ch.motion, width(ch.motion));
    }
    write_id_planes(body, id_residual);
    state_ = std::move(next);
    return body;
  }

 public:
  std::array<float, 6> bounds() const {
    constexpr float inf = std::numeric_limits<float>::infinity();
    std::array<float, 6> b{inf, inf, inf, -inf, -inf, -inf};
    for (int a = 0; a < 3; ++a) {
      const WordCodingEntry& e = info_.words[std::size_t(a)];
      if (e.coding == WordCoding::Quantized && e.step > 0 && state_.count > 0) {
        // dequantize() never decreases as q grows: the extremes are those of the grid values.
        const auto [lo, hi] = signed_extremes(std::span(state_.q[std::size_t(position_k_[a])]).first(state_.count));
        b[std::size_t(a)] = dequantize(static_cast<std::uint32_t>(lo), e.step, as_float(e.base));
        b[std::size_t(a) + 3] = dequantize(static_cast<std::uint32_t>(hi), e.step, as_float(e.base));
        continue;
      }
      for (std::uint32_t j = 0; j < state_.count; ++j) {
        float v;
        if (e.coding == WordCoding::Constant) {
          v = as_float(e.base);
        } else {
          const std::uint32_t q = state_.q[std::size_t(position_k_[a])][j];
          v = e.coding == WordCoding::Quantized ? dequantize(q, e.step, as_float(e.base)) : as_float(q);
        }
        b[std::size_t(a)] = std::min(b[std::size_t(a)], v);
        b[std::size_t(a) + 3] = std::max(b[std::size_t(a) + 3], v);
      }
    }
    return b;
  }

 private:
  const CodecInfo& info_;
  WordPlan plan_;
  std::uint32_t record_size_ = 0;
  int position_k_[3] = {-1, -1, -1};
  int velocity_k_[3] = {-1, -1, -1};  // a stored velocity's coded words, for frames matched by position
  EncoderState state_;
  bool follows_a_frame_ = false;  // state_ is the frame before the one being encoded
  std::vector<std::vector<std::uint32_t>> source_;
  std::vector<std::vector<std::uint32_t>> raw_;    // per Relative word and source particle: the float's bits
  std::vector<std::vector<std::uint32_t>> birth_;  // per coded word and source particle (or empty)
  std::span<const std::uint64_t> ids_in_;
  ZSTD_CCtx* zstd_ = nullptr;
  std::vector<std::uint8_t> nibbles_;  // per coded word: its survivors' residuals are packed as nibbles
  MatchScratch match_;                 // match_by_position()'s working memory, kept from frame to frame
};

}  // namespace

std::vector<EncodedFrame> encode_group(const CodecInfo& info, std::span<const SourceFrame> frames,
                                       std::span<const SourceFrame> before, std::uint64_t first_index) {
  GroupEncoder encoder(info);
  // The last two frames before the group seed the keyframe's motion state only.
  const std::size_t seeds = std::min<std::size_t>(before.size(), 2);
  for (std::size_t b = before.size() - seeds; b < before.size(); ++b)
    (void)encoder.encode(before[b], b == before.size() - seeds, first_index - (before.size() - b));
  std::vector<EncodedFrame> out;
  out.reserve(frames.size());
  for (std::size_t f = 0; f < frames.size(); ++f) out.push_back(encoder.encode(frames[f], f == 0, first_index + f));
  return out;
}

}  // namespace pstream::format
