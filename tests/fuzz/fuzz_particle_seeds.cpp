// Writes seed inputs for fuzz_particle: real bodies of a keyframe and a predicted frame, for each
// layout and order the target's selector picks, with births, deaths and moving particles.
#include <cmath>
#include <fstream>
#include <string>

#include "format/particle_common.hpp"
#include "particle_fuzz_clip.hpp"
#include "zstd_packets.hpp"

int main(int argc, char** argv) {
  using namespace pstream;
  if (argc != 2) return 2;
  for (std::uint8_t selector = 0; selector < 32; ++selector) {
    for (std::uint64_t n0 : {1u, 20u, 64u}) {
      const std::uint64_t n1 = n0 > 10 ? n0 - 7 : n0 + 3;  // deaths or births
      format::Metadata meta = fuzz::particle_clip(selector, n0, n1);
      meta.codec.nibbles = meta.version >= format::particle::kFirstNibbleVersion;  // older bodies: byte planes
      meta.codec.keyframe_links = meta.version >= format::particle::kFirstKeyframeLinksVersion;
      std::vector<std::vector<std::byte>> records(2);
      std::vector<std::vector<std::uint64_t>> ids(2);
      for (int f = 0; f < 2; ++f) {
        const std::uint64_t n = f == 0 ? n0 : n1;
        records[f].resize(n * meta.record_size);
        for (std::uint64_t i = 0; i < n; ++i) {
          const std::uint64_t id = f == 0 || i % 3 != 0 ? i * 3 : i * 3 + 2;  // some ids persist, some are new
          // The second frame moves each particle its own few grid steps (0.01), some of them far:
          // residuals of one and two bytes, and nibbles with escapes (version 5).
          const float jitter = f == 0 ? 0.0f : 0.01f * float((i * 7) % 13) + (i % 11 == 0 ? 3.0f : 0.0f);
          const float jump = f == 1 && i % 5 == 0 ? 0.2f : 0.0f;
          const float r[4] = {0.1f * float(i % 7) + 0.02f * float(f) + jitter, 0.05f * float(i / 7) + jump, 0.3f,
                              0.02f};
          std::memcpy(records[f].data() + i * meta.record_size, r, 16);
          if (meta.record_size > 16) {
            const std::uint32_t color = 0xff000000u | std::uint32_t(i * 40);
            std::memcpy(records[f].data() + i * meta.record_size + 16, &color, 4);
            std::memcpy(records[f].data() + i * meta.record_size + 20, &id, 8);
          }
          if (meta.record_size > 28) {  // a derived velocity: the source's seeds new particles
            const float v[3] = {0.5f * float(i % 3), -1.0f, 0.25f};
            std::memcpy(records[f].data() + i * meta.record_size + 28, v, 12);
          }
          ids[f].push_back(id);
        }
      }
      const bool by_id = meta.codec.order == format::FrameOrder::Id;
      const format::SourceFrame frames[2] = {{records[0], by_id ? std::span(ids[0]) : std::span<std::uint64_t>{}, n0},
                                             {records[1], by_id ? std::span(ids[1]) : std::span<std::uint64_t>{}, n1}};
      // Two keyframes (selector bit 4): the second a group of its own after the first, which links it.
      const bool two_keyframes = meta.frames[1].keyframe;
      const auto encoded = two_keyframes ? format::encode_group(meta.codec, std::span(frames, 1), {}, 0)
                                         : format::encode_group(meta.codec, frames, {}, 0);
      const auto second = two_keyframes
                              ? format::encode_group(meta.codec, std::span(frames + 1, 1), std::span(frames, 1), 1)
                              : std::vector<format::EncodedFrame>{};
      const std::span<const std::byte> packets[2] = {encoded[0].packet,
                                                     two_keyframes ? second[0].packet : encoded[1].packet};
      // The packets are one zstd stream, or with two keyframes each the start of a frame of its own.
      const auto bodies = two_keyframes ? std::vector{test::decompress_packets(std::span(packets, 1), 1 << 16)[0],
                                                      test::decompress_packets(std::span(packets + 1, 1), 1 << 16)[0]}
                                        : test::decompress_packets(packets, 1 << 16);
      std::ofstream out(std::string(argv[1]) + "/seed-" + std::to_string(selector) + "-" + std::to_string(n0),
                        std::ios::binary);
      const auto size = static_cast<std::uint32_t>(bodies[0].size());
      out.put(static_cast<char>(selector));
      out.write(reinterpret_cast<const char*>(&size), 4);
      out.write(reinterpret_cast<const char*>(bodies[0].data()), std::streamsize(bodies[0].size()));
      out.write(reinterpret_cast<const char*>(bodies[1].data()), std::streamsize(bodies[1].size()));
    }
  }
  return 0;
}
