// The particle codec's decoder (docs/format.md, "The particle codec"): a FrameUnit that keeps the
// previous frame's state and reconstructs each packet bit for bit as the encoder did. It builds
// and links without the encoder.
//
// Every record word is a 32-bit channel. A coded word (quantised or exact) keeps, per particle,
// its value q and its last step d = q - q_previous (wrapping 32-bit arithmetic). A persisting
// particle is predicted as q1 + bias (previous) or q1 + d1 + bias (linear), the predictor chosen
// per word and frame, the bias per word and block of 1024 survivors (local coherent motion: gravity,
// drag of a cohort, a swirl); a new particle as the particle before it in the frame plus a
// residual (spatial delta). Encoder and decoder keep identical state, so the encoder's
// reconstruction is the decoder's output, bit for bit.
#include "format/entropy.hpp"
#include "format/frame_unit.hpp"
#include "format/particle_common.hpp"

#include <array>
#include <cstdint>
#include <cstdlib>
#include <string_view>
#include <type_traits>
#include <utility>

// The decoder's kernels are also built for AVX2 (picked at run time, use_avx2()) on x86-64 outside
// the browser; elsewhere only the baseline vectors are.
#if defined(__x86_64__) && !defined(__EMSCRIPTEN__)
#define PSTREAM_DECODER_AVX2 1
#else
#define PSTREAM_DECODER_AVX2 0
#endif
#if defined(__SSE2__) && !defined(__EMSCRIPTEN__)
#include <emmintrin.h>
#define PSTREAM_DECODER_STREAM 1
#else
#define PSTREAM_DECODER_STREAM 0
#endif

namespace pstream::format {
namespace {

using namespace particle;

// ---- the decoding unit ----------------------------------------------------------------------

int stream_window_log(const Metadata& meta) { return meta.version >= kFirstStreamedVersion ? kStreamWindowLog : 0; }

// The decoder's state, buffer by buffer, in elements: what a unit allocates at open, and what
// particle_unit_state_bytes() counts before one is made (a unit's state_bytes() counts what it
// did allocate; the codec tests check that the two agree).
struct StateSizes {
  std::uint64_t words = 0;                    // q_ and d_, each in two states: every coded word of every particle
  std::uint64_t ids = 0;                      // ids_, in two states
  std::uint64_t particles = 0;                // residual_: new particles' values and steps
  std::uint64_t steps = 0;                    // steps_ (bytes), in two states
  std::uint64_t derived = 0;                  // derived_: every derived word of every particle
  std::uint64_t blocks = 0;                   // bias_: one per block of survivors and coded word
  std::uint64_t alive_words = 0;              // alive_: a bit per previous particle, and one word past
  std::uint64_t stride = 0, bias_stride = 0;  // elements from one coded word's to the next's
  std::uint64_t body = 0;                     // body_ (bytes)
  int window_log = 0;                         // the zstd stream's

