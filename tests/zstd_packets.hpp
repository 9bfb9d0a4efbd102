// Particle-codec packets made from bodies and back, for tests and fuzzing that change a body and
// need its packets again (docs/format.md, "The particle codec": from version 4 the packets of a
// keyframe group are one zstd stream, each ending at a block boundary; before, a zstd frame each).
#pragma once

#include <zstd.h>

#include <cstddef>
#include <memory>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "format/particle_common.hpp"

namespace pstream::test {

// The bodies as packets at zstd `level`: one stream with each body flushed at a block boundary
// (`streamed`: version 4 on), or a zstd frame each (versions 1 to 3).
inline std::vector<std::vector<std::byte>> compress_packets(std::span<const std::span<const std::byte>> bodies,
                                                            bool streamed, int level) {
  const std::unique_ptr<ZSTD_CCtx, decltype(&ZSTD_freeCCtx)> c(ZSTD_createCCtx(), &ZSTD_freeCCtx);
  ZSTD_CCtx_setParameter(c.get(), ZSTD_c_compressionLevel, level);
  ZSTD_CCtx_setParameter(c.get(), ZSTD_c_windowLog, format::particle::kStreamWindowLog);
  std::vector<std::vector<std::byte>> packets;
  for (const std::span<const std::byte> body : bodies) {
    std::vector<std::byte> z(ZSTD_compressBound(body.size()) + 64);
    ZSTD_inBuffer in{body.data(), body.size(), 0};
    ZSTD_outBuffer out{z.data(), z.size(), 0};
    for (;;) {  // the bound leaves room for everything: one call unless zstd says otherwise
      const std::size_t left = ZSTD_compressStream2(c.get(), &out, &in, streamed ? ZSTD_e_flush : ZSTD_e_end);
      if (ZSTD_isError(left)) throw std::runtime_error(std::string("zstd: ") + ZSTD_getErrorName(left));
      if (left == 0) break;
    }
    z.resize(out.pos);
    packets.push_back(std::move(z));
  }
  return packets;
}

// The packets of one zstd stream (or frames one after another) decoded back into their bodies,
// each at most `bound` bytes. Throws std::runtime_error when they do not decode.
inline std::vector<std::vector<std::byte>> decompress_packets(std::span<const std::span<const std::byte>> packets,
                                                              std::size_t bound) {
  const std::unique_ptr<ZSTD_DCtx, decltype(&ZSTD_freeDCtx)> d(ZSTD_createDCtx(), &ZSTD_freeDCtx);
  std::vector<std::vector<std::byte>> bodies;
  for (const std::span<const std::byte> packet : packets) {
    std::vector<std::byte> body(bound);
    ZSTD_inBuffer in{packet.data(), packet.size(), 0};
    ZSTD_outBuffer out{body.data(), body.size(), 0};
    while (in.pos < in.size) {
      const std::size_t r = ZSTD_decompressStream(d.get(), &out, &in);
      if (ZSTD_isError(r)) throw std::runtime_error(std::string("zstd: ") + ZSTD_getErrorName(r));
      if (out.pos == out.size && in.pos < in.size) throw std::runtime_error("zstd: a body larger than the bound");
    }
    body.resize(out.pos);
    bodies.push_back(std::move(body));
  }
  return bodies;
}

}  // namespace pstream::test
