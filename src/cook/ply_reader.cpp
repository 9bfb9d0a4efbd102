#include "cook/ply_reader.hpp"

#include <algorithm>
#include <charconv>
#include <cstring>
#include <limits>
#include <map>
#include <sstream>

#include <fmt/format.h>

#include "particlestream/error.hpp"

namespace pstream::cook {
namespace {

std::size_t type_size(PlyType t) {
  static constexpr std::size_t sizes[] = {1, 1, 2, 2, 4, 4, 4, 8};
  return sizes[static_cast<int>(t)];
}

bool parse_type(const std::string& s, PlyType& t) {
  static const std::map<std::string, PlyType> types = {
      {"char", PlyType::Int8},      {"int8", PlyType::Int8},       {"uchar", PlyType::Uint8},
      {"uint8", PlyType::Uint8},    {"short", PlyType::Int16},     {"int16", PlyType::Int16},
      {"ushort", PlyType::Uint16},  {"uint16", PlyType::Uint16},   {"int", PlyType::Int32},
      {"int32", PlyType::Int32},    {"uint", PlyType::Uint32},     {"uint32", PlyType::Uint32},
      {"float", PlyType::Float32},  {"float32", PlyType::Float32}, {"double", PlyType::Float64},
      {"float64", PlyType::Float64}};
  const auto it = types.find(s);
  if (it == types.end()) return false;
  t = it->second;
  return true;
}

}  // namespace

const char* ply_type_name(PlyType type) {
  static constexpr const char* names[] = {"int8", "uint8", "int16", "uint16", "int32", "uint32", "float32", "float64"};
  return names[static_cast<int>(type)];
}

PlyHeader parse_ply_header(std::string_view text, const std::string& file) {
  PlyHeader h;
  const auto end = text.find("end_header");
  if (text.substr(0, 3) != "ply" || end == std::string_view::npos) {
    throw Error(fmt::format("{}: not a PLY file (expected 'ply' ... 'end_header')", file));
  }
  std::istringstream lines{std::string(text.substr(0, end))};
  std::string line, element;
  bool vertex_seen = false;
  while (std::getline(lines, line)) {
    std::istringstream words(line);
    std::string key;
    words >> key;
    if (key == "format") {
      std::string f;
      words >> f;
      if (f == "binary_little_endian") {
        h.binary = true;
      } else if (f != "ascii") {
        throw Error(fmt::format("{}: PLY format '{}' is not supported (ascii or binary_little_endian)", file, f));
      }
    } else if (key == "element") {
      std::string count;
      words >> element >> count;
      if (element == "vertex") {
        const auto [end_of, ec] = std::from_chars(count.data(), count.data() + count.size(), h.vertex_count);
        if (ec != std::errc() || end_of != count.data() + count.size()) {
          throw Error(fmt::format("{}: header line '{}': expected a vertex count from 0 to {}", file, line,
                                  std::numeric_limits<std::uint64_t>::max()));
        }
        vertex_seen = true;
      } else if (!vertex_seen) {
        h.has_elements_before_vertex = true;
      } else {
        h.has_elements_after_vertex = true;
      }
    } else if (key == "property" && element == "vertex") {
      std::string type, name;
      words >> type >> name;
      PlyProperty p{name, PlyType::Float32, h.vertex_size};
      if (type == "list" || !parse_type(type, p.type)) {
        throw Error(fmt::format("{}: vertex property '{}' has unsupported type '{}'", file, name, type));
      }
      h.vertex_size += type_size(p.type);
      h.properties.push_back(p);
    }
  }
  if (!vertex_seen) throw Error(fmt::format("{}: the PLY file has no vertex element", file));
  if (h.has_elements_before_vertex) throw Error(fmt::format("{}: elements before 'vertex' are not supported", file));
  std::size_t data = end + std::strlen("end_header");
  if (data < text.size() && text[data] == '\r') ++data;
  if (data < text.size() && text[data] == '\n') ++data;
  h.data_offset = data;
  return h;
}

static double load_binary(const std::byte* p, PlyType t) {
  switch (t) {
    case PlyType::Int8: {
      std::int8_t v;
      std::memcpy(&v, p, 1);
      return v;
    }
    case PlyType::Uint8: {
      std::uint8_t v;
      std::memcpy(&v, p, 1);
      return v;
    }
    case PlyType::Int16: {
      std::int16_t v;
      std::memcpy(&v, p, 2);
      return v;
    }
    case PlyType::Uint16: {
      std::uint16_t v;
      std::memcpy(&v, p, 2);
      return v;
    }
    case PlyType::Int32: {
      std::int32_t v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case PlyType::Uint32: {
      std::uint32_t v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case PlyType::Float32: {
      float v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case PlyType::Float64: {
      double v;
      std::memcpy(&v, p, 8);
      return v;
    }
  }
  return 0;
}

const char* ply_format_name(bool binary) { return binary ? "binary_little_endian" : "ascii"; }

void read_ply_vertices(std::span<const std::byte> bytes, const std::string& file, std::uint64_t max_vertices,
                       PlyHeader& header, std::vector<double>& values) {
  const auto text = std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size());
  header = parse_ply_header(text, file);
  const PlyHeader& h = header;
  const std::uint64_t n = h.vertex_count;
  if (n > max_vertices) {
    throw OptionError("max_particles",
                      fmt::format("{}: declares {} vertices, more than `max_particles`, {}", file, n, max_vertices));
  }
  // The declared count must fit in the file before anything is allocated for it: a binary
  // vertex takes vertex_size bytes, an ascii value at least one digit and a separator.
  const std::uint64_t data_bytes = bytes.size() - std::min(h.data_offset, bytes.size());
  const std::uint64_t props = h.properties.size();
  if (props == 0 && n > 0) {  // (found by fuzz_ply: a count of values per vertex of zero)
    throw Error(fmt::format("{}: the header declares {} vertices but no vertex property", file, n));
  }
  const std::uint64_t per_vertex = std::max<std::uint64_t>(h.binary ? h.vertex_size : 2 * props, 1);
  if (n > data_bytes / per_vertex) {
    throw Error(
        fmt::format("{}: the header declares {} vertices of {} bytes{}, but the file has {} bytes of data "
                    "(truncated, or a wrong count)",
                    file, n, per_vertex, h.binary ? "" : " or more", data_bytes));
  }
  values.resize(n * props);
  if (h.binary) {
    const std::uint64_t used = n * h.vertex_size;
    if (used != data_bytes && !h.has_elements_after_vertex) {
      throw Error(
          fmt::format("{}: the header declares {} vertices ({} bytes), but {} bytes of data follow it; "
                      "the vertex count is wrong",
                      file, n, used, data_bytes));
    }
    const std::byte* p = bytes.data() + h.data_offset;
    for (std::uint64_t i = 0; i < n; ++i, p += h.vertex_size) {
      for (std::size_t k = 0; k < h.properties.size(); ++k) {
        values[i * h.properties.size() + k] = load_binary(p + h.properties[k].offset, h.properties[k].type);
      }
    }
  } else {
    const char* c = text.data() + h.data_offset;
    const char* end = text.data() + text.size();
    for (std::uint64_t i = 0; i < values.size(); ++i) {
      while (c < end && std::isspace(static_cast<unsigned char>(*c))) ++c;
      const auto r = std::from_chars(c, end, values[i]);
      if (r.ec != std::errc()) {
        throw Error(fmt::format("{}: vertex {}: expected {} numbers per line", file, i / h.properties.size(),
                                h.properties.size()));
      }
      c = r.ptr;
    }
    while (c < end && std::isspace(static_cast<unsigned char>(*c))) ++c;
    if (c != end && !h.has_elements_after_vertex) {
      throw Error(
          fmt::format("{}: offset {}: more numbers follow the vertices the header declares ({}); the "
                      "vertex count is wrong",
                      file, c - text.data(), n));
    }
  }
}

}  // namespace pstream::cook