  StateSizes(const Metadata& meta, const WordPlan& plan) {
    const std::uint64_t n = meta.max_count;
    const bool has_ids = plan.id_word >= 0;
    stride = n + kRunPad;  // SurvivorRuns reads and writes past a run, so each word has room after its own
    words = plan.coded.size() * stride;
    ids = has_ids ? n : 0;
    particles = 2 * n;
    steps = plan.derived.empty() ? 0 : n + kStepPad;  // after_steps() reads and writes past a run
    derived = plan.derived.size() * n;
    bias_stride = (n + kBlock - 1) >> kBlockShift;
    blocks = plan.coded.size() * bias_stride;
    alive_words = (n + 63) / 64 + 1;  // mark_survivors() clears a word past the last particle's
    body = body_capacity(n, plan.coded.size(), has_ids) + kReadPad;
    window_log = stream_window_log(meta);
  }
  std::uint64_t bytes() const {
    return 2 * (2 * words * 4 + ids * 8 + steps) + (particles + derived + blocks) * 4 + alive_words * 8 + body +
           EntropyDecoder::stream_bytes(window_log);
  }
  // A saved state (ParticleUnit::save): the frame's particle count and whether the stream follows
  // (4 bytes each), then per coded word its values
  // and steps, the ids, the step states (max_count of each), then the zstd stream. 0 where the
  // stream cannot be saved.
  std::uint64_t saved_bytes(std::uint64_t max_count, std::size_t coded) const {
    if (window_log > 0 && !EntropyDecoder::can_save_stream()) return 0;
    return 8 + 2 * coded * max_count * 4 + ids * 8 + (steps != 0 ? max_count : 0) +
           EntropyDecoder::stream_bytes(window_log);
  }
};

// ---- records from the state ----------------------------------------------------------------

// Where a record word's values come from in this frame's state, and how a value becomes the
// word's bits: each word of a record is one column.
struct Column {
  enum Kind : std::uint8_t { kDequantize, kShift, kConstant, kIdLow, kIdHigh };
  Kind kind = kConstant;
  const std::uint32_t* values = nullptr;  // kDequantize and kShift (exact and derived words: shift 0)
  const std::uint64_t* ids = nullptr;     // kIdLow and kIdHigh
  float step = 0.0f, origin = 0.0f;       // kDequantize
  std::uint32_t bits = 0;                 // kShift: the shift; kConstant: the value
};

using V = std::uint32_t __attribute__((vector_size(16)));
using V8 = std::uint32_t __attribute__((vector_size(32)));
using I4 = std::int32_t __attribute__((vector_size(16)));
using I8 = std::int32_t __attribute__((vector_size(32)));
using F4 = float __attribute__((vector_size(16)));
using F8 = float __attribute__((vector_size(32)));

// Word c of particles t to t + L - 1 (L = 4 for V, 8 for V8), as the records hold it: `K` is
// c.kind, or kAny for a kind read at run time (four lanes only). The vector is returned through
// a reference: a 32-byte vector passed by value changes the ABI where AVX is not enabled.
constexpr int kAny = -1;
template <int K, class W>
[[gnu::always_inline]] inline void column_lanes(const Column& c, std::uint32_t t, W& out) {
  using I = std::conditional_t<std::is_same_v<W, V>, I4, I8>;
  using F = std::conditional_t<std::is_same_v<W, V>, F4, F8>;
  W q;
  if constexpr (K == Column::kDequantize) {
    std::memcpy(&q, c.values + t, sizeof(W));
    const F scaled = __builtin_convertvector(reinterpret_cast<I>(q), F) * c.step;  // dequantize(), lane by lane
    out = reinterpret_cast<W>(scaled + c.origin);
  } else if constexpr (K == Column::kShift) {
    std::memcpy(&q, c.values + t, sizeof(W));
    out = q << c.bits;  // relative_decode(), lane by lane
  } else if constexpr (K == Column::kConstant) {
    out = W{} + c.bits;
  } else {
    static_assert(std::is_same_v<W, V>);
    switch (c.kind) {
      case Column::kDequantize: return column_lanes<Column::kDequantize>(c, t, out);
      case Column::kShift: return column_lanes<Column::kShift>(c, t, out);
      case Column::kConstant: return column_lanes<Column::kConstant>(c, t, out);
      case Column::kIdLow:
      case Column::kIdHigh: {
        V lo, hi;
        std::memcpy(&lo, c.ids + t, 16);
        std::memcpy(&hi, c.ids + t + 2, 16);
        out = c.kind == Column::kIdLow ? __builtin_shufflevector(lo, hi, 0, 2, 4, 6)
                                       : __builtin_shufflevector(lo, hi, 1, 3, 5, 7);
        return;
      }
    }
    out = V{};
  }
}
std::uint32_t column1(const Column& c, std::uint32_t t) {
  switch (c.kind) {
    case Column::kDequantize: return std::bit_cast<std::uint32_t>(dequantize(c.values[t], c.step, c.origin));
    case Column::kShift: return relative_decode(c.values[t], c.bits);
    case Column::kConstant: return c.bits;
    case Column::kIdLow: return static_cast<std::uint32_t>(c.ids[t]);
    case Column::kIdHigh: return static_cast<std::uint32_t>(c.ids[t] >> 32);
  }
  return 0;
}

// One record's 16 bytes into the output: past the caches when `stream` (x86-64's non-temporal
// store, write_records() says when), else an ordinary store.
[[gnu::always_inline]] inline void put_record16(std::byte* to, const void* from, [[maybe_unused]] bool stream) {
#if PSTREAM_DECODER_STREAM
  if (stream) {
    __m128i v;
    std::memcpy(&v, from, 16);
    _mm_stream_si128(reinterpret_cast<__m128i*>(to), v);
    return;
  }
#endif
  std::memcpy(to, from, 16);
}

// Four words of the records of particles [0, L × groups), from the columns that make them (the
// kind of each known when compiled, or kAny), L = 4 or 8 at a time in vectors W (V or V8): each
// word's values in a register, then 4 × 4 transposes into the records.
template <class W, int K0, int K1, int K2, int K3>
[[gnu::always_inline]] inline void write_group_with(const Column* columns, std::byte* records, std::size_t rs,
                                                    std::uint32_t first, std::uint32_t groups, bool stream) {
  constexpr std::uint32_t L = sizeof(W) / 4;
  const Column c0 = columns[0], c1 = columns[1], c2 = columns[2], c3 = columns[3];
  std::byte* record = records + std::size_t(first) * rs;
  for (std::uint32_t t = first; t < first + L * groups; t += L, record += L * rs) {
    W x, y, z, v;
    column_lanes<K0>(c0, t, x);
    column_lanes<K1>(c1, t, y);
    column_lanes<K2>(c2, t, z);
    column_lanes<K3>(c3, t, v);
    if constexpr (std::is_same_v<W, V>) {
      const V xy01 = __builtin_shufflevector(x, y, 0, 4, 1, 5), zv01 = __builtin_shufflevector(z, v, 0, 4, 1, 5);
      const V xy23 = __builtin_shufflevector(x, y, 2, 6, 3, 7), zv23 = __builtin_shufflevector(z, v, 2, 6, 3, 7);
      const V r0 = __builtin_shufflevector(xy01, zv01, 0, 1, 4, 5),
              r1 = __builtin_shufflevector(xy01, zv01, 2, 3, 6, 7);
      const V r2 = __builtin_shufflevector(xy23, zv23, 0, 1, 4, 5),
              r3 = __builtin_shufflevector(xy23, zv23, 2, 3, 6, 7);
      put_record16(record, &r0, stream);
      put_record16(record + rs, &r1, stream);
      put_record16(record + 2 * rs, &r2, stream);
      put_record16(record + 3 * rs, &r3, stream);
    } else {  // the same in each 16-byte half: records t to t + 3 in the low halves, t + 4 to t + 7 in the high
      const V8 xy = __builtin_shufflevector(x, y, 0, 8, 1, 9, 4, 12, 5, 13);
      const V8 zv = __builtin_shufflevector(z, v, 0, 8, 1, 9, 4, 12, 5, 13);
      const V8 xy2 = __builtin_shufflevector(x, y, 2, 10, 3, 11, 6, 14, 7, 15);
      const V8 zv2 = __builtin_shufflevector(z, v, 2, 10, 3, 11, 6, 14, 7, 15);
      const V8 r04 = __builtin_shufflevector(xy, zv, 0, 1, 8, 9, 4, 5, 12, 13);
      const V8 r15 = __builtin_shufflevector(xy, zv, 2, 3, 10, 11, 6, 7, 14, 15);
      const V8 r26 = __builtin_shufflevector(xy2, zv2, 0, 1, 8, 9, 4, 5, 12, 13);
      const V8 r37 = __builtin_shufflevector(xy2, zv2, 2, 3, 10, 11, 6, 7, 14, 15);
      const auto* b04 = reinterpret_cast<const std::byte*>(&r04);
      const auto* b15 = reinterpret_cast<const std::byte*>(&r15);
      const auto* b26 = reinterpret_cast<const std::byte*>(&r26);
      const auto* b37 = reinterpret_cast<const std::byte*>(&r37);
      put_record16(record, b04, stream);
      put_record16(record + rs, b15, stream);
      put_record16(record + 2 * rs, b26, stream);
      put_record16(record + 3 * rs, b37, stream);
      put_record16(record + 4 * rs, b04 + 16, stream);
      put_record16(record + 5 * rs, b15 + 16, stream);
      put_record16(record + 6 * rs, b26 + 16, stream);
      put_record16(record + 7 * rs, b37 + 16, stream);
    }
  }
}
using WriteGroup = void (*)(const Column*, std::byte*, std::size_t, std::uint32_t, std::uint32_t, bool);
template <int K0, int K1, int K2, int K3>
void write_group(const Column* columns, std::byte* records, std::size_t rs, std::uint32_t first, std::uint32_t groups,
                 bool stream) {
  write_group_with<V, K0, K1, K2, K3>(columns, records, rs, first, groups, stream);
}
#if PSTREAM_DECODER_AVX2
template <int K0, int K1, int K2, int K3>
[[gnu::target("avx2")]] void write_group_avx2(const Column* columns, std::byte* records, std::size_t rs,
                                              std::uint32_t first, std::uint32_t groups, bool stream) {
  write_group_with<V8, K0, K1, K2, K3>(columns, records, rs, first, groups, stream);
}
#endif
// write_group for the 81 mixes of dequantised, shifted and constant columns: column x's kind is
// digit x of the index in base 3.
template <bool Avx2, std::size_t... M>
constexpr auto known_groups(std::index_sequence<M...>) {
#if PSTREAM_DECODER_AVX2
  if constexpr (Avx2)
    return std::array<WriteGroup, sizeof...(M)>{
        &write_group_avx2<int(M % 3), int(M / 3 % 3), int(M / 9 % 3), int(M / 27)>...};
#endif
  return std::array<WriteGroup, sizeof...(M)>{&write_group<int(M % 3), int(M / 3 % 3), int(M / 9 % 3), int(M / 27)>...};
}
constexpr auto kKnownGroups = known_groups<false>(std::make_index_sequence<81>{});
constexpr auto kKnownGroupsAvx2 = known_groups<true>(std::make_index_sequence<81>{});

Op op_at(const Body& b, std::uint32_t o) {
  Op op;
  std::memcpy(&op, b.ops + o * kOpSize, kOpSize);
  return op;
}

// ---- the survivors of a predicted frame ----------------------------------------------------

// One coded word's survivors: its residuals and where its values and steps are.
struct WordRuns {
  SurvivorRuns runs;
  unsigned kind = 0;                                 // runs.kind()
  std::uint32_t linear = 0;                          // ~0 for the linear predictor, else 0
  std::uint32_t *q0 = nullptr, *d0 = nullptr;        // this frame's values and steps
  const std::uint32_t *q1 = nullptr, *d1 = nullptr;  // the previous frame's
};

// The survivors of `count` coded words, in one walk over the operations: each run of survivors
// (split at the blocks' borders, each block has its bias) is predicted word after word, straight
// from the residuals (SurvivorRuns, `Lanes` values a vector). The new particles' places are left
// for insert_new(). With the new particles in the same walk, read from their byte planes one at a
// time, the sparks decoded 3-6 % slower.
template <unsigned Lanes>
[[gnu::always_inline]] inline void walk_survivors(const Body& b, WordRuns* words, std::size_t count) {
  std::uint32_t i = 0, j = 0, kt = 0;
  for (std::uint32_t o = 0; o < b.op_count; ++o) {
    const Op op = op_at(b, o);
    for (std::uint32_t t = 0; t < op.keep;) {
      const std::uint32_t len = std::min(op.keep - t, kBlock - ((kt + t) & (kBlock - 1)));
      for (std::size_t k = 0; k < count; ++k) {
        WordRuns& w = words[k];
        w.runs.run<Lanes>(w.kind, kt + t, len, w.q0 + j + t, w.d0 + j + t, w.q1 + i + t, w.d1 + i + t, w.linear);
      }
      t += len;
    }
    i += op.keep + op.drop;
    j += op.keep + op.insert;
    kt += op.keep;
  }
}

// Every coded word's survivors. A small frame's words share one walk: their values and steps (16
// bytes a survivor and word, the previous frame's read and this one's written) stay in the core's
// caches, and a walk of its own for each word would end each run's loop where the branch predictor
// does not expect it, once per word (the sparks, 5,374 particles at most: 4-8 % slower). Past
// kWordWalkBytes each word walks alone: the words' 4 streams each, 16 for [x y z scale], then come
// from the shared cache or memory, and 4 at a time reach them faster (the demo fountain's first 120
// frames, up to 249k particles: 2.28-2.65 GB/s in one walk, 2.73-3.17 a word at a time, the two
// alternating in one process).
constexpr std::uint64_t kWordWalkBytes = 1 << 20;
inline bool walk_together(const Body& b, std::size_t words) {
  return std::uint64_t(b.keep_total) * words * 16 < kWordWalkBytes;
}
template <unsigned Lanes>
[[gnu::always_inline]] inline void predict_survivors_with(const Body& b, WordRuns* words, std::size_t count) {
  if (walk_together(b, count)) {
    walk_survivors<Lanes>(b, words, count);
  } else {
    for (std::size_t k = 0; k < count; ++k) walk_survivors<Lanes>(b, words + k, 1);
  }
}

// Whether the frame's survivors come first, every new particle after them (every frame of a clip
// matched by position, whose new particles follow its survivors; a frame of a clip ordered by id
// when its new ids are above its survivors'), and if so `alive` marks
// the previous particles that survive, a bit each (the lowest first; read as bytes on x86-64,
// little-endian), zero past prev_count.
[[maybe_unused]] bool mark_survivors(const Body& b, std::uint64_t* alive) {
  std::memset(alive, 0, (std::size_t(b.prev_count) + 63) / 64 * 8 + 8);
  std::uint32_t i = 0, inserted = 0;
  for (std::uint32_t o = 0; o < b.op_count; ++o) {
    const Op op = op_at(b, o);
    if (op.keep != 0) {
      if (inserted != 0) return false;
      const std::uint32_t first = i >> 6, last = (i + op.keep - 1) >> 6;
      const std::uint64_t from = ~std::uint64_t{0} << (i & 63),
                          to = ~std::uint64_t{0} >> (63 - ((i + op.keep - 1) & 63));
      if (first == last) {
        alive[first] |= from & to;
      } else {
        alive[first] |= from;
        for (std::uint32_t w = first + 1; w < last; ++w) alive[w] = ~std::uint64_t{0};
        alive[last] |= to;
      }
    }
    inserted += op.insert;
    i += op.keep + op.drop;
  }
  return true;
}

using PredictSurvivors = void (*)(const Body&, WordRuns*, std::size_t, std::uint64_t*);
void predict_survivors_baseline(const Body& b, WordRuns* words, std::size_t count, std::uint64_t*) {
  predict_survivors_with<4>(b, words, count);
}
#if PSTREAM_DECODER_AVX2
// The same compiled for AVX2: eight survivors a vector instead of two vectors of four. Given
// `alive` (a frame past kWordWalkBytes, or any frame in the fuzzing build), a large frame whose
// survivors come first (mark_survivors(); every frame of a clip without ids, such as the FLIP pour
// re-simulated at resolution 120, up to 353,000 particles a frame, one in eight new) is predicted
// a word at a time in one pass over the previous particles, eight at a time, those that survive
// moved into the lowest lanes: no walk of the runs between deaths, which average 8 survivors
// there. 1.10-1.17x as fast a decode of that clip, 1.05-1.14x at resolution 80
// (docs/compression-experiments.md, "The survivors compacted"); below kWordWalkBytes the walk
// stays, 10 % faster on the fixtures' small frames.
[[gnu::target("avx2")]] void predict_survivors_avx2(const Body& b, WordRuns* words, std::size_t count,
                                                    [[maybe_unused]] std::uint64_t* alive) {
#if PSTREAM_COMPACT_SURVIVORS
  if (alive != nullptr && mark_survivors(b, alive)) {
    for (std::size_t k = 0; k < count; ++k) {
      WordRuns& w = words[k];
      w.runs.compact(w.kind, reinterpret_cast<const std::uint8_t*>(alive), b.prev_count, w.q0, w.d0, w.q1, w.d1,
                     w.linear);
    }
    return;
  }
#endif
  predict_survivors_with<8>(b, words, count);
}
#else
constexpr PredictSurvivors predict_survivors_avx2 = predict_survivors_baseline;  // never chosen: use_avx2() is false
#endif

// One word's new particles, after its survivors, in the frame's order: each is the particle
// before it in the frame plus its value (`fresh`, unzigzagged); its first step the running sum
// of `motion` (version 3), else that of the new particles before it.
void insert_new(const Body& b, bool has_motion, std::uint32_t* q0, std::uint32_t* d0, const std::uint32_t* fresh,
                const std::uint32_t* motion) {
  std::uint32_t j = 0, nt = 0, step = 0;
  for (std::uint32_t o = 0; o < b.op_count && nt < b.new_count; ++o) {
    const Op op = op_at(b, o);
    j += op.keep;
    if (op.insert == 0) continue;
    std::uint32_t before = j == 0 ? 0u : q0[j - 1];
    for (std::uint32_t t = 0; t < op.insert; ++t) q0[j + t] = before += fresh[nt + t];
    if (has_motion) {
      for (std::uint32_t t = 0; t < op.insert; ++t) d0[j + t] = step += motion[nt + t];
    } else {
      for (std::uint32_t t = 0; t < op.insert; ++t) d0[j + t] = step;
    }
    j += op.insert;
    nt += op.insert;
  }
}

// derive_run() as the compiler vectorises it for SSE2 and, with eight values a vector, for AVX2.
using DeriveRun = void (*)(std::uint32_t*, const std::uint32_t*, const std::uint32_t*, const std::uint8_t*,
                           std::uint32_t, float);
void derive_run_baseline(std::uint32_t* out, const std::uint32_t* d0, const std::uint32_t* d1,
                         const std::uint8_t* state, std::uint32_t n, float step) {
  derive_run(out, d0, d1, state, n, step);
}
#if PSTREAM_DECODER_AVX2
[[gnu::target("avx2")]] void derive_run_avx2(std::uint32_t* out, const std::uint32_t* d0, const std::uint32_t* d1,
                                             const std::uint8_t* state, std::uint32_t n, float step) {
  derive_run(out, d0, d1, state, n, step);
}
#else
constexpr DeriveRun derive_run_avx2 = derive_run_baseline;                       // never chosen: use_avx2() is false
#endif

// AVX2 where the processor has it, unless the environment says PSTREAM_SIMD=baseline (which the
// tests use to check that both decode the same bits).
bool use_avx2() {
#if PSTREAM_DECODER_AVX2
  const char* simd = std::getenv("PSTREAM_SIMD");
  return (simd == nullptr || std::string_view(simd) != "baseline") && __builtin_cpu_supports("avx2");
#else
  return false;
#endif
}

class ParticleUnit final : public FrameUnit {
 public:
  ParticleUnit(const Metadata& meta, std::string_view name)
      : meta_(meta), name_(name), plan_(meta.codec), entropy_(stream_window_log(meta)) {
    const StateSizes sizes(meta, plan_);
    for (int b = 0; b < 2; ++b) {
      q_[b].assign(sizes.words, 0);
      d_[b].assign(sizes.words, 0);
      ids_[b].assign(sizes.ids, 0);
      steps_[b].assign(sizes.steps, 0);
    }
    residual_.assign(sizes.particles, 0);
    alive_.assign(sizes.alive_words, 0);
    derived_.assign(sizes.derived, 0);
    bias_.assign(sizes.blocks, 0);
    stride_ = sizes.stride;
    bias_stride_ = sizes.bias_stride;
    save_bytes_ = sizes.saved_bytes(meta.max_count, plan_.coded.size());
    runs_.resize(plan_.coded.size());
    columns_.resize(plan_.words);
    words_.resize(plan_.coded.size());
    body_.resize(sizes.body);
    choose_groups();
  }

