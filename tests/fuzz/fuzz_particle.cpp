// libFuzzer target: particle-codec packet bodies. Any body either decodes into exactly the frame's
// records (and a matching whose runs cover both frames) or raises pstream::Error naming the frame;
// nothing is written outside the output (AddressSanitizer watches the exactly-sized buffers).
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "format/particle_common.hpp"
#include "particle_fuzz_clip.hpp"
#include "zstd_packets.hpp"

namespace {

std::uint64_t count_of(std::span<const std::uint8_t> body) {
  std::uint32_t n = 0;
  if (body.size() >= 4) std::memcpy(&n, body.data(), 4);
  return std::min<std::uint64_t>(n, pstream::fuzz::kMaxParticles);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pstream;
  if (size < 5) return 0;
  std::uint32_t first = 0;
  std::memcpy(&first, data + 1, 4);
  const std::span<const std::uint8_t> rest(data + 5, size - 5);
  const std::span<const std::uint8_t> a = rest.first(std::min<std::size_t>(first, rest.size()));
  const std::span<const std::uint8_t> b = rest.subspan(a.size());
  const format::Metadata meta = fuzz::particle_clip(data[0], count_of(a), count_of(b));
  try {
    format::FrameDecoder decoder(meta, "fuzz.pstream");
    // The packets of the two bodies: one zstd stream (version 4 on) or a frame each (version 3, or
    // two keyframes: each starts a frame).
    const std::span<const std::byte> bodies[2] = {std::as_bytes(a), std::as_bytes(b)};
    const auto packets = test::compress_packets(
        bodies, meta.version >= format::particle::kFirstStreamedVersion && !meta.frames[1].keyframe, 1);
    std::vector<std::byte> out0(meta.frames[0].count * meta.record_size);
    decoder.decode(0, packets[0], out0);
    std::vector<std::byte> out1(meta.frames[1].count * meta.record_size);
    // The matching too, as the stream asks for it: any runs it gives cover both frames exactly.
    std::vector<format::MatchRun> runs(2 * meta.max_count + 1);
    const std::size_t n = decoder.decode(1, packets[1], out1, runs);
    if (n != format::kNoMatching) {
      std::uint64_t from = 0, to = 0;
      for (std::size_t i = 0; i < n; ++i) {
        from += std::uint64_t{runs[i].keep} + runs[i].drop;
        to += std::uint64_t{runs[i].keep} + runs[i].insert;
      }
      if (n > runs.size() || from != meta.frames[0].count || to != meta.frames[1].count) __builtin_trap();
    }
  } catch (const Error&) {
    // A clear error is the expected outcome for a malformed body.
  }
  return 0;
}
