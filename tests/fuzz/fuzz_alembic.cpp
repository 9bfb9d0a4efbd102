// libFuzzer target: any bytes given to the Alembic reader either read or raise pstream::Error.
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "particlestream/alembic.hpp"
#include "particlestream/alembic_describe.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pstream::alembic;
  try {
    const Archive archive = Archive::from_memory(std::as_bytes(std::span(data, size)), "fuzz.abc");
    // Everything the describer reads, limited in samples so a claimed billion repeats stays quick.
    (void)describe_json(archive, {.indent = -1, .max_samples = 4});
    for (const Object& o : archive.objects()) {
      if (!Points::matches(o)) continue;
      const Points points(o);
      for (std::uint32_t s = 0; s < std::min(points.num_samples(), 4u); ++s) {
        std::vector<float> buffer(static_cast<std::size_t>(points.count(s)) * 3);
        points.read_positions(s, buffer);
        points.read_velocities(s, buffer);
        (void)world_matrix(o, points.sample_time(s));
      }
    }
  } catch (const pstream::Error&) {
    // A clear error is the expected outcome for malformed input.
  }
  return 0;
}