  void reset() override { count_[cur_ ^ 1] = 0; }
  std::uint64_t state_bytes() const override {
    std::uint64_t bytes = body_.size() + (residual_.size() + bias_.size() + derived_.size()) * 4 + alive_.size() * 8 +
                          EntropyDecoder::stream_bytes(stream_window_log(meta_));
    for (int b = 0; b < 2; ++b) bytes += (q_[b].size() + d_[b].size()) * 4 + ids_[b].size() * 8 + steps_[b].size();
    return bytes;
  }

  std::uint64_t save_bytes() const override { return save_bytes_; }

  // The state decode() reads of the frame before (the other half of q_, d_, ids_ and steps_, its
  // count) and the zstd stream, each as far as the frame's particles reach. Its layout is
  // StateSizes::saved_bytes(): an 8-byte header, then each piece of saved_pieces() in its room.
  void save(std::span<std::byte> to) const override {
    const int s = cur_ ^ 1;
    std::byte* p = to.data() + 8;
    saved_pieces(*this, s, count_[s], [&](const void* from, std::size_t bytes, std::size_t room) {
      std::memcpy(p, from, bytes);
      p += room;
    });
    // The header: the count, and whether the stream was saved (a restore without it cannot
    // continue one).
    const std::uint32_t header[2] = {count_[s], entropy_.save_stream({p, to.data() + to.size()}) ? 1u : 0u};
    std::memcpy(to.data(), header, 8);
  }

