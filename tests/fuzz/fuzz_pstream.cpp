// libFuzzer target: any bytes given to the .pstream reader either read or raise pstream::Error.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "particlestream/codec.hpp"
#include "particlestream/format.hpp"

namespace {

std::uint64_t hash(std::span<const std::byte> bytes) {  // FNV-1a
  std::uint64_t h = 14695981039346656037ull;
  for (const std::byte b : bytes) h = (h ^ std::to_integer<std::uint64_t>(b)) * 1099511628211ull;
  return h;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pstream::format;
  try {
    const Reader reader = Reader::from_memory(std::as_bytes(std::span(data, size)), "fuzz.pstream");
    const Metadata& m = reader.metadata();
    // Never more than the file's own stream needs, however large a chunk size it claims.
    std::vector<std::byte> scratch(std::min(m.chunk_size, m.stream_size()));
    for (std::uint64_t c = 0; c < m.chunk_count(); ++c) reader.read_chunk(c, scratch);
    std::vector<std::byte> frame;
    // With the matching, as export asks for it: any runs cover this frame and the one before.
    // (frame_buffer() first: it refuses a max_count the file's bytes do not justify.)
    (void)frame_buffer(m, "fuzz.pstream");
    std::vector<MatchRun> runs(2 * m.max_count + 1);
    std::vector<std::uint64_t> hashes(m.frame_count());
    for (std::uint64_t f = 0; f < m.frame_count(); ++f) {
      frame.resize(m.frames[f].count * m.record_size);
      const std::size_t n = reader.read_frame(f, frame, runs);
      hashes[f] = hash(frame);
      if (n == kNoMatching) continue;
      std::uint64_t from = 0, to = 0;
      for (std::size_t i = 0; i < n; ++i) {
        from += std::uint64_t{runs[i].keep} + runs[i].drop;
        to += std::uint64_t{runs[i].keep} + runs[i].insert;
      }
      if (f == 0 || n > runs.size() || from != m.frames[f - 1].count || to != m.frames[f].count) __builtin_trap();
    }
    // Every frame read again, last to first, as reverse play and a Reader going back decode them
    // (the Reader's decoder is made again with saved states, their zstd stream restored): each
    // frame must come out as it did forwards, and never fail.
    for (std::uint64_t f = m.frame_count(); f-- > 0;) {
      frame.resize(m.frames[f].count * m.record_size);
      try {
        reader.read_frame(f, frame);
      } catch (const pstream::Error&) {
        __builtin_trap();  // it decoded forwards
      }
      if (hash(frame) != hashes[f]) __builtin_trap();
    }
  } catch (const pstream::Error&) {
    // A clear error is the expected outcome for malformed input.
  }
  return 0;
}
