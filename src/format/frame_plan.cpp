// Frame codecs, the encoding side: a clip's statistics, the particle codec's plan (what each
// record word becomes), and comparing decoded frames with their source (verify, benchmarks).
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>

#include <fmt/format.h>

#include "particlestream/codec.hpp"

namespace pstream::format {

// ---- Clip statistics ----------------------------------------------------------------------------

ClipStats::ClipStats(const std::vector<Attribute>& layout) : layout_(layout), record_size_(record_size_of(layout)) {
  for (const Attribute& a : layout_) {
    first_component_.push_back(min_.size());
    const std::size_t n = a.type == AttributeType::Float32 ? a.components : 0;
    min_.insert(min_.end(), n, std::numeric_limits<float>::infinity());
    max_.insert(max_.end(), n, -std::numeric_limits<float>::infinity());
  }
  constant_.assign(layout_.size(), 1);
  value_.resize(record_size_);
}

void ClipStats::add(std::span<const std::byte> records, std::uint64_t count) {
  for (std::size_t a = 0; a < layout_.size(); ++a) {
    const Attribute& at = layout_[a];
    if (count > 0 && particles_ == 0) std::memcpy(value_.data() + at.offset, records.data() + at.offset, at.size());
    for (std::uint64_t i = 0; i < count; ++i) {
      const std::byte* r = records.data() + i * record_size_ + at.offset;
      if (constant_[a] && std::memcmp(r, value_.data() + at.offset, at.size()) != 0) constant_[a] = 0;
      if (at.type != AttributeType::Float32) continue;
      for (std::size_t c = 0; c < at.components; ++c) {
        float v;
        std::memcpy(&v, r + 4 * c, 4);
        float& lo = min_[first_component_[a] + c];
        float& hi = max_[first_component_[a] + c];
        if (std::isnan(v)) {  // no grid holds it: the attribute is kept exact
          lo = -std::numeric_limits<float>::infinity();
          hi = std::numeric_limits<float>::infinity();
        }
        lo = std::min(lo, v);
        hi = std::max(hi, v);
      }
    }
  }
  particles_ += count;
}

std::span<const std::byte> ClipStats::constant_value(std::size_t a) const {
  return std::span(value_).subspan(layout_[a].offset, layout_[a].size());
}

double ClipStats::diagonal() const {
  if (particles_ == 0) return 0.0;
  double sum = 0.0;
  for (std::size_t c = 0; c < 3; ++c) {
    const double e = double(max_[c]) - double(min_[c]);
    sum += e * e;
  }
  return std::sqrt(sum);
}

// ---- Planning -----------------------------------------------------------------------------------

std::uint32_t relative_shift_for(double error) {
  for (std::uint32_t kept = 0; kept < 23; ++kept) {
    if (std::ldexp(1.0, -int(kept) - 1) <= error) return 23 - kept;
  }
  return 0;
}

namespace {

// A grid for values in [lo, hi] whose decoded floats stay within `error`: the step leaves room
// for the two roundings of the decoder's float arithmetic (one ulp of the largest magnitude
// each), and every value must fit 24 bits.
bool make_grid(double lo, double hi, double error, WordCodingEntry& e) {
  if (!std::isfinite(lo) || !std::isfinite(hi) || !(error > 0.0) || !std::isfinite(error)) return false;
  const float magnitude = static_cast<float>(std::max({std::abs(lo), std::abs(hi), hi - lo}));
  const double ulp = double(std::nextafter(magnitude, std::numeric_limits<float>::infinity())) - double(magnitude);
  const double step = 2.0 * (error - 2.0 * ulp);
  if (!(step > 0.0)) return false;
  e.coding = WordCoding::Quantized;
  e.step = static_cast<float>(step);
  if (double(e.step) > step) e.step = std::nextafter(e.step, 0.0f);
  e.error = static_cast<float>(error);
  if (double(e.error) > error) e.error = std::nextafter(e.error, 0.0f);
  const auto origin = static_cast<float>(lo);
  e.base = std::bit_cast<std::uint32_t>(origin);
  return (hi - double(origin)) / double(e.step) < double((1 << 24) - 2);
}

}  // namespace

CodecInfo plan_particle_codec(const std::vector<Attribute>& layout, const ClipStats& stats, double fps, bool has_ids,
                              const ParticleCodecOptions& options) {
  CodecInfo info;
  info.codec = FrameCodec::Particle;
  info.lossless = options.lossless;
  info.keyframe_interval = options.keyframe_interval;
  if (info.keyframe_interval < 1 || info.keyframe_interval > kMaxKeyframeInterval) {
    throw Error(
        fmt::format("the keyframe interval is {}, expected 1 to {}", info.keyframe_interval, kMaxKeyframeInterval));
  }
  info.order = particle_frame_order(has_ids, options.lossless);
  info.zstd_level =
      options.zstd_level != 0 ? options.zstd_level : default_particle_zstd_level(info.order, options.lossless);
  const std::uint32_t record_size = record_size_of(layout);
  info.words.resize(record_size / 4);
  const double diagonal = stats.diagonal();
  double position_error = 0.0;
  if (!options.lossless) {
    if (!(options.error > 0.0) || !std::isfinite(options.error)) {
      throw Error(fmt::format("the error bound is {}, expected a positive number", options.error));
    }
    position_error = options.error_relative ? options.error * diagonal : options.error;
  }
  // Velocity and other float attributes: a fraction of their own range.
  const double fraction = options.attribute_error;
  if (!options.lossless && (!(fraction > 0.0) || !(fraction < 1.0)))
    throw Error(
        fmt::format("the attribute error bound is {}, expected a fraction of a range, above 0 and below 1", fraction));
  info.error = position_error;
  std::size_t component = 0;
  const Attribute* position = find_attribute(layout, "position");
  for (std::size_t a = 0; a < layout.size(); ++a) {
    const Attribute& at = layout[a];
    const std::uint32_t first = at.offset / 4, words = static_cast<std::uint32_t>(at.size() / 4);
    const bool is_float = at.type == AttributeType::Float32;
    if (options.derive_velocity && info.order == FrameOrder::Id && at.name == "velocity" && is_float &&
        at.components == 3 && position != nullptr && position->type == AttributeType::Float32 &&
        position->components == 3) {
      if (!(fps > 0.0) || !std::isfinite(fps))
        throw Error(fmt::format("a derived velocity needs the clip's frame rate, not {} fps", fps));
      // Not stored: each component from its position word's grid steps (the position words come
      // first in the layout, so their codings are set).
      for (std::uint32_t c = 0; c < 3; ++c) {
        WordCodingEntry& entry = info.words[first + c];
        const std::uint32_t from = position->offset / 4 + c;
        const WordCodingEntry& p = info.words[from];
        entry = WordCodingEntry{};
        if (p.coding == WordCoding::Quantized) {
          entry.coding = WordCoding::Derived;
          entry.base = from;
          entry.step = static_cast<float>(double(p.step) * fps * 0.5);
        } else {
          entry.coding = WordCoding::Constant;  // a position that never moves on this axis: 0
          entry.base = std::bit_cast<std::uint32_t>(0.0f);
        }
      }
      component += at.components;
      continue;
    }
    if (stats.particles() > 0 && stats.constant(a)) {
      const std::span<const std::byte> v = stats.constant_value(a);
      for (std::uint32_t w = 0; w < words; ++w) {
        info.words[first + w].coding = WordCoding::Constant;
        std::memcpy(&info.words[first + w].base, v.data() + 4 * w, 4);
      }
    } else if (at.name == "id" && at.type == AttributeType::Uint64 && info.order == FrameOrder::Id) {
      info.words[first].coding = info.words[first + 1].coding = WordCoding::Id;
    } else if (is_float && !options.lossless && stats.particles() > 0) {  // no particles: nothing to grid
      // Position: the absolute bound. Scale: relative to each particle's own (sizes span orders
      // of magnitude: an absolute bound would erase the small ones). Velocity and other floats:
      // a fraction of their own range.
      if (at.name == "scale" && at.components == 1) {
        const double lo = stats.min()[component], hi = stats.max()[component];
        // Two mantissa bits more than the bound needs: about five codes are then within the
        // bound of a value, and the encoder takes the one its prediction gives (particle_encoder.cpp,
        // relative_toward()). Sizes that shrink over each particle's life, the demo fountain's,
        // then cost 2.65 -> 1.5 MB of its first 120 frames' 19.5 (one bit: 2.07; three: 1.4, and
        // the sparks' random radii 0.3 % more for each bit at birth).
        const std::uint32_t coarsest = relative_shift_for(options.scale_error);
        const std::uint32_t shift = coarsest == 0 ? 0 : std::max<std::uint32_t>(coarsest, 3) - 2;
        WordCodingEntry& entry = info.words[first];
        entry = WordCodingEntry{};  // exact unless a relative grid applies
        if (std::isfinite(lo) && std::isfinite(hi) && shift > 0) {
          entry.coding = WordCoding::Relative;
          entry.base = shift;
          entry.error = static_cast<float>(options.scale_error);
          if (double(entry.error) > options.scale_error) entry.error = std::nextafter(entry.error, 0.0f);
        }
        component += at.components;
        continue;
      }
      const double error = at.name == "position" ? position_error : 0.0;
      for (std::uint32_t c = 0; c < at.components; ++c) {
        const double lo = stats.min()[component + c], hi = stats.max()[component + c];
        double e = error > 0 ? error : fraction * (hi - lo);
        // A velocity never moves the Hermite curve between two frames by more than the position
        // bound: the curve's tangents are the velocities times the frame's time h, and their basis
        // weights sum to t(1 - t), at most 1/4, so errors within 4 e / h move it by at most e.
        if (at.name == "velocity" && fps > 0 && position_error > 0) e = std::min(e, 4.0 * position_error * fps);
        WordCodingEntry& entry = info.words[first + c];
        if (!make_grid(lo, hi, e, entry)) {
          if (at.name == "position") {
            throw Error(fmt::format(
                "positions span {}..{} on axis {}: an error bound of {} cannot be kept on a 24-bit grid at float "
                "precision; raise the error bound or use the lossless mode",
                lo, hi, "xyz"[c], e));
          }
          entry = WordCodingEntry{};  // kept exact: not finite, no range, or too fine a bound
        }
      }
    }
    if (is_float) component += at.components;
  }
  // Frames matched by position may pair particles moved on by their stored velocity, where that
  // finds them again (particle_matching.cpp).
  const Attribute* velocity = find_attribute(layout, "velocity");
  if (info.order == FrameOrder::Matched && velocity != nullptr && velocity->type == AttributeType::Float32 &&
      velocity->components == 3 && fps > 0.0 && std::isfinite(fps)) {
    const std::uint32_t first = velocity->offset / 4;
    bool quantized = true;
    for (std::uint32_t c = 0; c < 3; ++c)
      quantized = quantized && info.words[first + c].coding == WordCoding::Quantized;
    if (quantized) {
      info.velocity_word = static_cast<std::int32_t>(first);
      info.frame_seconds = 1.0 / fps;
    }
  }
  return info;
}

}  // namespace pstream::format