  void restore(std::span<const std::byte> from) override {
    const int s = cur_ ^ 1;
    std::uint32_t header[2];
    std::memcpy(header, from.data(), 8);
    count_[s] = header[0];
    const std::byte* p = from.data() + 8;
    saved_pieces(*this, s, header[0], [&](void* to, std::size_t bytes, std::size_t room) {
      std::memcpy(to, p, bytes);
      p += room;
    });
    if (stream_window_log(meta_) > 0)  // no saved stream: the next packet fails as not its successor
      entropy_.restore_stream(header[1] ? std::span<const std::byte>(p, from.data() + from.size())
                                        : std::span<const std::byte>{});
  }

  std::size_t decode(std::uint64_t frame, bool keyframe, std::span<const std::byte> packet, std::span<std::byte> out,
                     std::span<MatchRun> matching) override {
    const Body b = parse(frame, keyframe, packet);
    const int prev = cur_ ^ 1;
    const std::uint64_t n = stride_;
    if (b.keyframe) {
      for (std::size_t k = 0; k < plan_.coded.size(); ++k) {
        const Body::Word& w = b.words[k];
        std::uint32_t* q0 = q_[cur_].data() + k * n;
        std::uint32_t* d0 = d_[cur_].data() + k * n;
        read_planes(w.fresh, b.count, w.new_bytes, residual_.data());
        std::uint32_t acc = 0;
        for (std::uint32_t j = 0; j < b.count; ++j) q0[j] = acc += unzigzag(residual_[j]);
        read_planes(w.motion, b.count, w.motion_bytes, residual_.data());
        acc = 0;
        for (std::uint32_t j = 0; j < b.count; ++j) d0[j] = acc += unzigzag(residual_[j]);
        if (!plan_.derived.empty()) {  // each particle's step before its last, where derive() finds it
          std::uint32_t* d1_out = d_[prev].data() + k * n;
          read_planes(w.prior, b.count, w.prior_bytes, residual_.data());
          acc = 0;
          for (std::uint32_t j = 0; j < b.count; ++j) d1_out[j] = acc += unzigzag(residual_[j]);
        }
      }
    } else {
      // Every word's survivors in one walk over the operations, then each word's new particles
      // (whose values start from the particle before them, a survivor or a new one).
      const std::uint32_t blocks = (b.keep_total + kBlock - 1) >> kBlockShift;
      for (std::size_t k = 0; k < plan_.coded.size(); ++k) {
        const Body::Word& w = b.words[k];
        std::uint32_t* bias = bias_.data() + k * bias_stride_;
        read_planes(w.bias, blocks, w.bias_bytes, bias);
        for (std::uint32_t acc = 0, x = 0; x < blocks; ++x) bias[x] = acc += unzigzag(bias[x]);
        WordRuns& r = runs_[k];
        r.runs = SurvivorRuns(w.keep, b.keep_total, w.keep_packing, w.keep_bytes, w.keep_escape_planes, w.keep_escapes,
                              bias);
        r.kind = r.runs.kind();
        r.linear = w.predictor == kLinear ? ~0u : 0u;
        r.q0 = q_[cur_].data() + k * n;
        r.d0 = d_[cur_].data() + k * n;
        r.q1 = q_[prev].data() + k * n;
        r.d1 = d_[prev].data() + k * n;
      }
      const bool compact = compact_every_frame() || !walk_together(b, runs_.size());
      predict_survivors_(b, runs_.data(), runs_.size(), compact ? alive_.data() : nullptr);
      if (b.new_count != 0) {
        // The new particles' values and first steps, each in one vector pass into the residual
        // buffer.
        std::uint32_t* fresh = residual_.data();
        std::uint32_t* motion = fresh + b.new_count;
        for (std::size_t k = 0; k < plan_.coded.size(); ++k) {
          const Body::Word& w = b.words[k];
          read_values(w.fresh, b.new_count, w.new_bytes, fresh);
          if (w.motion_bytes != 0) read_values(w.motion, b.new_count, w.motion_bytes, motion);
          insert_new(b, w.motion_bytes != 0, runs_[k].q0, runs_[k].d0, fresh, motion);
        }
      }
    }
    if (plan_.id_word >= 0) decode_ids(b, prev);
    if (!plan_.derived.empty()) derive(b, prev);
    write_records(b.count, out);
    count_[cur_] = b.count;
    cur_ ^= 1;
    // The operations pair survivors with the particles they continue (in id or matched order;
    // in source order particle i is only predicted from particle i, which may be another one).
    // A keyframe's links do the same where it has them.
    const std::byte* const runs = b.keyframe ? b.links : b.ops;
    const std::uint32_t run_count = b.keyframe ? b.link_count : b.op_count;
    if ((b.keyframe && run_count == 0) || meta_.codec.order == FrameOrder::Source || run_count > matching.size())
      return kNoMatching;
    static_assert(sizeof(Op) == sizeof(MatchRun));
    if (run_count != 0) std::memcpy(matching.data(), runs, std::size_t(run_count) * kOpSize);
    return run_count;
  }

