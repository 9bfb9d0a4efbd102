// Particles from a numbered PLY sequence (frame.0001.ply, frame.0002.ply, ...), ascii or
// binary little-endian, as Houdini and Blender users export when they have no Alembic.
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <memory>
#include <sstream>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <xxhash.h>

#include "base/mapped_file.hpp"
#include "cook/ply_reader.hpp"
#include "cook/source.hpp"
#include "particlestream/io.hpp"

namespace pstream::cook {
namespace {

struct SequenceFile {
  std::int64_t number;
  std::filesystem::path path;
};

// The numbered files of the sequence `example` belongs to, sorted, with no gaps.
std::vector<SequenceFile> find_sequence(const std::filesystem::path& example) {
  if (io::is_url(example.string())) {
    throw Error(
        fmt::format("{}: a PLY sequence is read from local files (its frames are found by listing "
                    "its folder); copy it here first",
                    example.string()));
  }
  const std::string name = example.filename().string();
  const auto dot = name.rfind('.');
  std::size_t digits_end = dot == std::string::npos ? name.size() : dot;
  std::size_t digits_begin = digits_end;
  while (digits_begin > 0 && std::isdigit(static_cast<unsigned char>(name[digits_begin - 1]))) --digits_begin;
  const std::string prefix = name.substr(0, digits_begin), suffix = name.substr(digits_end);
  const auto dir = example.has_parent_path() ? example.parent_path() : std::filesystem::path(".");
  std::vector<SequenceFile> files;
  if (digits_begin == digits_end) {
    files.push_back({0, example});
    return files;
  }
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    const std::string n = entry.path().filename().string();
    if (n.size() <= prefix.size() + suffix.size() || n.compare(0, prefix.size(), prefix) != 0 ||
        n.compare(n.size() - suffix.size(), suffix.size(), suffix) != 0) {
      continue;
    }
    const std::string mid = n.substr(prefix.size(), n.size() - prefix.size() - suffix.size());
    if (!std::all_of(mid.begin(), mid.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)); }))
      continue;
    std::int64_t number = 0;
    const auto [end_of, ec] = std::from_chars(mid.data(), mid.data() + mid.size(), number);
    if (ec != std::errc() || end_of != mid.data() + mid.size()) {
      throw Error(fmt::format("{}: frame number {} is too large (at most {})", entry.path().string(), mid,
                              std::numeric_limits<std::int64_t>::max()));
    }
    files.push_back({number, entry.path()});
  }
  std::sort(files.begin(), files.end(), [](const auto& a, const auto& b) { return a.number < b.number; });
  for (std::size_t i = 1; i < files.size(); ++i) {
    if (files[i].number == files[i - 1].number) {
      throw Error(
          fmt::format("{} and {} have the same frame number", files[i - 1].path.string(), files[i].path.string()));
    }
    if (files[i].number != files[i - 1].number + 1) {
      throw Error(fmt::format("PLY sequence {}{}{}: frame {} is missing (between {} and {})", prefix,
                              std::string(digits_end - digits_begin, '#'), suffix, files[i - 1].number + 1,
                              files[i - 1].path.filename().string(), files[i].path.filename().string()));
    }
  }
  return files;
}

class PlySource final : public Source {
 public:
  explicit PlySource(const Options& options)
      : files_(find_sequence(options.input)), max_particles_(options.max_particles) {
    fps_ = options.fps > 0 ? options.fps : 24.0;
    const MappedFile first = MappedFile::open(files_.front().path);
    const auto text = std::string_view(reinterpret_cast<const char*>(first.bytes().data()), first.bytes().size());
    header_ = parse_ply_header(text, files_.front().path.string());
    for (const auto& p : header_.properties) names_.push_back(p.name);
    for (const char* axis : {"x", "y", "z"}) {
      if (find(axis) < 0) throw Error(fmt::format("{}: no '{}' vertex property", files_.front().path.string(), axis));
    }
    for (const auto& f : files_) bytes_ += std::filesystem::file_size(f.path);
  }

