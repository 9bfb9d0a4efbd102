// export_clip(): a cooked clip back out for a DCC, as a binary PLY sequence (one file a frame) or
// an Alembic points cache written by our Alembic writer.
#include <algorithm>
#include <cctype>
#include <cstring>
#include <filesystem>
#include <optional>

#include <fmt/format.h>

#include "base/output_file.hpp"
#include "particlestream/alembic_writer.hpp"
#include "particlestream/codec.hpp"
#include "particlestream/cook.hpp"
#include "particlestream/error.hpp"

namespace pstream::cook {
namespace {

using namespace pstream::format;
namespace fs = std::filesystem;

// One frame's records as columns: what both writers take.
struct Columns {
  std::vector<float> position, scale_width, velocity;
  std::vector<std::uint64_t> id;
  std::vector<std::uint8_t> color;                 // RGBA8
  std::vector<std::vector<float>> floats;          // other float attributes
  std::vector<const Attribute*> float_attributes;  // their layout entries
};

void split(const Metadata& m, std::span<const std::byte> records, std::uint64_t n, Columns& c) {
  const auto get = [&](const Attribute& a, std::uint64_t i, std::size_t k, auto& out) {
    std::memcpy(&out, records.data() + i * m.record_size + a.offset + k * sizeof(out), sizeof(out));
  };
  // Each column the clip has is sized for the frame, even an empty one (an empty frame is an
  // empty sample with every property, not a sample with some missing).
  c.position.resize(n * 3);
  c.scale_width.resize(n);
  c.velocity.assign(m.find("velocity") ? n * 3 : 0, 0.0f);
  c.id.assign(m.find("id") ? n : 0, 0);
  c.color.assign(m.find("color") ? n * 4 : 0, 0);
  c.floats.assign(c.float_attributes.size(), {});
  for (const Attribute& a : m.layout) {
    for (std::uint64_t i = 0; i < n; ++i) {
      if (a.name == "position") {
        for (std::size_t k = 0; k < 3; ++k) get(a, i, k, c.position[i * 3 + k]);
      } else if (a.name == "scale") {
        get(a, i, 0, c.scale_width[i]);
      } else if (a.name == "velocity") {
        for (std::size_t k = 0; k < 3; ++k) get(a, i, k, c.velocity[i * 3 + k]);
      } else if (a.name == "id") {
        if (a.type == AttributeType::Uint64) {
          get(a, i, 0, c.id[i]);
        } else {
          std::uint32_t v;
          get(a, i, 0, v);
          c.id[i] = v;
        }
      } else if (a.name == "color") {
        std::memcpy(&c.color[i * 4], records.data() + i * m.record_size + a.offset, 4);
      }
    }
  }
  for (std::size_t e = 0; e < c.float_attributes.size(); ++e) {
    const Attribute& a = *c.float_attributes[e];
    c.floats[e].resize(n * a.components);
    for (std::uint64_t i = 0; i < n; ++i)
      for (std::size_t k = 0; k < a.components; ++k) get(a, i, k, c.floats[e][i * a.components + k]);
  }
}

// A PLY header is lines of words: a name is data, never syntax. Names with a space (or anything
// the reader's validation lets through but a PLY word cannot hold) are refused; text in the
// comment is escaped.
const std::string& ply_word(const std::string& name, const std::string& input) {
  if (name.find_first_of(" \t\r\n\v\f") != std::string::npos || !format::is_valid_name(name)) {
    throw Error(
        fmt::format("{}: the attribute \"{}\" cannot be a PLY property name (it is not one word); export "
                    "to Alembic (NAME.abc) instead",
                    input, format::escaped_name(name)));
  }
  return name;
}

// A PLY sequence's ids: whether it has them, whether every one fits a PLY uint (else all are
// doubles, exact to 2^53) — the same in every file — and this frame's.
struct PlyIds {
  bool present = false, fit32 = true;
  std::span<const std::uint64_t> values;
};

// A binary little-endian PLY of one frame, complete or not at all (never over `input`). Returns
// its size.
std::uint64_t write_ply(const fs::path& path, const Metadata& m, const Columns& c, const PlyIds& ids, std::uint64_t n,
                        const std::string& input) {
  std::string header = fmt::format(
      "ply\nformat binary_little_endian 1.0\ncomment pstream export of {} {}\n"
      "element vertex {}\nproperty float x\nproperty float y\nproperty float z\n"
      "property float pscale\n",
      format::escaped_name(m.source_file), format::escaped_name(m.source_object), n);
  // The clip's attributes decide the properties, so that every file of the sequence (an empty
  // frame's too) has the same ones.
  const bool velocity = m.find("velocity") != nullptr, color = m.find("color") != nullptr, id = ids.present;
  if (velocity) header += "property float vx\nproperty float vy\nproperty float vz\n";
  if (color) header += "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n";
  if (id) header += ids.fit32 ? "property uint id\n" : "property double id\n";
  for (const Attribute* a : c.float_attributes) {
    for (std::size_t k = 0; k < a->components; ++k)
      header += a->components == 1 ? fmt::format("property float {}\n", ply_word(a->name, input))
                                   : fmt::format("property float {}_{}\n", ply_word(a->name, input), k);
  }
  header += "end_header\n";
  std::vector<std::byte> body(reinterpret_cast<const std::byte*>(header.data()),
                              reinterpret_cast<const std::byte*>(header.data() + header.size()));
  const auto put = [&](const auto& v) {
    const auto* b = reinterpret_cast<const std::byte*>(&v);
    body.insert(body.end(), b, b + sizeof(v));
  };
  for (std::uint64_t i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) put(c.position[i * 3 + k]);
    put(c.scale_width[i]);  // pscale is a radius, as the record's scale
    if (velocity)
      for (int k = 0; k < 3; ++k) put(c.velocity[i * 3 + k]);
    if (color)
      for (int k = 0; k < 4; ++k) put(c.color[i * 4 + k]);
    if (id) {
      if (ids.fit32)
        put(static_cast<std::uint32_t>(ids.values[i]));
      else
        put(static_cast<double>(ids.values[i]));
    }
    for (std::size_t e = 0; e < c.floats.size(); ++e)
      for (std::size_t k = 0; k < c.float_attributes[e]->components; ++k)
        put(c.floats[e][i * c.float_attributes[e]->components + k]);
  }
  const fs::path inputs[] = {fs::path(input)};
  write_file(path, body, inputs);
  return body.size();
}

// Ids for a clip that keeps none (Alembic wants them): a particle the codec's matching carries
// over from the frame before keeps its id, and every other particle takes the next unused number.
// Where the codec gives no matching (a keyframe, a clip in source order, the records codec) no
// particle is known to persist, so each takes a new one: an id never names two particles.
class MatchedIds {
 public:
  explicit MatchedIds(const Metadata& m) : runs_(2 * m.max_count + 1) {}
  std::span<MatchRun> runs() { return runs_; }