 private:
  // The saved state's pieces after its header, in order: f(data, bytes of `count` particles,
  // bytes of room for max_count) for each coded word's values, then its steps, the ids and the
  // step states of state half `s` (`self` const when saving).
  template <class Self, class F>
  static void saved_pieces(Self& self, int s, std::uint32_t count, F&& f) {
    const std::uint64_t m = self.meta_.max_count;
    const std::size_t coded = self.plan_.coded.size();
    for (std::size_t k = 0; k < coded; ++k) f(self.q_[s].data() + k * self.stride_, count * 4ull, m * 4);
    for (std::size_t k = 0; k < coded; ++k) f(self.d_[s].data() + k * self.stride_, count * 4ull, m * 4);
    if (!self.ids_[s].empty()) f(self.ids_[s].data(), count * 8ull, m * 8);
    if (!self.steps_[s].empty()) f(self.steps_[s].data(), std::size_t{count}, m);
  }

  // "position.y", "color", "velocity.x": the attribute (and component) a record word belongs to.
  std::string word_name(std::uint32_t w) const {
    for (const Attribute& a : meta_.layout) {
      if (w * 4 < a.offset || w * 4 >= a.offset + a.size()) continue;
      if (a.type != AttributeType::Float32 || a.components == 1) return a.name;
      const std::uint32_t c = (w * 4 - a.offset) / 4;
      return a.components <= 4 ? fmt::format("{}.{}", a.name, "xyzw"[c]) : fmt::format("{}[{}]", a.name, c);
    }
    return fmt::format("record word {}", w);
  }

  [[noreturn]] void fail(std::uint64_t frame, std::string_view what, std::uint64_t offset) const {
    throw Error(fmt::format("{}: frame {}: particle packet: at body offset {}: {}", name_, frame, offset, what));
  }