  std::string name() const override { return files_.front().path.string(); }
  std::string object() const override { return "vertex"; }
  double default_fps() const override { return fps_; }
  double start_time() const override { return static_cast<double>(files_.front().number) / fps_; }
  double end_time() const override { return static_cast<double>(files_.back().number) / fps_; }
  std::uint64_t input_bytes() const override { return bytes_; }
  bool has_widths() const override { return !default_scale().first.empty(); }
  bool has_color() const override { return (find("red") >= 0 && find("green") >= 0 && find("blue") >= 0); }
  bool has_velocity() const override { return find("vx") >= 0 && find("vy") >= 0 && find("vz") >= 0; }
  bool has_ids() const override { return find("id") >= 0; }
  std::uint32_t float_components(const std::string& name) const override { return find(name) >= 0 ? 1 : 0; }
  std::string why_no_ids() const override { return "the PLY files have no 'id' vertex property"; }
  bool can_interpolate() const override { return false; }
  std::string why_no_interpolation() const override {
    return "a PLY sequence is cooked file by file, each frame from the nearest file; cook it without `interpolate`";
  }
  std::vector<std::filesystem::path> files() const override {
    std::vector<std::filesystem::path> out;
    for (const auto& f : files_) out.push_back(f.path);
    return out;
  }
  void check_intact() const override {}  // each file is checked right after it is read
  std::uint64_t content_hash() const override {
    const std::unique_ptr<XXH3_state_t, decltype(&XXH3_freeState)> state(XXH3_createState(), &XXH3_freeState);
    if (!state) throw std::bad_alloc();
    XXH3_64bits_reset(state.get());
    for (const auto& f : files_) {
      const MappedFile mapping = MappedFile::open(f.path);
      XXH3_64bits_update(state.get(), mapping.bytes().data(), mapping.bytes().size());
      mapping.check_intact();
    }
    return XXH3_64bits_digest(state.get());
  }

  void read(double time, const Request& request, ParticleFrame& out) override {
    const double rel = std::round(time * fps_) - static_cast<double>(files_.front().number);
    const auto index = static_cast<std::size_t>(std::clamp(rel, 0.0, static_cast<double>(files_.size() - 1)));
    const std::string file = files_[index].path.string();
    const MappedFile mapping = MappedFile::open(files_[index].path);
    PlyHeader h;
    read_ply_vertices(mapping.bytes(), file, max_particles_, h, values_);
    mapping.check_intact();
    check_like_the_first(h, file);
    const std::uint64_t n = h.vertex_count;
    const std::vector<double>& values = values_;
    const std::size_t stride = h.properties.size();
    const auto column = [&](int k, std::uint64_t i) { return values[i * stride + static_cast<std::size_t>(k)]; };
    const std::uint64_t base = out.count;
    out.count += n;
    ensure_size(out.position, out.count * 3);
    const int x = find("x"), y = find("y"), z = find("z");
    for (std::uint64_t i = 0; i < n; ++i) {
      out.position[(base + i) * 3] = static_cast<float>(column(x, i));
      out.position[(base + i) * 3 + 1] = static_cast<float>(column(y, i));
      out.position[(base + i) * 3 + 2] = static_cast<float>(column(z, i));
    }
    ensure_size(out.scale, out.count);
    std::fill(out.scale.begin() + static_cast<std::ptrdiff_t>(base),
              out.scale.begin() + static_cast<std::ptrdiff_t>(out.count), request.scale_constant);
    if (request.scale_from != ScaleFrom::Constant) {
      int k = -1;
      bool diameter = false;
      if (request.scale_from == ScaleFrom::Attribute) {
        k = find(request.scale_attribute);
      } else {
        const auto [name, is_diameter] = default_scale();
        k = find(name);
        diameter = is_diameter;
      }
      if (k < 0) throw Error(fmt::format("{}: no vertex property to take the scale from", file));
      for (std::uint64_t i = 0; i < n; ++i) {
        const auto s = static_cast<float>(column(k, i));
        out.scale[base + i] = diameter ? scale_from_width(s) : s;
      }
    }
    if (request.color) {
      const int r = find("red"), g = find("green"), b = find("blue"), a = find("alpha");
      const bool bytes = h.properties[static_cast<std::size_t>(r)].type == PlyType::Uint8;
      const auto unorm = [bytes](double v) {
        const double scaled = bytes ? v : v * 255.0;
        return static_cast<std::uint8_t>(std::clamp(std::lround(scaled), 0L, 255L));
      };
      ensure_size(out.color, out.count * 4);
      for (std::uint64_t i = 0; i < n; ++i) {
        std::uint8_t* dst = &out.color[(base + i) * 4];
        dst[0] = unorm(column(r, i));
        dst[1] = unorm(column(g, i));
        dst[2] = unorm(column(b, i));
        dst[3] = a >= 0 ? unorm(column(a, i)) : 255;
      }
    }
    if (request.velocity) {
      const int vx = find("vx"), vy = find("vy"), vz = find("vz");
      ensure_size(out.velocity, out.count * 3);
      for (std::uint64_t i = 0; i < n; ++i) {
        out.velocity[(base + i) * 3] = static_cast<float>(column(vx, i));
        out.velocity[(base + i) * 3 + 1] = static_cast<float>(column(vy, i));
        out.velocity[(base + i) * 3 + 2] = static_cast<float>(column(vz, i));
      }
    }
    if (request.id) {
      const int id = find("id");
      ensure_size(out.id, out.count);
      for (std::uint64_t i = 0; i < n; ++i) {
        const double v = column(id, i);
        // 2^64 is exactly representable: below it (and >= 0, whole) the conversion is defined.
        if (!(v >= 0 && v < 18446744073709551616.0) || v != std::floor(v)) {
          throw Error(fmt::format("{}: vertex {}: id {} is not a whole number from 0 to 2^64-1", file, i, v));
        }
        out.id[base + i] = static_cast<std::uint64_t>(v);
      }
    }
    for (std::size_t e = 0; e < request.floats.size(); ++e) {
      const int k = find(request.floats[e]);
      ensure_size(out.extra[e], out.count);
      for (std::uint64_t i = 0; i < n; ++i) out.extra[e][base + i] = static_cast<float>(column(k, i));
    }
  }

