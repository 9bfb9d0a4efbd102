// Reading PLY files (ascii and binary little-endian), the vertex element only: the parser behind
// PLY sequences (ply_source.cpp) and the PLY fuzz target. Every declared size is checked against
// the bytes before anything is allocated for it.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace pstream::cook {

enum class PlyType { Int8, Uint8, Int16, Uint16, Int32, Uint32, Float32, Float64 };

struct PlyProperty {
  std::string name;
  PlyType type;
  std::size_t offset = 0;  // within a binary vertex
};

struct PlyHeader {
  bool binary = false;
  std::uint64_t vertex_count = 0;
  std::vector<PlyProperty> properties;
  std::size_t vertex_size = 0;
  std::size_t data_offset = 0;
  bool has_elements_before_vertex = false;
  bool has_elements_after_vertex = false;  // faces and such: bytes after the vertices are theirs
};

const char* ply_format_name(bool binary);  // "ascii" or "binary_little_endian"
const char* ply_type_name(PlyType type);   // "uint8", "float32", ...

// Parses the header at the start of `text`. Throws pstream::Error naming `file`.
PlyHeader parse_ply_header(std::string_view text, const std::string& file);

// Parses a whole PLY file's `bytes`: its header into `header`, and every vertex's property values
// into `values` (vertex_count x properties, row-major, as doubles). Refuses (pstream::Error
// naming `file` and where) more than `max_vertices` vertices, a count the bytes cannot hold, a
// count smaller than the data, a value that is not a number.
void read_ply_vertices(std::span<const std::byte> bytes, const std::string& file, std::uint64_t max_vertices,
                       PlyHeader& header, std::vector<double>& values);

}  // namespace pstream::cook