  Body parse(std::uint64_t frame, bool keyframe, std::span<const std::byte> packet) {
    std::string why;
    // Version 4: a packet continues the zstd frame of the packet before unless it starts one
    // (every keyframe's does); before, each packet was a whole zstd frame.
    std::uint32_t magic = 0;
    if (packet.size() >= 4) std::memcpy(&magic, packet.data(), 4);
    if (meta_.version >= kFirstStreamedVersion && keyframe && magic != kZstdMagic)
      fail(frame, "a keyframe's packet must start a zstd frame", 0);
    const std::span<std::byte> body = std::span(body_).first(body_.size() - kReadPad);  // SurvivorRuns reads past
    const std::size_t size = meta_.version >= kFirstStreamedVersion
                                 ? entropy_.zstd_stream(body, packet, magic == kZstdMagic, why)
                                 : entropy_.zstd(body, packet, why);
    if (size == EntropyDecoder::kFailed) {
      fail(frame,
           fmt::format("the zstd data does not decode within {} bytes, the most {} particles need: {} (corrupted)",
                       body.size(), meta_.max_count, why),
           0);
    }
    if (size < kBodyHeader)
      fail(frame, fmt::format("the body holds {} bytes, expected at least {}", size, kBodyHeader), 0);
    const std::byte* p = body_.data();
    std::size_t at = 0;
    const auto u32 = [&] {
      std::uint32_t v;
      std::memcpy(&v, p + at, 4);
      at += 4;
      return v;
    };
    Body b;
    b.count = u32();
    b.prev_count = u32();
    b.op_count = u32();
    b.new_count = u32();
    b.keyframe = keyframe;
    const FrameEntry& entry = meta_.frames[frame];
    if (b.count != entry.count)
      fail(frame, fmt::format("{} particles, the frame index says {}", b.count, entry.count), 0);
    // A keyframe codes every particle as new. From version 6, in id order, it may also link them
    // to the frame before with operations (whose count it takes from the frame index: a keyframe
    // decodes without that frame).
    if (keyframe) {
      const bool may_link =
          meta_.version >= kFirstKeyframeLinksVersion && meta_.codec.order == FrameOrder::Id && frame > 0;
      const bool links = b.op_count != 0 || b.prev_count != 0;
      if (b.new_count != b.count || (links && !may_link)) {
        fail(frame,
             may_link ? "a keyframe must code every particle as new (and may link them to the previous frame)"
                      : "a keyframe must code every particle as new, with no operations",
             4);
      }
      if (links && (b.op_count == 0 || b.prev_count != meta_.frames[frame - 1].count)) {
        fail(frame,
             fmt::format("a keyframe's {} links to {} particles of the previous frame, which has {}", b.op_count,
                         b.prev_count, meta_.frames[frame - 1].count),
             4);
      }
    }
    if (!keyframe && b.prev_count != count_[cur_ ^ 1]) {
      fail(frame,
           fmt::format("predicted from {} particles, but the previous frame has {}", b.prev_count, count_[cur_ ^ 1]),
           4);
    }
    if (b.op_count > std::uint64_t(b.prev_count) + b.count)
      fail(frame, fmt::format("{} operations for {} + {} particles", b.op_count, b.prev_count, b.count), 8);
    const std::size_t coded = plan_.coded.size();
    const std::size_t fixed = kBodyHeader + coded * kWordHeader + (plan_.id_word >= 0 ? kIdHeader : 0);
    if (size < fixed + std::uint64_t(b.op_count) * kOpSize)
      fail(frame, fmt::format("the body of {} bytes ends inside its header or operations", size), size);
    for (std::size_t k = 0; k < coded; ++k) {
      Body::Word& w = words_[k];
      std::memcpy(&w.predictor, p + at, 1);
      std::memcpy(&w.keep_bytes, p + at + 1, 1);
      std::memcpy(&w.new_bytes, p + at + 2, 1);
      std::memcpy(&w.motion_bytes, p + at + 3, 1);
      std::memcpy(&w.bias_bytes, p + at + 4, 1);
      std::memcpy(&w.prior_bytes, p + at + 5, 1);
      std::memcpy(&w.keep_packing, p + at + 6, 1);
      const bool reserved = p[at + 7] != std::byte{0};
      at += 8;
      if (w.predictor > kLinear || w.keep_bytes > 4 || w.new_bytes > 4 || w.motion_bytes > 4 || w.bias_bytes > 4 ||
          w.prior_bytes > 4 || reserved || (!keyframe && w.motion_bytes != 0 && meta_.version < 3) ||
          (keyframe && w.bias_bytes != 0) || (w.prior_bytes != 0 && (!keyframe || meta_.version < 3)) ||
          w.keep_packing > kNibbles ||
          (w.keep_packing == kNibbles && (keyframe || meta_.version < kFirstNibbleVersion))) {
        fail(frame,
             fmt::format("{}: predictor {} with {}/{}/{}/{}/{} keep/new/motion/bias/prior residual bytes and keep "
                         "packing {} (expected a predictor 0..1, 0..4 bytes, motion only in keyframes before version "
                         "3, bias only in predicted frames, prior steps only in version 3 keyframes, packing 0 or "
                         "(predicted frames of version 5 on) 1, reserved byte 0)",
                         word_name(plan_.coded[k]), w.predictor, w.keep_bytes, w.new_bytes, w.motion_bytes,
                         w.bias_bytes, w.prior_bytes, w.keep_packing),
             at - 8);
      }
    }
    b.words = words_;
    if (plan_.id_word >= 0) {
      b.id_bytes = std::to_integer<unsigned>(p[at]);
      if (b.id_bytes > 8) fail(frame, fmt::format("id residuals of {} bytes (at most 8)", b.id_bytes), at);
      at += kIdHeader;
    }
    b.ops = p + at;
    std::uint64_t keep = 0, drop = 0, insert = 0;
    for (std::uint32_t o = 0; o < b.op_count; ++o) {
      const Op op = op_at(b, o);
      if (std::uint64_t(op.keep) + op.drop + op.insert == 0) fail(frame, fmt::format("operation {} is empty", o), at);
      keep += op.keep;
      drop += op.drop;
      insert += op.insert;
    }
    at += std::size_t(b.op_count) * kOpSize;
    const std::size_t start_of_planes = at;
    if ((!keyframe || b.op_count != 0) &&
        (keep + drop != b.prev_count || keep + insert != b.count || (!keyframe && insert != b.new_count))) {
      fail(frame,
           fmt::format("the operations keep {}, drop {} and insert {} particles; the frame needs {} kept + dropped "
                       "and {} in all, {} new",
                       keep, drop, insert, b.prev_count, b.count, keyframe ? b.count - keep : b.new_count),
           at);
    }
    if (keyframe) {  // links, not operations: every particle decodes as new
      b.links = b.ops;
      b.link_count = b.op_count;
      b.op_count = 0;
      b.prev_count = 0;
    }
    b.keep_total = static_cast<std::uint32_t>(keyframe ? 0 : keep);
    const std::uint64_t blocks = (std::uint64_t(b.keep_total) + kBlock - 1) >> kBlockShift;
    // The planes, word by word: each part must fit in what is left of the body.
    const auto take = [&](std::uint64_t bytes, std::string_view what, std::size_t k) {
      if (bytes > size - at) {
        fail(frame,
             fmt::format("the residual planes need more than the body holds: {}'s {} take {} bytes, {} are left",
                         word_name(plan_.coded[k]), what, bytes, size - at),
             at);
      }
      const std::byte* part = p + at;
      at += static_cast<std::size_t>(bytes);
      return part;
    };
    for (std::size_t k = 0; k < coded; ++k) {
      Body::Word& w = words_[k];
      w.bias = take(std::uint64_t(w.bias_bytes) * blocks, "bias planes", k);
      if (w.keep_packing == kNibbles) {
        const std::uint64_t packed = (std::uint64_t(b.keep_total) + 1) / 2;
        w.keep = take(packed, "survivors' nibbles", k);
        const auto* nibbles = reinterpret_cast<const std::uint8_t*>(w.keep);
        if ((b.keep_total & 1) != 0 && (nibbles[packed - 1] >> 4) != 0)
          fail(frame, fmt::format("{}: the padding nibble is not 0", word_name(plan_.coded[k])), at - 1);
        w.keep_escapes = static_cast<std::uint32_t>(count_escapes(nibbles, b.keep_total));
        w.keep_escape_planes = take(std::uint64_t(w.keep_bytes) * w.keep_escapes, "survivors' escape planes", k);
      } else {
        w.keep = take(std::uint64_t(w.keep_bytes) * b.keep_total, "survivors' planes", k);
      }
      w.fresh = take(std::uint64_t(w.new_bytes) * b.new_count, "new particles' planes", k);
      w.motion = take(std::uint64_t(w.motion_bytes) * b.new_count, "motion planes", k);
      w.prior = take(std::uint64_t(w.prior_bytes) * b.new_count, "prior steps' planes", k);
    }
    const std::uint64_t id_planes = std::uint64_t(b.id_bytes) * b.new_count;
    if (at + id_planes != size) {
      fail(frame,
           fmt::format("the residual planes need {} bytes, the body holds {}", at + id_planes - start_of_planes,
                       size - start_of_planes),
           start_of_planes);
    }
    b.ids = p + at;
    return b;
  }