  // This frame's ids from the runs read_frame() gave (or kNoMatching).
  std::span<const std::uint64_t> next(std::uint64_t count, std::size_t run_count) {
    cur_.resize(count);
    std::uint64_t i = 0, j = 0;
    if (run_count != kNoMatching) {  // the decoder checked that the runs cover both frames; so does this
      std::uint64_t from = 0, to = 0;
      for (const MatchRun& r : std::span(runs_).first(run_count)) {
        from += std::uint64_t{r.keep} + r.drop;
        to += std::uint64_t{r.keep} + r.insert;
      }
      if (from != prev_.size() || to != count) run_count = kNoMatching;
    }
    if (run_count != kNoMatching) {
      for (const MatchRun& r : std::span(runs_).first(run_count)) {
        for (std::uint32_t t = 0; t < r.keep; ++t) cur_[j++] = prev_[i++];
        i += r.drop;
        for (std::uint32_t t = 0; t < r.insert; ++t) cur_[j++] = next_++;
      }
    }
    while (j < count) cur_[j++] = next_++;  // no matching: all new
    prev_.swap(cur_);
    return prev_;
  }

 private:
  std::vector<MatchRun> runs_;
  std::vector<std::uint64_t> prev_, cur_;
  std::uint64_t next_ = 0;
};

}  // namespace

