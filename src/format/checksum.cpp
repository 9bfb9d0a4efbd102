// Checksums of the header, the tables and every chunk (XXH3, 64 bits). The one file that the
// fuzzing build of the format compiles differently (PSTREAM_FUZZING: every checksum matches, so
// that mutated files reach the parsers and decoders behind the checksums, and the particle decoder
// compacts the survivors of small frames too, so that the fuzz targets reach that loop); the rest
// of the format is compiled once and shared by both builds.
#include <xxhash.h>

#include "format/particle_common.hpp"
#include "particlestream/format.hpp"

namespace pstream::format {

std::uint64_t checksum(std::span<const std::byte> bytes) { return XXH3_64bits(bytes.data(), bytes.size()); }

bool checksum_matches(std::span<const std::byte> bytes, std::uint64_t stored) {
#ifdef PSTREAM_FUZZING
  (void)bytes;
  (void)stored;
  return true;
#else
  return checksum(bytes) == stored;
#endif
}

namespace particle {
bool compact_every_frame() {
#ifdef PSTREAM_FUZZING
  return true;
#else
  return false;
#endif
}
}  // namespace particle

}  // namespace pstream::format