  void decode_ids(const Body& b, int prev) {
    std::uint64_t* out = ids_[cur_].data();
    const std::uint64_t* before = ids_[prev].data();
    const auto* planes = reinterpret_cast<const std::uint8_t*>(b.ids);
    const auto fresh = [&](std::uint32_t j, std::uint32_t nt) {
      out[j] = (j == 0 ? 0 : out[j - 1]) + unzigzag64(plane_value<std::uint64_t>(planes, b.new_count, nt, b.id_bytes));
    };
    if (b.keyframe) {
      for (std::uint32_t j = 0; j < b.count; ++j) fresh(j, j);
      return;
    }
    std::uint32_t i = 0, j = 0, nt = 0;
    for (std::uint32_t o = 0; o < b.op_count; ++o) {
      const Op op = op_at(b, o);
      std::copy_n(before + i, op.keep, out + j);
      i += op.keep + op.drop;
      j += op.keep;
      for (std::uint32_t t = 0; t < op.insert; ++t) fresh(j++, nt++);
    }
  }

  // Derived words (velocity) from each particle's last two grid steps over the matching
  // (StepState). A keyframe's particle: its motion and its prior step (two steps, or one when the
  // prior is 0); with motion 0 and a prior step, that is its seed (it becomes its step). A new
  // particle: seeded when its motion is not 0. A survivor: after_step() of what it had.
  void derive(const Body& b, int prev) {
    const std::uint64_t n = stride_;  // between words in d_ (derived_'s words are max_count apart)
    std::uint8_t* steps = steps_[cur_].data();
    const std::uint8_t* before = steps_[prev].data();
    const auto any = [&](int state, std::uint32_t j) {
      for (const WordPlan::Derived& dw : plan_.derived)
        if (d_[state][dw.from * n + j] != 0) return true;
      return false;
    };
    if (b.keyframe) {  // the prior steps were decoded into the other state's d, in this frame's order
      for (std::uint32_t j = 0; j < b.count; ++j) {
        const bool moving = any(cur_, j), prior = any(prev, j);
        if (!moving && prior) {
          for (const WordPlan::Derived& dw : plan_.derived) d_[cur_][dw.from * n + j] = d_[prev][dw.from * n + j];
        }
        steps[j] = moving ? (prior ? kTwoSteps : kOneStep) : prior ? kSeeded : kNoStep;
      }
    } else {
      for (std::uint32_t o = 0, i = 0, j = 0; o < b.op_count; ++o) {
        const Op op = op_at(b, o);
        after_steps(steps + j, before + i, op.keep);
        i += op.keep + op.drop;
        j += op.keep;
        // A new particle's state (0 or 3) leaves its step before unused.
        for (std::uint32_t t = 0; t < op.insert; ++t) steps[j + t] = any(cur_, j + t) ? kSeeded : kNoStep;
        j += op.insert;
      }
    }
    // Each derived word in one run over the frame (the runs between births and deaths are short):
    // in a predicted frame the steps before are first gathered into this frame's order (0 for new
    // particles).
    for (std::size_t x = 0; x < plan_.derived.size(); ++x) {
      const WordPlan::Derived& dw = plan_.derived[x];
      const std::uint32_t* d1 = d_[prev].data() + dw.from * n;
      if (!b.keyframe) {
        std::uint32_t* gathered = residual_.data();
        for (std::uint32_t o = 0, i = 0, j = 0; o < b.op_count; ++o) {
          const Op op = op_at(b, o);
          std::copy_n(d1 + i, op.keep, gathered + j);
          std::fill_n(gathered + j + op.keep, op.insert, 0u);
          i += op.keep + op.drop;
          j += op.keep + op.insert;
        }
        d1 = gathered;
      }
      derive_run_(derived_.data() + x * meta_.max_count, d_[cur_].data() + dw.from * n, d1, steps, b.count,
                  meta_.codec.words[dw.word].step);
    }
  }

  // This frame's columns. Coded and derived words are met in record order, the order of
  // plan_.coded and plan_.derived (WordPlan), which is how q_ and derived_ hold them.
  void set_columns() {
    const std::uint64_t n = stride_, m = meta_.max_count;  // between words in q_, and in derived_
    std::size_t k = 0, x = 0;
    for (std::uint32_t w = 0; w < plan_.words; ++w) {
      const WordCodingEntry& e = meta_.codec.words[w];
      Column& c = columns_[w];
      switch (e.coding) {
        case WordCoding::Quantized:
          c = {Column::kDequantize, q_[cur_].data() + k++ * n, nullptr, e.step, as_float(e.base), 0};
          break;
        case WordCoding::Relative: c = {Column::kShift, q_[cur_].data() + k++ * n, nullptr, 0, 0, e.base}; break;
        case WordCoding::Exact: c = {Column::kShift, q_[cur_].data() + k++ * n, nullptr, 0, 0, 0}; break;
        case WordCoding::Derived: c = {Column::kShift, derived_.data() + x++ * m, nullptr, 0, 0, 0}; break;
        case WordCoding::Constant: c = {Column::kConstant, nullptr, nullptr, 0, 0, e.base}; break;
        case WordCoding::Id:
          c = {
              std::int64_t(w) == plan_.id_word ? Column::kIdLow : Column::kIdHigh, nullptr, ids_[cur_].data(), 0, 0, 0};
          break;
      }
    }
  }

  // The first record word of group g: groups of four words, the last one overlapping the one
  // before when the words are not a multiple of four (a record is 16 bytes or more).
  std::uint32_t group_word(std::uint32_t g) const { return std::min(4 * g, plan_.words - 4); }