ExportReport export_clip(const ExportOptions& options,
                         const std::function<void(std::uint64_t done, std::uint64_t total)>& progress) {
  const std::string& input = options.input;
  const fs::path& output = options.output;
  const fs::path inputs[] = {fs::path(input)};
  std::error_code ec;
  if (fs::equivalent(output, input, ec)) check_output(output, inputs);  // the data-loss message first
  std::string ext = output.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char ch) { return char(std::tolower(ch)); });
  ExportReport report;
  report.ply = ext == ".ply";
  if (!report.ply && ext != ".abc") {
    throw Error(
        fmt::format("{}: the extension chooses the format: .abc (an Alembic cache) or .ply (a PLY sequence, "
                    "NAME.0001.ply ...); '{}' is neither",
                    output.string(), ext.empty() ? std::string("no extension") : ext));
  }
  const Reader reader = Reader::open(input);
  const Metadata& m = reader.metadata();
  Columns c;
  for (const Attribute& a : m.layout) {
    const bool known =
        a.name == "position" || a.name == "scale" || a.name == "velocity" || a.name == "id" || a.name == "color";
    if (!known && a.type == AttributeType::Float32) c.float_attributes.push_back(&a);
  }
  const std::uint64_t first = static_cast<std::uint64_t>(std::max<std::int64_t>(options.frame_begin, 0));
  const std::uint64_t end =
      options.frame_end < 0 ? m.frame_count() : std::min<std::uint64_t>(options.frame_end, m.frame_count());
  if (options.frame_begin < 0 || first >= end) {
    throw Error(fmt::format("{}: frames {}:{} select none; the clip has {} (0:{})", input, options.frame_begin,
                            options.frame_end < 0 ? std::string() : std::to_string(options.frame_end), m.frame_count(),
                            m.frame_count()));
  }
  std::vector<std::byte> records = format::frame_buffer(m, input);
  report.frames = end - first;
  if (report.ply) {
    const fs::path folder = output.parent_path().empty() ? fs::path(".") : output.parent_path();
    const std::string stem = output.stem().string();
    if (fs::exists(folder) && !fs::is_directory(folder))
      throw Error(fmt::format("{}: exists and is not a folder (the PLY sequence's)", folder.string()));
    for (const Attribute* a : c.float_attributes) ply_word(a->name, input);  // before anything is written
    fs::create_directories(folder);
    report.first = folder / fmt::format("{}.{:04}.ply", stem, first + 1);
    // Ids: those the clip stores, or, where the cook ordered and matched its particles by the
    // source's ids without storing them, the ids the codec's matching keeps (as the Alembic export
    // writes). A clip matched by position has none: the source had none.
    PlyIds ids;
    std::optional<MatchedIds> matched;
    if (const Attribute* a = m.find("id")) {
      ids.present = true;
      for (std::uint64_t f = first; a->type == AttributeType::Uint64 && ids.fit32 && f < end; ++f) {
        reader.read_frame(f, records);
        split(m, records, m.frames[f].count, c);
        ids.fit32 = std::all_of(c.id.begin(), c.id.end(), [](std::uint64_t v) { return v <= 0xffffffffu; });
      }
    } else if (m.codec.order == FrameOrder::Id) {
      ids.present = true;
      matched.emplace(m);
      std::uint64_t particles = 0;  // the most ids the matching can hand out
      for (std::uint64_t f = first; f < end; ++f) particles += m.frames[f].count;
      ids.fit32 = particles <= 0xffffffffu;
    }
    for (std::uint64_t f = first; f < end; ++f) {
      const std::size_t runs = reader.read_frame(f, records, matched ? matched->runs() : std::span<MatchRun>{});
      const std::uint64_t n = m.frames[f].count;
      split(m, records, n, c);
      ids.values = matched ? matched->next(n, runs) : std::span<const std::uint64_t>(c.id);
      report.bytes_written += write_ply(folder / fmt::format("{}.{:04}.ply", stem, f + 1), m, c, ids, n, input);
      if (progress) progress(f - first + 1, report.frames);
    }
    return report;
  }
  // Alembic: widths are diameters (twice the record's radius); colours become Cd: rgb, or rgba when
  // any particle is not opaque (so that alpha comes back, as the cook reads a fourth Cd component).
  alembic::PointsWriterOptions po;
  po.velocities = m.find("velocity") != nullptr;
  const Attribute* color = m.find("color");
  bool alpha = false;
  for (std::uint64_t f = first; color && !alpha && f < end; ++f) {
    reader.read_frame(f, records);
    for (std::uint64_t i = 0; i < m.frames[f].count && !alpha; ++i)
      alpha = std::to_integer<std::uint8_t>(records[i * m.record_size + color->offset + 3]) != 255;
  }
  const int cd_components = alpha ? 4 : 3;
  if (color) po.float_params.push_back({"Cd", cd_components});
  for (const Attribute* a : c.float_attributes) po.float_params.push_back({a->name, a->components});
  check_output(output, inputs);
  if (is_source_of(m, output)) {
    throw Error(
        fmt::format("{}: is the source {} was cooked from; writing it would destroy the source. Choose "
                    "another output",
                    output.string(), input));
  }
  // The writer writes a temporary beside the output and renames it at close().
  alembic::ArchiveWriter writer(output, "pstream export", fmt::format("{} {}", m.source_file, m.source_object), m.fps,
                                first == 0 ? m.time_of_frame0 : m.frames[first].time, po);
  std::vector<float> widths, cd;
  std::optional<MatchedIds> matched;  // a clip without ids
  if (!m.find("id")) matched.emplace(m);
  for (std::uint64_t f = first; f < end; ++f) {
    const std::size_t runs = reader.read_frame(f, records, matched ? matched->runs() : std::span<MatchRun>{});
    const std::uint64_t n = m.frames[f].count;
    split(m, records, n, c);
    widths.resize(n);
    for (std::uint64_t i = 0; i < n; ++i) widths[i] = 2.0f * c.scale_width[i];
    alembic::PointsSample s;
    s.positions = c.position;
    s.ids = matched ? matched->next(n, runs) : std::span<const std::uint64_t>(c.id);
    s.velocities = c.velocity;
    s.widths = widths;
    if (color) {
      cd.resize(n * cd_components);
      for (std::uint64_t i = 0; i < n; ++i)
        for (int k = 0; k < cd_components; ++k) cd[i * cd_components + k] = float(c.color[i * 4 + k]) / 255.0f;
      s.params.push_back(cd);
    }
    for (const auto& values : c.floats) s.params.push_back(values);
    writer.write_sample(s);
    if (progress) progress(f - first + 1, report.frames);
  }
  writer.close();
  report.first = output;
  report.bytes_written = fs::file_size(output, ec);
  return report;
}

}  // namespace pstream::cook
