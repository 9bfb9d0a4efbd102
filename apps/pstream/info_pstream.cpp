// `pstream info FILE.pstream` and `pstream verify FILE.pstream`.
#include <cstring>
#include <fstream>
#include <map>
#include <optional>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <unistd.h>

#include <cmath>
#include <filesystem>

#include "base/mapped_file.hpp"
#include "cli_terms.hpp"
#include "commands.hpp"
#include "particlestream/codec.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/format.hpp"
#include "progress.hpp"

namespace pstream::app {
namespace {

using namespace pstream::format;
using json = nlohmann::ordered_json;

json layout_json(const Metadata& m) {
  json out = json::array();
  for (const Attribute& a : m.layout) {
    out.push_back(
        {{"name", a.name}, {"type", attribute_type_name(a.type)}, {"components", a.components}, {"offset", a.offset}});
  }
  return out;
}

std::uint64_t stored_bytes(const Metadata& m) {
  std::uint64_t s = 0;
  for (const ChunkEntry& c : m.chunks) s += c.stored_size;
  return s;
}

std::string_view coding_name(WordCoding c) {
  const format::WordCodingType* type = format::find_word_coding(c);
  return type ? type->name : "?";
}

// A frame order's name (JSON) and what it means (text).
struct OrderWords {
  std::string_view name, phrase;
};
OrderWords order_words(FrameOrder o) {
  switch (o) {
    case FrameOrder::Source: return {"source", "in the source's order"};
    case FrameOrder::Id: return {"id", "in id order, survivors found by id"};
    case FrameOrder::Matched: return {"matched", "survivors matched by position (no ids)"};
  }
  return {"?", "in an unknown order"};
}

double bytes_per_particle(const Metadata& m) {
  const std::uint64_t n = m.total_particles();
  return n ? double(stored_bytes(m)) / double(n) : 0.0;
}

// The frame codec and, for the particle codec, how each attribute is coded and its bound.
json codec_json(const Metadata& m) {
  json j{{"name", frame_codec_name(m.codec.codec)}, {"bytes_per_particle", bytes_per_particle(m)}};
  if (m.codec.codec != FrameCodec::Particle) return j;
  j["lossless"] = m.codec.lossless;
  j["order"] = order_words(m.codec.order).name;
  j["keyframe_interval"] = m.codec.keyframe_interval;
  j["error"] = m.codec.error;
  json attributes = json::array();
  for (const Attribute& a : m.layout) {
    json words = json::array();
    for (std::uint32_t w = a.offset / 4; w < (a.offset + a.size()) / 4; ++w) {
      const WordCodingEntry& e = m.codec.words[w];
      json word{{"coding", coding_name(e.coding)}};
      if (e.coding == WordCoding::Quantized) {
        word["step"] = e.step;
        word["error"] = e.error;
      } else if (e.coding == WordCoding::Relative) {
        word["shift"] = e.base;
        word["relative_error"] = e.error;
      }
      words.push_back(word);
    }
    attributes.push_back({{"name", a.name}, {"words", words}});
  }
  j["attributes"] = attributes;
  return j;
}

json bounds_json(const std::array<float, 6>& b) {
  return json{{"min", {b[0], b[1], b[2]}}, {"max", {b[3], b[4], b[5]}}};
}

}  // namespace

namespace {

// The first bytes of a file (fewer when it is shorter). Refuses FIFOs and other special files
// (reading one could block forever).
std::string first_bytes(const std::string& file, std::size_t n) {
  std::uint64_t size = 0;
  const int fd = open_regular_file(file, size);
  std::string out(n, '\0');
  const ssize_t got = ::pread(fd, out.data(), n, 0);
  ::close(fd);
  out.resize(got > 0 ? static_cast<std::size_t>(got) : 0);
  return out;
}

}  // namespace

// A URL is read as a clip unless its path ends in .abc (or .ply: a PLY sequence), without a request of its own to sniff
// it: the reader's header check (format::parse_header) gives the same "cook it first" message for anything else.
bool is_pstream_file(const std::string& file) {
  if (!io::is_url(file)) return first_bytes(file, 8) == std::string("PSTREAM\0", 8);
  std::string path = file.substr(0, file.find_first_of("?#"));
  std::transform(path.begin(), path.end(), path.begin(), [](unsigned char c) { return std::tolower(c); });
  return !path.ends_with(".abc") && !path.ends_with(".ply");
}

void require_cooked(const std::string& file) {
  if (io::is_url(file)) return;
  const std::string magic = first_bytes(file, 8);
  if (magic.empty()) return;  // unreadable or empty: the command's own open says so
  format::check_magic(std::as_bytes(std::span(magic.data(), magic.size())), file);
}

int info_pstream(const InfoPstreamOptions& options) {
  const Reader reader = Reader::open(options.file);
  const Metadata& m = reader.metadata();
  std::map<std::string, std::uint64_t> codecs;
  for (const ChunkEntry& c : m.chunks) ++codecs[std::string(codec_name(c.codec))];
  const std::uint64_t stored = stored_bytes(m);
  const double ratio = stored ? double(m.stream_size()) / double(stored) : 1.0;
  const double decoded_ratio = stored ? double(m.decoded_size()) / double(stored) : 1.0;
  if (options.json) {
    json j{
        {"format", "pstream"},
        {"file", options.file},
        {"version", m.version},
        {"flags",
         {{"xforms_baked", (m.flags & kFlagXformsBaked) != 0}, {"interpolated", (m.flags & kFlagInterpolated) != 0}}},
        {"source", {{"file", m.source_file}, {"object", m.source_object}}},
        {"cooked_with", m.cooked_with},
        {"fps", m.fps},
        {"time_of_frame0", m.time_of_frame0},
        {"frame_count", m.frame_count()},
        {"particles", {{"min", m.min_count}, {"avg", m.avg_count}, {"max", m.max_count}}},
        {"bounds", bounds_json(m.bounds)},
        {"record_size", m.record_size},
        {"layout", layout_json(m)},
        {"chunk_size", m.chunk_size},
        {"chunk_count", m.chunk_count()},
        {"particles_per_chunk", m.particles_per_chunk()},
        {"stream_bytes", m.stream_size()},
        {"decoded_bytes", m.decoded_size()},
        {"stored_bytes", stored},
        {"file_bytes", reader.file_size()},
        {"compression_ratio", ratio},
        {"codecs", codecs},
        {"frame_codec", codec_json(m)}};
    if (options.frames) {
      json frames = json::array();
      std::vector<std::byte> buffer = format::frame_buffer(m, options.file);
      for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
        reader.read_frame(f, buffer);
        double sum[4] = {0, 0, 0, 0};
        for (std::uint64_t i = 0; i < m.frames[f].count; ++i) {
          float rec[4];
          std::memcpy(rec, buffer.data() + i * m.record_size, 16);
          for (int c = 0; c < 4; ++c) sum[c] += rec[c];
        }
        frames.push_back({{"index", f}, {"time", m.frames[f].time}, {"count", m.frames[f].count}, {"sum", sum}});
      }
      j["frames"] = frames;
    }
    fmt::print("{}\n", j.dump(1));
    return 0;
  }
  fmt::print("{}: ParticleStream clip (format version {}), {:.1f} MiB\n", options.file, m.version,
             reader.file_size() / 1048576.0);
  fmt::print("  source        {} {}\n", m.source_file, m.source_object);
  if (!m.cooked_with.empty()) fmt::print("  cooked with   {}\n", m.cooked_with);
  fmt::print("  frames        {} at {:.6g} fps, from {:.6g} s{}{}\n", m.frame_count(), m.fps, m.time_of_frame0,
             m.flags & kFlagXformsBaked ? ", world space" : ", object space",
             m.flags & kFlagInterpolated ? ", interpolated" : "");
  fmt::print("  particles     min {} / avg {:.1f} / max {} per frame\n", m.min_count, m.avg_count, m.max_count);
  fmt::print("  bounds        ({:.4g}, {:.4g}, {:.4g}) .. ({:.4g}, {:.4g}, {:.4g})\n", m.bounds[0], m.bounds[1],
             m.bounds[2], m.bounds[3], m.bounds[4], m.bounds[5]);
  fmt::print("  record        {} bytes:", m.record_size);
  for (const Attribute& a : m.layout) {
    fmt::print(" {}({}{})@{}", a.name, attribute_type_name(a.type),
               a.components > 1 ? fmt::format("x{}", a.components) : "", a.offset);
  }
  fmt::print("\n  chunks        {} of {} KiB ({:.0f} particles each)", m.chunk_count(), m.chunk_size >> 10,
             m.particles_per_chunk());
  for (const auto& [name, n] : codecs) fmt::print(", {} {}", n, name);
  fmt::print(
      "\n  size          {:.1f} MiB of records stored in {:.1f} MiB: compression {:.2f}x, {:.2f} bytes per "
      "particle per frame\n",
      m.decoded_size() / 1048576.0, stored / 1048576.0, decoded_ratio, bytes_per_particle(m));
  if (m.codec.codec == FrameCodec::Particle) {
    fmt::print("  frame codec   particle{}, keyframe every {} frames, {}\n", m.codec.lossless ? " (lossless)" : "",
               m.codec.keyframe_interval, order_words(m.codec.order).phrase);
    for (const Attribute& a : m.layout) {
      fmt::print("    {:<12}", a.name);
      for (std::uint32_t w = a.offset / 4; w < (a.offset + a.size()) / 4; ++w) {
        const WordCodingEntry& e = m.codec.words[w];
        if (e.coding == WordCoding::Quantized)
          fmt::print(" quantized(within {:.3g})", e.error);
        else if (e.coding == WordCoding::Relative)
          fmt::print(" relative(within {:.3g}% of its value)", 100.0 * e.error);
        else if (e.coding == WordCoding::Derived)
          fmt::print(" derived from the matched positions (not stored)");
        else
          fmt::print(" {}", coding_name(e.coding));
        if (e.coding == WordCoding::Id || e.coding == WordCoding::Derived) break;
      }
      fmt::print("\n");
    }
  }
  return 0;
}