// ---- Comparison ---------------------------------------------------------------------------------

namespace pstream::format {

void FrameComparison::add(const std::vector<Attribute>& layout, std::span<const std::byte> decoded,
                          std::uint64_t decoded_count, const std::vector<Attribute>& source_layout,
                          std::span<const std::byte> source, std::uint64_t source_count, const CodecInfo* codec) {
  const std::uint32_t rs = record_size_of(layout), from_rs = record_size_of(source_layout);
  std::vector<std::byte> mapped(source_count * rs, std::byte{0});
  for (const Attribute& at : layout) {
    const Attribute* from = find_attribute(source_layout, at.name);
    const std::size_t size = at.size();
    if (from == nullptr || from->size() != size || size == 0) continue;
    const std::uint64_t count = std::min<std::uint64_t>(source_count, source.size() / from_rs);  // from_rs >= size
    if (count == 0) continue;  // (an empty frame's data may be null)
    const std::byte* in = source.data() + from->offset;
    std::byte* out = mapped.data() + at.offset;
    for (std::uint64_t i = 0; i < count; ++i, in += from_rs, out += rs) std::memcpy(out, in, size);
  }
  add(layout, decoded, decoded_count, mapped, source_count, codec);
}

void FrameComparison::add(const std::vector<Attribute>& layout, std::span<const std::byte> decoded,
                          std::uint64_t decoded_count, std::span<const std::byte> source, std::uint64_t source_count,
                          const CodecInfo* codec) {
  const std::uint32_t rs = record_size_of(layout), words = rs / 4;
  if (max_error.size() < words) max_error.resize(words, 0.0);
  if (max_relative_error.size() < words) max_relative_error.resize(words, 0.0);
  if (sum_squared_error.size() < words) {
    sum_squared_error.resize(words, 0.0);
    sum_squared_source.resize(words, 0.0);
    compared.resize(words, 0);
  }
  particles += decoded_count;
  if (decoded_count != source_count) ++count_mismatches;
  std::vector<bool> is_float(words, false);
  const Attribute* id = nullptr;
  for (const Attribute& a : layout) {
    if (a.name == "id") id = &a;
    for (std::uint32_t w = a.offset / 4; w < (a.offset + a.size()) / 4; ++w)
      is_float[w] = a.type == AttributeType::Float32;
  }
  const auto word = [](std::span<const std::byte> recs, std::uint32_t rsize, std::uint64_t i, std::uint32_t w) {
    std::uint32_t v;
    std::memcpy(&v, recs.data() + i * rsize + 4 * w, 4);
    return v;
  };
  const auto pair = [&](std::uint64_t d, std::uint64_t s) {
    for (std::uint32_t w = 0; w < words; ++w) {
      const std::uint32_t a = word(decoded, rs, d, w), b = word(source, rs, s, w);
      double e = 0.0;
      if (is_float[w]) {
        const float fa = std::bit_cast<float>(a), fb = std::bit_cast<float>(b);
        e = (std::isnan(fa) && std::isnan(fb)) ? 0.0 : std::abs(double(fa) - double(fb));
        if (std::isnan(e)) e = std::numeric_limits<double>::infinity();
        const double relative = e == 0.0 ? 0.0 : e / std::abs(double(fb));
        max_relative_error[w] = std::max(max_relative_error[w], std::isnan(relative) ? INFINITY : relative);
        if (std::isfinite(e) && std::isfinite(fb)) {
          sum_squared_error[w] += e * e;
          sum_squared_source[w] += double(fb) * double(fb);
          ++compared[w];
        }
      } else if (a != b) {
        e = std::numeric_limits<double>::infinity();
      }
      max_error[w] = std::max(max_error[w], e);
    }
  };
  std::vector<std::uint64_t> partner(decoded_count, UINT64_MAX);
  if (in_order && decoded_count == source_count) {
    std::iota(partner.begin(), partner.end(), std::uint64_t{0});
  } else if (id != nullptr) {
    const auto id_of = [&](std::span<const std::byte> recs, std::uint64_t i) {
      std::uint64_t v = 0;
      std::memcpy(&v, recs.data() + i * rs + id->offset, id->size());
      return v;
    };
    std::vector<std::pair<std::uint64_t, std::uint64_t>> by_id(source_count);
    for (std::uint64_t s = 0; s < source_count; ++s) by_id[s] = {id_of(source, s), s};
    std::sort(by_id.begin(), by_id.end());
    std::vector<bool> used(source_count, false);
    for (std::uint64_t d = 0; d < decoded_count; ++d) {
      auto it = std::lower_bound(by_id.begin(), by_id.end(), std::pair{id_of(decoded, d), std::uint64_t{0}});
      while (it != by_id.end() && it->first == id_of(decoded, d) && used[it->second]) ++it;
      if (it != by_id.end() && it->first == id_of(decoded, d)) {
        used[it->second] = true;
        partner[d] = it->second;
      }
    }
  } else {
    // Nearest unpaired source particle, searched in a grid of the source positions.
    const auto pos = [&](std::span<const std::byte> recs, std::uint64_t i, int c) {
      float v;
      std::memcpy(&v, recs.data() + i * rs + 4 * c, 4);
      return double(v);
    };
    double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
    for (int c = 0; c < 3; ++c) {
      lo[c] = std::numeric_limits<double>::max();
      hi[c] = -lo[c];
      for (std::uint64_t s = 0; s < source_count; ++s) {
        lo[c] = std::min(lo[c], pos(source, s, c));
        hi[c] = std::max(hi[c], pos(source, s, c));
      }
    }
    // Cells of about one particle spacing, never finer than the positions' bound (a frame of
    // one particle, or of particles on a plane, has no volume).
    const double volume = (hi[0] - lo[0]) * (hi[1] - lo[1]) * (hi[2] - lo[2]);
    double cell = std::cbrt(std::max(volume, 0.0) / double(std::max<std::uint64_t>(source_count, 1)));
    const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 0.0});
    if (codec && !codec->words.empty() && codec->words[0].coding == WordCoding::Quantized) {
      // A partner lies within the bound: cells of a few bounds keep each search small however
      // dense the particles are.
      cell = 4.0 * double(codec->words[0].error);
    }
    cell = std::max({cell, extent * 1e-6, 1e-30});
    const auto cell_of = [&](double v, int c) {
      const double x = std::floor((v - lo[c]) / cell);
      return static_cast<std::int64_t>(std::clamp(std::isnan(x) ? 0.0 : x, -1e12, 1e12));
    };
    const auto key = [](std::int64_t x, std::int64_t y, std::int64_t z) {
      return (std::uint64_t(x & 0x1fffff) << 42) | (std::uint64_t(y & 0x1fffff) << 21) | std::uint64_t(z & 0x1fffff);
    };
    // The source particles by cell, in index order within each, and where each cell's run of
    // `by_cell` starts and ends in an open-addressing table of the occupied cells (a key is 63
    // bits: all ones marks an empty slot).
    std::vector<std::pair<std::uint64_t, std::uint64_t>> by_cell(source_count);
    for (std::uint64_t s = 0; s < source_count; ++s)
      by_cell[s] = {key(cell_of(pos(source, s, 0), 0), cell_of(pos(source, s, 1), 1), cell_of(pos(source, s, 2), 2)),
                    s};
    std::sort(by_cell.begin(), by_cell.end());
    struct Cell {
      std::uint64_t key = UINT64_MAX, begin = 0, end = 0;
    };
    const int table_log = std::bit_width(std::max<std::uint64_t>(2 * source_count, 16) - 1);
    std::vector<Cell> table(std::size_t{1} << table_log);
    const auto slot_of = [&](std::uint64_t k) {
      std::size_t at = std::size_t((k * 0x9E3779B97F4A7C15ull) >> (64 - table_log));
      while (table[at].key != UINT64_MAX && table[at].key != k) at = (at + 1) & (table.size() - 1);
      return at;
    };
    for (std::uint64_t b = 0, e = 0; b < source_count; b = e) {
      for (e = b + 1; e < source_count && by_cell[e].first == by_cell[b].first;) ++e;
      table[slot_of(by_cell[b].first)] = Cell{by_cell[b].first, b, e};
    }
    // How each word is compared, once: its difference in units of its bound where it has one
    // (quantised: absolute; relative: of the source's value), any difference far where it is exact.
    // Derived words have no bound and say nothing about which particle this is.
    enum class Bound : std::uint8_t { kSkip, kQuantized, kRelative, kExact, kPlain };
    std::vector<Bound> bound(words, Bound::kSkip);
    std::vector<double> error(words, 0.0);
    for (std::uint32_t w = 0; w < words; ++w) {
      const WordCodingEntry* c = codec && w < codec->words.size() ? &codec->words[w] : nullptr;
      error[w] = c ? double(c->error) : 0.0;
      if (c && c->coding == WordCoding::Quantized && c->error > 0)
        bound[w] = Bound::kQuantized;
      else if (c && c->coding == WordCoding::Relative && c->error > 0)
        bound[w] = Bound::kRelative;
      else if (c && (c->coding == WordCoding::Exact || c->coding == WordCoding::Constant) && w >= 3)
        bound[w] = Bound::kExact;
      else if (w < 3)
        bound[w] = Bound::kPlain;
    }
    // A partner within every bound lies within each quantised position's bound of the decoded
    // particle: the cells that box overlaps (one to eight of the 27 around it) are searched first.
    // Any particle outside them is beyond a bound (more than 1 in its units), so a partner found
    // there within every bound is the one the 27 cells would give (visited in the same order).
    const bool boxed = bound[0] == Bound::kQuantized && bound[1] == Bound::kQuantized && bound[2] == Bound::kQuantized;
    std::vector<bool> used(source_count, false);
    for (std::uint64_t d = 0; d < decoded_count; ++d) {
      const std::int64_t cx = cell_of(pos(decoded, d, 0), 0), cy = cell_of(pos(decoded, d, 1), 1),
                         cz = cell_of(pos(decoded, d, 2), 2);
      double best = std::numeric_limits<double>::infinity();
      // The nearest unused source particle in cells [from, to] (each within 1 of the home cell).
      const auto search = [&](const std::int64_t* from, const std::int64_t* to) {
        for (std::int64_t x = from[0]; x <= to[0]; ++x) {
          for (std::int64_t y = from[1]; y <= to[1]; ++y) {
            for (std::int64_t z = from[2]; z <= to[2]; ++z) {
              const Cell& run = table[slot_of(key(x, y, z))];
              for (std::uint64_t r = run.begin; r < run.end; ++r) {
                const std::uint64_t s = by_cell[r].second;
                if (used[s]) continue;
                double e = 0.0;
                for (std::uint32_t w = 0; w < words; ++w) {
                  if (bound[w] == Bound::kSkip) continue;
                  if (bound[w] == Bound::kExact) {
                    if (word(decoded, rs, d, w) != word(source, rs, s, w)) e = std::max(e, 1e6);
                    continue;
                  }
                  const float fx = std::bit_cast<float>(word(decoded, rs, d, w));
                  const float fy = std::bit_cast<float>(word(source, rs, s, w));
                  const double diff = std::abs(double(fx) - double(fy));
                  if (bound[w] == Bound::kQuantized)
                    e = std::max(e, diff / error[w]);
                  else if (bound[w] == Bound::kRelative)
                    e = std::max(e, diff / (error[w] * std::max(std::abs(double(fy)), 1e-30)));
                  else
                    e = std::max(e, diff);
                }
                if (e < best) {
                  best = e;
                  partner[d] = s;
                }
              }
            }
          }
        }
      };
      const std::int64_t home[3] = {cx, cy, cz};
      if (boxed) {
        std::int64_t from[3], to[3];
        for (int c = 0; c < 3; ++c) {
          // The bound and a margin for the rounding of v ± bound, so that no particle within it
          // falls outside the box.
          const double v = pos(decoded, d, c), reach = error[std::size_t(c)] * (1 + 1e-6) + std::abs(v) * 1e-15;
          from[c] = std::max(home[c] - 1, cell_of(v - reach, c));
          to[c] = std::min(home[c] + 1, cell_of(v + reach, c));
        }
        search(from, to);
      }
      if (!(best <= 1.0)) {  // none within every bound there: the 27 cells, as if afresh
        best = std::numeric_limits<double>::infinity();
        partner[d] = UINT64_MAX;
        const std::int64_t from[3] = {cx - 1, cy - 1, cz - 1}, to[3] = {cx + 1, cy + 1, cz + 1};
        search(from, to);
      }
      if (partner[d] != UINT64_MAX) used[partner[d]] = true;
    }
  }
  for (std::uint64_t d = 0; d < decoded_count; ++d) {
    if (partner[d] == UINT64_MAX)
      ++unmatched;
    else
      pair(d, partner[d]);
  }
}

}  // namespace pstream::format
