// The particle codec's encoder (docs/format.md, "The particle codec"): quantisation, frames
// ordered so that persisting particles are predicted from the frame before, residuals in byte
// planes compressed by zstd. Its reconstruction is the decoder's output, bit for bit.
#define ZSTD_STATIC_LINKING_ONLY  // ZSTD_c_useBlockSplitter and ZSTD_getCParams (exported by libzstd)
#include <zstd.h>

#include <array>
#include <bit>
#include <span>

#include "format/particle_common.hpp"
#include "format/particle_matching.hpp"
#include "format/zstd_memory.hpp"

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
      case FrameOrder::Matched: match_by_position(n, match); break;
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

  // Pairs the frame's particles with the frame before's by position (particle_matching.hpp).
  void match_by_position(std::uint32_t n, std::vector<std::int64_t>& match) {
    if (position_k_[0] < 0 || position_k_[1] < 0 || position_k_[2] < 0) return;
    GridPoints previous{.q = {}, .count = state_.count}, current{.q = {}, .count = n};
    GridVelocity velocity;
    for (std::size_t a = 0; a < 3; ++a) {
      previous.q[a] = state_.q[std::size_t(position_k_[a])].data();
      current.q[a] = source_[std::size_t(position_k_[a])].data();
      if (velocity_k_[a] < 0) continue;
      const WordCodingEntry& v = info_.words[std::size_t(info_.velocity_word) + a];
      velocity.q[a] = state_.q[std::size_t(velocity_k_[a])].data();
      velocity.step[a] = v.step;
      velocity.origin[a] = as_float(v.base);
      velocity.position_step[a] = double(info_.words[a].step);
    }
    velocity.frame_seconds = info_.frame_seconds;
    matcher_.match(previous, velocity, current, match);
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
  PositionMatcher matcher_;            // pairs a clip's frames without ids
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