int verify_pstream(const std::string& file, bool as_json, const std::string& against) {
  // A bar a stage (the last stage of a long verify --against is the source's reading).
  std::optional<ProgressBar> bar;
  int stage = -1;
  const cook::VerifyReport r = cook::verify(file, against, [&](const cook::VerifyProgress& p) {
    if (int(p.stage) != stage) {
      stage = int(p.stage);
      constexpr const char* kLabels[] = {"verify: checksums", "verify: decode", "verify: compare"};
      bar.emplace(kLabels[stage], !as_json);
    }
    bar->update(p.done, p.total, p.stage == cook::VerifyProgress::Checksums ? "chunks" : "frames");
  });
  bar.reset();
  json attributes = json::array();
  for (const cook::AttributeCheck& a : r.attributes) {
    attributes.push_back({{"name", a.name},
                          {"max_error", a.max_error},
                          {"bound", a.exact ? 0.0 : a.bound},
                          {"relative", a.relative},
                          {"ok", a.ok}});
    if (a.counted) {
      attributes.back()["distinct_clip"] = a.distinct_clip;
      attributes.back()["distinct_source"] = a.distinct_source;
      attributes.back()["distinct_counted_up_to"] = cook::kDistinctValuesCounted;
      attributes.back()["kept_apart"] = a.kept_apart;
    }
    if (a.derived) {
      attributes.back()["derived"] = true;
      attributes.back()["in_source"] = a.in_source;
      attributes.back()["rms_error"] = a.rms_error;
      attributes.back()["rms_source"] = a.rms_source;
    }
  }
  json comparison;
  if (!r.source.empty()) {
    comparison = json{{"source", r.source},
                      {"frames_compared", r.frames_compared},
                      {"particles", r.particles_compared},
                      {"attributes", attributes}};
  }
  if (as_json) {
    fmt::print("{}\n", json{{"file", file},
                            {"ok", r.ok()},
                            {"chunks_verified", r.chunks_verified},
                            {"frames", r.frames},
                            {"errors", r.errors},
                            {"against", comparison}}
                           .dump());
  } else if (r.ok()) {
    fmt::print("{}: OK — {}, {}, every checksum and index entry verified{}\n", file, count_of(r.frames, "frame"),
               count_of(r.chunks_verified, "chunk"),
               against.empty() ? "" : ", every value within its bound of the source");
    for (const cook::AttributeCheck& a : r.attributes) {
      if (a.derived && !a.in_source) {
        fmt::print("  {:<12} derived from the matched positions; the source has none to compare with\n", a.name);
        continue;
      }
      if (a.derived) {
        fmt::print(
            "  {:<12} derived from the matched positions: RMS error {:.4g} ({:.1f}% of the source's RMS {:.4g}), "
            "max {:.4g}\n",
            a.name, a.rms_error, a.rms_source > 0 ? 100.0 * a.rms_error / a.rms_source : 0.0, a.rms_source,
            a.max_error);
        continue;
      }
      const std::string bound = a.exact      ? std::string("0, exact")
                                : a.relative ? fmt::format("{:.3g}% of each value", 100.0 * a.bound)
                                             : fmt::format("{:.6g}", a.bound);
      const std::string error =
          a.relative ? fmt::format("{:.3g}%", 100.0 * a.max_error) : fmt::format("{:.6g}", a.max_error);
      fmt::print("  {:<12} max error {} (bound {})", a.name, error, bound);
      if (a.counted) {
        const auto count = [](std::uint64_t n) {
          return n >= cook::kDistinctValuesCounted ? fmt::format("{} or more", n) : fmt::format("{}", n);
        };
        fmt::print("; distinct values: {} in the clip, {} in the source", count(a.distinct_clip),
                   count(a.distinct_source));
        if (a.kept_apart != a.distinct_source) fmt::print(", of which the bound keeps {} apart", a.kept_apart);
      }
      fmt::print("\n");
    }
  } else {
    for (const auto& e : r.errors) fmt::print(stderr, "{}\n", e);
    fmt::print(stderr, "{}: FAILED — {} problem(s)\n", file, r.errors.size());
  }
  return r.ok() ? 0 : 1;
}

}  // namespace pstream::app
