// The native decoder's answer for the web player's test: a clip's frame decoded by the format's
// Reader, written raw (count × record_size bytes).
//   reference_frame CLIP FRAME OUT
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <vector>

#include "particlestream/format.hpp"

int main(int argc, char** argv) {
  if (argc != 4) {
    std::fprintf(stderr, "usage: reference_frame CLIP FRAME OUT\n");
    return 2;
  }
  try {
    const auto reader = pstream::format::Reader::open(argv[1]);
    const auto& meta = reader.metadata();
    const std::uint64_t frame = std::strtoull(argv[2], nullptr, 10);
    std::vector<std::byte> records = pstream::format::frame_buffer(meta, reader.name());
    reader.read_frame(frame, records);
    const std::size_t bytes = meta.frames.at(frame).count * meta.record_size;
    std::FILE* out = std::fopen(argv[3], "wb");
    if (out == nullptr || std::fwrite(records.data(), 1, bytes, out) != bytes || std::fclose(out) != 0) {
      std::fprintf(stderr, "reference_frame: cannot write %s\n", argv[3]);
      return 1;
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "reference_frame: %s\n", e.what());
    return 1;
  }
  return 0;
}