  // Each group's loop, from its columns' kinds (the clip's codings, the same in every frame):
  // one of its own for each mix of dequantised, shifted and constant columns, else the loop that
  // reads the kinds at run time. Eight particles at a time with AVX2 when every group has a loop
  // of its own.
  void choose_groups() {
    static_assert(Column::kDequantize == 0 && Column::kShift == 1 && Column::kConstant == 2);
    set_columns();
    std::vector<int> mixes;
    for (std::uint32_t w0 = 0; w0 < plan_.words; w0 += 4) {
      const std::uint32_t w = group_word(w0 / 4);
      int mix = 0;
      for (int x = 0, digit = 1; x < 4 && mix >= 0; ++x, digit *= 3)
        mix = columns_[w + x].kind > Column::kConstant ? -1 : mix + columns_[w + x].kind * digit;
      mixes.push_back(mix);
    }
    const bool all_known = std::find(mixes.begin(), mixes.end(), -1) == mixes.end();
    record_lanes_ = avx2_ && all_known ? 8 : 4;
    for (const int mix : mixes) {
      groups_.push_back(mix < 0              ? &write_group<kAny, kAny, kAny, kAny>
                        : record_lanes_ == 8 ? kKnownGroupsAvx2[mix]
                                             : kKnownGroups[mix]);
    }
  }

  // Records are written four words of four particles at a time (eight with AVX2), straight from
  // the state: each word's values made in a vector register, then 4×4 transposes into the
  // records. Through a tile (each word's column of 256 particles made in a loop of its own, then
  // transposed from there) the sparks decoded about 6 % slower; with each column's kind read at
  // run time in the loop, about 4 % (the FLIP pour, whose sizes are constant, 5 %), so the groups
  // of the usual kinds have loops of their own.
  //
  // A frame whose records take kStreamedRecords or more goes to its output past the caches (on
  // x86-64, where the output is 16-byte aligned and its records 16 bytes or a multiple): it is
  // larger than a core's L2, read later by the player's thread or the GPU upload, and an ordinary
  // store would first read each of its lines from memory and push the decoder's own state (the
  // frame before, read again next frame) out of the cache. A cache line is only written straight
  // to memory when it is written whole before the processor lets it go, so a record of two groups
  // or more is written kTile particles at a time, group after group. The demo fountain's first 120
  // frames, up to 249,000 particles, decoded over and over with and without these stores
  // alternating on one core (six runs each, large frames walking word by word in both): its
  // default cook (32-byte records) 2.29-2.48 -> 2.60-2.83 GB/s, [x y z scale] 2.89-3.35 ->
  // 3.09-3.45. The player's own cost is the same (docs/compression-experiments.md, "A large frame's
  // records stored past the caches"). Written with 64 particles a tile (2 KiB of lines in flight) the
  // default cook was about 30 % slower than with ordinary stores, with each group in a pass of its
  // own 25 %.
  static constexpr std::uint64_t kStreamedRecords = std::uint64_t(1) << 20;
  static constexpr std::uint32_t kTile = 16;
  void write_records(std::uint32_t count, std::span<std::byte> out) {
    const std::size_t rs = meta_.record_size;
    if (count == 0) return;  // an empty frame's output may be no memory at all
    set_columns();
    const std::uint32_t lanes = record_lanes_;
    const bool stream = PSTREAM_DECODER_STREAM && std::uint64_t(count) * rs >= kStreamedRecords && rs % 16 == 0 &&
                        reinterpret_cast<std::uintptr_t>(out.data()) % 16 == 0;
    std::uint32_t done = 0;
    if (stream && groups_.size() > 1) {
      const std::uint32_t tiles = count / kTile;
      for (std::uint32_t t = 0; t < tiles; ++t) {
        for (std::uint32_t g = 0; g < groups_.size(); ++g) {
          const std::uint32_t w = group_word(g);
          groups_[g](columns_.data() + w, out.data() + 4 * w, rs, t * kTile, kTile / lanes, true);
        }
      }
      done = tiles * kTile;
    }
    for (std::uint32_t g = 0; g < groups_.size(); ++g) {
      const std::uint32_t w = group_word(g);
      groups_[g](columns_.data() + w, out.data() + 4 * w, rs, done, (count - done) / lanes, stream);
    }
#if PSTREAM_DECODER_STREAM
    if (stream) _mm_sfence();  // the streamed stores are seen before the frame is handed on
#endif
    for (std::uint32_t t = count / lanes * lanes; t < count; ++t) {
      for (std::uint32_t x = 0; x < plan_.words; ++x) {
        const std::uint32_t value = column1(columns_[x], t);
        std::memcpy(out.data() + std::size_t(t) * rs + 4 * x, &value, 4);
      }
    }
  }

  const Metadata& meta_;
  std::string_view name_;
  WordPlan plan_;
  EntropyDecoder entropy_;
  std::vector<std::uint32_t> q_[2], d_[2], residual_, bias_;
  std::vector<Column> columns_;  // one per record word, set for each frame
  std::vector<std::uint64_t> ids_[2];
  std::vector<std::uint8_t> steps_[2];  // per particle: grid steps known (0, 1, 2 = two or more)
  std::vector<std::uint32_t> derived_;  // per derived word and particle: the value's bits
  std::vector<std::uint64_t> alive_;    // a bit per previous particle: it survives (mark_survivors())
  std::uint32_t count_[2] = {0, 0};
  std::uint64_t save_bytes_ = 0;
  int cur_ = 0;
  std::vector<Body::Word> words_;
  std::vector<std::byte> body_;
  bool avx2_ = use_avx2();
  PredictSurvivors predict_survivors_ = avx2_ ? predict_survivors_avx2 : predict_survivors_baseline;
  DeriveRun derive_run_ = avx2_ ? derive_run_avx2 : derive_run_baseline;
  std::vector<WordRuns> runs_;                  // one per coded word, set for each predicted frame
  std::vector<WriteGroup> groups_;              // each group of four record words' loop (choose_groups)
  std::uint32_t record_lanes_ = 4;              // particles a loop of groups_ makes at a time
  std::uint64_t stride_ = 0, bias_stride_ = 0;  // elements between words in q_ and d_, and in bias_
};

}  // namespace

std::string_view particle_decoder_simd() {
#if defined(__EMSCRIPTEN__)
  return "SIMD128";
#elif PSTREAM_DECODER_AVX2
  return use_avx2() ? "AVX2" : "SSE2";
#else
  return "generic vectors";
#endif
}

std::uint64_t particle_unit_state_bytes(const Metadata& meta) { return StateSizes(meta, WordPlan(meta.codec)).bytes(); }

std::uint64_t particle_unit_save_bytes(const Metadata& meta) {
  const WordPlan plan(meta.codec);
  return StateSizes(meta, plan).saved_bytes(meta.max_count, plan.coded.size());
}

std::unique_ptr<FrameUnit> make_particle_unit(const Metadata& meta, std::string_view name) {
  return std::make_unique<ParticleUnit>(meta, name);
}

}  // namespace pstream::format
