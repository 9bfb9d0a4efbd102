// Hostile inputs shared by the hardening tests (tests/hardening_test.cpp) and the adversarial
// tree's generator (tests/adversarial/make_inputs.cpp): PLY headers that claim what the caller
// says, and an Alembic cache whose time sampling starts at any double (NaN, infinity, 1e300).
// No GoogleTest here: the generator is a plain program.
#pragma once

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "particlestream/alembic_writer.hpp"

namespace pstream::test {

inline std::string read_file(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

inline void write_file(const std::filesystem::path& p, std::string_view bytes) {
  std::ofstream out(p, std::ios::binary);
  out.write(bytes.data(), std::streamsize(bytes.size()));
}

// A PLY header declaring `count` (written as given, so it can be anything) vertices of the first
// `properties` of x, y, z, pscale as floats.
inline std::string ply_header(const std::string& format, const std::string& count, int properties = 3) {
  std::string h = "ply\nformat " + format + " 1.0\nelement vertex " + count + "\n";
  const char* names[] = {"x", "y", "z", "pscale"};
  for (int i = 0; i < properties; ++i) h += std::string("property float ") + names[i] + "\n";
  return h + "end_header\n";
}

// Three samples of two points at 24 fps whose time sampling starts at `start`: written with a
// recognisable start time by the library's writer, which is then found in the bytes and replaced
// (the writer itself refuses a start that is not finite).
inline void write_archive_with_start(const std::filesystem::path& path, double start) {
  constexpr double kMarker = 0.123456789012345;
  alembic::PointsWriterOptions o;
  o.velocities = false;
  {
    alembic::ArchiveWriter w(path, "hostile inputs", "time sampling start", 24.0, kMarker, o);
    const std::vector<float> P = {0, 0, 0, 1, 1, 1};
    const std::vector<std::uint64_t> ids = {1, 2};
    const std::vector<float> widths = {0.1f, 0.1f};
    for (int f = 0; f < 3; ++f) w.write_sample({P, ids, {}, widths, {}});
    w.close();
  }
  std::string bytes = read_file(path);
  const std::string needle(reinterpret_cast<const char*>(&kMarker), 8);
  const auto at = bytes.find(needle);
  if (at == std::string::npos) throw std::runtime_error(path.string() + ": the start time marker is not in the file");
  std::memcpy(bytes.data() + at, &start, 8);
  write_file(path, bytes);
}

}  // namespace pstream::test
