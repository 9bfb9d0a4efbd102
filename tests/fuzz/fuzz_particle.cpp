// libFuzzer target: particle-codec packet bodies. Any body either decodes into exactly the frame's
// records or raises pstream::Error naming the frame; nothing is written outside the output
// (AddressSanitizer watches the exactly-sized buffers).
#include <zstd.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "format/particle_common.hpp"
#include "particle_fuzz_clip.hpp"

namespace {

// The packets of the two bodies: one zstd frame each (version 3), or (version 4) one zstd frame
// the second packet continues, as the encoder writes small bodies.
std::array<std::vector<std::byte>, 2> compress(std::uint32_t version, std::span<const std::uint8_t> a,
                                               std::span<const std::uint8_t> b) {
  std::array<std::vector<std::byte>, 2> z;
  ZSTD_CCtx* c = ZSTD_createCCtx();
  ZSTD_CCtx_setParameter(c, ZSTD_c_compressionLevel, 1);
  ZSTD_CCtx_setParameter(c, ZSTD_c_windowLog, pstream::format::particle::kStreamWindowLog);
  for (int f = 0; f < 2; ++f) {
    const std::span<const std::uint8_t> body = f == 0 ? a : b;
    z[f].resize(ZSTD_compressBound(body.size()) + 64);
    ZSTD_inBuffer in{body.data(), body.size(), 0};
    ZSTD_outBuffer out{z[f].data(), z[f].size(), 0};
    while (ZSTD_compressStream2(
               c, &out, &in, version >= pstream::format::particle::kFirstStreamedVersion ? ZSTD_e_flush : ZSTD_e_end) !=
           0) {
    }
    z[f].resize(out.pos);
  }
  ZSTD_freeCCtx(c);
  return z;
}

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
    const auto packets = compress(meta.version, a, b);
    std::vector<std::byte> out0(meta.frames[0].count * meta.record_size);
    decoder.decode(0, packets[0], out0);
    std::vector<std::byte> out1(meta.frames[1].count * meta.record_size);
    decoder.decode(1, packets[1], out1);
  } catch (const Error&) {
    // A clear error is the expected outcome for a malformed body.
  }
  return 0;
}
