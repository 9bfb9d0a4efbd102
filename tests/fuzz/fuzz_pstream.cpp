// libFuzzer target: any bytes given to the .pstream reader either read or raise pstream::Error.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "particlestream/format.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pstream::format;
  try {
    const Reader reader = Reader::from_memory(std::as_bytes(std::span(data, size)), "fuzz.pstream");
    const Metadata& m = reader.metadata();
    // Never more than the file's own stream needs, however large a chunk size it claims.
    std::vector<std::byte> scratch(std::min(m.chunk_size, m.stream_size()));
    for (std::uint64_t c = 0; c < m.chunk_count(); ++c) reader.read_chunk(c, scratch);
    std::vector<std::byte> frame;
    for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
      frame.resize(m.frames[f].count * m.record_size);
      reader.read_frame(f, frame);
    }
  } catch (const pstream::Error&) {
    // A clear error is the expected outcome for malformed input.
  }
  return 0;
}
