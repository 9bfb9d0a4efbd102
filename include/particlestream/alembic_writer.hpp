// Writing Alembic (Ogawa) point caches: a Points object with P, ids, velocities, widths and
// float arbGeomParams (Cd, age, ...) under an optional constant Xform, uniform time sampling,
// repeated samples stored once. The layout facts are the reader's (src/alembic/layout.hpp).
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "particlestream/error.hpp"

namespace pstream::alembic {

struct PointsWriterOptions {
  std::string name = "particles";
  std::string parent_xform;                  // non-empty: a constant Xform object of this name above it
  std::array<double, 3> translate{0, 0, 0};  // the Xform's translation
  bool velocities = true;
  bool widths = true;                                     // per-particle widths (a diameter), vertex scope
  std::vector<std::pair<std::string, int>> float_params;  // arbGeomParams: name and extent (Cd: 3, rgb)
};

// One sample of the points object. Spans hold count, 3 x count, ... values as the options ask.
struct PointsSample {
  std::span<const float> positions;  // 3 per particle
  std::span<const std::uint64_t> ids;
  std::span<const float> velocities;  // 3 per particle
  std::span<const float> widths;
  std::vector<std::span<const float>> params;  // in PointsWriterOptions::float_params order
};

class ArchiveWriter {
 public:
  // Writes to a temporary beside `path`, renamed over it by close(): until then `path` is untouched,
  // and an archive that is never closed leaves nothing behind.
  ArchiveWriter(const std::filesystem::path& path, const std::string& application, const std::string& description,
                double fps, double start_time, const PointsWriterOptions& points);
  ~ArchiveWriter();
  ArchiveWriter(const ArchiveWriter&) = delete;
  ArchiveWriter& operator=(const ArchiveWriter&) = delete;

  void write_sample(const PointsSample& sample);  // the next time sample, at start + i / fps
  void close();                                   // writes the hierarchy and freezes the file
  std::uint64_t bytes_written() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace pstream::alembic
