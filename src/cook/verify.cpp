// cook::verify: a cooked clip's checksums, decoding, and every attribute against its bound.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <unordered_set>

#include <fmt/format.h>
#include <xxhash.h>

#include "base/mapped_file.hpp"

#include "particlestream/codec.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"

namespace pstream::cook {
namespace {

using namespace pstream::format;

// How many of `values` (float bit patterns) a bound must keep apart: the most whose intervals
// (each value within `bound` of itself, or within `bound` of its own magnitude when `relative`) do
// not overlap, so that no decoded value can stand for two of them. Intervals taken by their ends,
// each one that starts past the end of the last one taken (interval scheduling).
std::uint64_t kept_apart(const std::unordered_set<std::uint32_t>& values, double bound, bool relative) {
  std::vector<std::pair<double, double>> intervals;  // (end, start)
  intervals.reserve(values.size());
  for (const std::uint32_t bits : values) {
    float f;
    std::memcpy(&f, &bits, 4);
    if (!std::isfinite(f)) continue;
    const double v = f, r = relative ? bound * std::abs(v) : bound;
    intervals.emplace_back(v + r, v - r);
  }
  std::sort(intervals.begin(), intervals.end());
  std::uint64_t kept = 0;
  double end = -std::numeric_limits<double>::infinity();
  for (const auto& [hi, lo] : intervals) {
    if (lo > end) {
      ++kept;
      end = hi;
    }
  }
  return kept;
}

// The source read again as a records cook reads it (read_frames: the clip's layout, fps and
// transforms, nothing written), every frame compared with the clip's frame of the same time.
void compare_with_source(const Reader& reader, const std::filesystem::path& source, VerifyReport& report,
                         const std::function<void(const VerifyProgress&)>& progress) {
  const Metadata& m = reader.metadata();
  Options o;
  o.input = source;
  o.object = m.source_object.find(',') == std::string::npos ? m.source_object : std::string();
  o.merge = m.source_object.find(',') != std::string::npos;
  o.bake_xforms = (m.flags & kFlagXformsBaked) != 0;
  o.interpolate = (m.flags & kFlagInterpolated) != 0;
  o.fps = m.fps;
  o.frame_codec = FrameCodec::Records;  // the source's exact values, raw
  o.codec = Codec::Raw;
  o.color_from = m.find("color") ? "Cd" : "none";
  // A derived velocity is compared with the source's, when it has one.
  const Attribute* velocity = m.find("velocity");
  const bool derived = m.codec.codec == FrameCodec::Particle && velocity != nullptr &&
                       m.codec.words[velocity->offset / 4].coding == WordCoding::Derived;
  o.keep_velocity = derived;  // otherwise the clip's attributes, no more
  for (const Attribute& a : m.layout) {
    if (a.name == "position" || a.name == "scale" || a.name == "color" || (derived && a.name == "velocity")) continue;
    o.attributes.push_back(a.name == "id" && a.type == AttributeType::Uint32 ? "id32" : a.name);
  }
  report.source = source.string();
  std::vector<std::byte> a = frame_buffer(m, reader.name());
  FrameComparison c;
  // A clip ordered by id lists each frame's particles as read_frames gives the source's (in id
  // order): pairing by position could take a near neighbour in a dense cloud for the particle.
  c.in_order = m.codec.codec == FrameCodec::Particle && m.codec.order == FrameOrder::Id;
  // Distinct values of every word but the positions', in the source and the clip, counted up to
  // kDistinctValuesCounted.
  const std::uint32_t words = m.record_size / 4;
  std::vector<std::unordered_set<std::uint32_t>> seen_source(words), seen_clip(words);
  // Every attribute's distinct values are counted but the positions' (a census of no use).
  const auto counted = [](const Attribute& at) { return at.name != "position"; };
  // `recs` in `lm`'s layout; each of the clip's words is found there by attribute name.
  const auto note = [&](std::vector<std::unordered_set<std::uint32_t>>& seen, std::span<const std::byte> recs,
                        std::uint64_t count, const Metadata& lm) {
    for (const Attribute& at : m.layout) {
      const Attribute* from = lm.find(at.name);
      if (!counted(at) || from == nullptr || from->size() != at.size()) continue;
      for (std::uint32_t w = at.offset / 4; w < (at.offset + at.size()) / 4; ++w) {
        const std::uint32_t at_byte = from->offset + 4 * w - at.offset;
        for (std::uint64_t i = 0; i < count && seen[w].size() < kDistinctValuesCounted; ++i) {
          std::uint32_t v;
          std::memcpy(&v, recs.data() + i * lm.record_size + at_byte, 4);
          seen[w].insert(v);
        }
      }
    }
  };
  // The clip's frames walked beside the source's, by time: a clip frame passed over had no
  // source frame at its time.
  const double tolerance = 0.25 / m.fps;
  std::uint64_t f = 0;
  const auto no_source_frame = [&] {
    report.errors.push_back(
        fmt::format("frame {} (time {}): the source has no frame at that time", f, m.frames[f].time));
    ++f;
  };
  bool source_velocity = false, layouts_differ = false;
  read_frames(o, [&](const Metadata& sm, const CookedFrame& s) {
    if (s.index == 0) {
      // Attributes are compared by name (a derived velocity: the source may have none, compared
      // as 0, or place it elsewhere); every other attribute of the clip must be in the source.
      source_velocity = sm.find("velocity") != nullptr;
      for (const Attribute& at : m.layout) {
        const Attribute* from = sm.find(at.name);
        if ((from == nullptr || from->size() != at.size()) && !(derived && at.name == "velocity")) {
          report.errors.push_back(
              fmt::format("{}: the source cooks to {}-byte records without the clip's '{}' ({} bytes)", source.string(),
                          sm.record_size, at.name, at.size()));
          layouts_differ = true;
          return false;
        }
      }
    }
    while (f < m.frame_count() && m.frames[f].time < s.time - tolerance) no_source_frame();
    if (f == m.frame_count()) return false;
    if (std::abs(s.time - m.frames[f].time) > tolerance) return true;  // between the clip's frames
    reader.read_frame(f, a);
    c.add(m.layout, a, m.frames[f].count, sm.layout, s.records, s.count, &m.codec);
    note(seen_clip, a, m.frames[f].count, m);
    note(seen_source, s.records, s.count, sm);
    ++report.frames_compared;
    ++f;
    if (progress) progress({VerifyProgress::Compare, f, m.frame_count()});
    return true;
  });
  if (layouts_differ) return;
  while (f < m.frame_count()) no_source_frame();
  report.particles_compared = c.particles;
  const bool particle = m.codec.codec == FrameCodec::Particle;
  for (const Attribute& at : m.layout) {
    AttributeCheck check;
    check.name = at.name;
    check.counted = counted(at);
    for (std::uint32_t w = at.offset / 4; w < (at.offset + at.size()) / 4; ++w) {
      const WordCodingEntry* e = particle ? &m.codec.words[w] : nullptr;
      const format::WordCodingType* type = e ? format::find_word_coding(e->coding) : nullptr;
      const bool relative = type && type->relative;
      const bool bounded = type && type->bounded;
      check.relative = check.relative || relative;
      if (bounded) {
        check.exact = false;
        check.bound = std::max(check.bound, double(e->error));
      }
      if (w < c.max_error.size())
        check.max_error = std::max(check.max_error, relative ? c.max_relative_error[w] : c.max_error[w]);
      check.distinct_source = std::max<std::uint64_t>(check.distinct_source, seen_source[w].size());
      check.distinct_clip = std::max<std::uint64_t>(check.distinct_clip, seen_clip[w].size());
      // How many sizes, ages or speeds the bound keeps: the source's values whose bounds do not
      // overlap stay distinct in the clip (the bound checked below implies it); an exact word keeps
      // every value, bit for bit.
      if (check.counted && !(e && e->coding == WordCoding::Derived)) {
        const std::uint64_t apart = bounded && at.type == AttributeType::Float32
                                        ? kept_apart(seen_source[w], double(e->error), relative)
                                        : seen_source[w].size();
        check.kept_apart = std::max(check.kept_apart, apart);
      }
      if (e && e->coding == WordCoding::Derived && w < c.compared.size() && c.compared[w] != 0) {
        check.derived = true;
        check.exact = false;
        check.in_source = source_velocity;
        const double n = double(c.compared[w]);
        check.rms_error = std::max(check.rms_error, std::sqrt(c.sum_squared_error[w] / n));
        check.rms_source = std::max(check.rms_source, std::sqrt(c.sum_squared_source[w] / n));
      }
    }
    if (check.derived) {  // no bound to hold: reported, never failed
      report.attributes.push_back(check);
      continue;
    }
    check.ok = check.exact ? check.max_error == 0.0 : check.max_error <= check.bound;
    if (!check.ok) {
      report.errors.push_back(
          fmt::format("attribute '{}': decoded values differ from the source by up to {:.6g}{}, the bound is {}",
                      at.name, check.max_error, check.relative ? " of their value" : "",
                      check.exact ? std::string("0 (exact)")
                                  : fmt::format("{:.6g}{}", check.bound, check.relative ? " of each value" : "")));
    }
    report.attributes.push_back(check);
  }
  if (c.unmatched || c.count_mismatches) {
    report.errors.push_back(
        fmt::format("{} particles found no partner in the source; {} frames have other particle counts", c.unmatched,
                    c.count_mismatches));
  }
}

}  // namespace

VerifyReport verify(const std::filesystem::path& file, const std::filesystem::path& against,
                    const std::function<void(const VerifyProgress&)>& progress) {
  VerifyReport report;
  report.file = file.string();
  try {
    const Reader reader = Reader::open(file);  // header, tables, frame index, chunk bounds
    const Metadata& m = reader.metadata();
    report.frames = m.frame_count();
    std::vector<std::byte> scratch(m.chunk_size);
    for (std::uint64_t c = 0; c < m.chunk_count(); ++c) {
      try {
        reader.read_chunk(c, scratch);  // checksum and decode
        ++report.chunks_verified;
        if (progress) progress({VerifyProgress::Checksums, c + 1, m.chunk_count()});
      } catch (const Error& e) {
        report.errors.push_back(e.what());
      }
    }
    // Every frame decodes (in order: a predicted frame needs the one before it).
    if (report.errors.empty()) {
      std::vector<std::byte> records = frame_buffer(m, file.string());
      for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
        try {
          reader.read_frame(f, records);
          if (progress) progress({VerifyProgress::Decode, f + 1, m.frame_count()});
        } catch (const Error& e) {
          report.errors.push_back(e.what());
          break;
        }
      }
    }
    if (report.errors.empty() && !against.empty()) compare_with_source(reader, against, report, progress);
  } catch (const Error& e) {
    report.errors.push_back(e.what());
  }
  return report;
}

bool is_source_of(const format::Metadata& meta, const std::filesystem::path& file) {
  const auto field = [&](std::string_view key) {
    const std::string& c = meta.cooked_with;
    const std::size_t at = c.find(key);
    if (at == std::string::npos || (at > 0 && c[at - 1] != ' ')) return std::string();
    const std::size_t end = c.find(' ', at);
    return c.substr(at + key.size(), end == std::string::npos ? std::string::npos : end - at - key.size());
  };
  const std::string name = field("source="), hash = field("source_xxh3=");
  std::error_code ec;
  if (name.empty() || hash.empty() || file.filename().string() != name || !std::filesystem::is_regular_file(file, ec))
    return false;
  try {
    const MappedFile mapped = MappedFile::open(file);
    const auto bytes = mapped.bytes();
    return fmt::format("{:016x}", XXH3_64bits(bytes.data(), bytes.size())) == hash;
  } catch (const Error&) {
    return false;
  }
}

}  // namespace pstream::cook