  // Every file of a sequence has the first one's format and vertex properties.
  void check_like_the_first(const PlyHeader& h, const std::string& file) const {
    std::vector<std::string> names;
    for (const auto& p : h.properties) names.push_back(p.name);
    if (h.binary != header_.binary) {
      throw Error(
          fmt::format("{}: is {} PLY, but the sequence's first file {} is {}; every file of a sequence must "
                      "have one format",
                      file, ply_format_name(h.binary), files_.front().path.string(), ply_format_name(header_.binary)));
    }
    if (names != names_) {
      throw Error(fmt::format("{}: vertex properties ({}) differ from the first file's ({})", file,
                              fmt::join(names, " "), fmt::join(names_, " ")));
    }
  }

  const PlyHeader& first_header() const { return header_; }
  const std::vector<SequenceFile>& sequence() const { return files_; }

  // The name of the property the scale comes from by default, and whether it is a diameter.
  std::pair<std::string, bool> default_scale() const {
    for (const char* name : {"pscale", "scale"})
      if (find(name) >= 0) return {name, false};
    return find("width") >= 0 ? std::pair<std::string, bool>{"width", true} : std::pair<std::string, bool>{"", false};
  }

 private:
  int find(std::string_view name) const {
    for (std::size_t i = 0; i < names_.size(); ++i) {
      if (names_[i] == name) return static_cast<int>(i);
    }
    return -1;
  }

  std::vector<SequenceFile> files_;
  std::uint64_t max_particles_ = 0;
  std::vector<double> values_;  // one file's vertex values, kept across frames
  PlyHeader header_;
  std::vector<std::string> names_;
  double fps_ = 24.0;
  std::uint64_t bytes_ = 0;
};

}  // namespace

std::unique_ptr<Source> open_ply_sequence(const Options& options) { return std::make_unique<PlySource>(options); }

PlySequenceInfo describe_ply_sequence(const std::filesystem::path& example) {
  Options options;
  options.input = example;
  const PlySource source(options);
  PlySequenceInfo info;
  const PlyHeader& first = source.first_header();
  info.format = ply_format_name(first.binary);
  for (const PlyProperty& p : first.properties) info.properties.push_back({p.name, ply_type_name(p.type)});
  info.first_number = source.sequence().front().number;
  for (const SequenceFile& f : source.sequence()) {
    const MappedFile mapping = MappedFile::open(f.path);
    const auto text = std::string_view(reinterpret_cast<const char*>(mapping.bytes().data()), mapping.bytes().size());
    const PlyHeader h = parse_ply_header(text, f.path.string());
    source.check_like_the_first(h, f.path.string());
    info.files.push_back(f.path);
    info.counts.push_back(h.vertex_count);
    info.bytes += mapping.bytes().size();
  }
  const auto [scale, diameter] = source.default_scale();
  info.scale_property = scale;
  info.scale_is_diameter = diameter;
  info.has_color = source.has_color();
  info.has_velocity = source.has_velocity();
  info.has_ids = source.has_ids();
  return info;
}

}  // namespace pstream::cook
