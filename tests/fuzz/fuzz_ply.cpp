// libFuzzer target: any bytes given to the PLY reader either read or raise pstream::Error, and
// never allocate for more vertices than the bytes can hold.
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "cook/ply_reader.hpp"
#include "particlestream/error.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pstream::cook;
  PlyHeader header;
  std::vector<double> values;
  try {
    // The cook's default limit: the size checks, not the limit, must stop a huge claimed count.
    read_ply_vertices(std::as_bytes(std::span(data, size)), "fuzz.ply", 64ull << 20, header, values);
    if (values.size() != header.vertex_count * header.properties.size()) __builtin_trap();
  } catch (const pstream::Error&) {
    // A clear error is the expected outcome for malformed input.
  }
  return 0;
}
