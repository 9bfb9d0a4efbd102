// Writes seed inputs for fuzz_particle: real bodies of a keyframe and a predicted frame, for each
// layout and order the target's selector picks, with births, deaths and moving particles.
#include <cmath>
#include <fstream>
#include <string>

#include "format/particle_common.hpp"
#include "particle_fuzz_clip.hpp"
#include "zstd_packets.hpp"

namespace {

// A predicted body whose nibble-packed words (version 5) are rewritten as byte planes, as the
// older versions' bodies are.
std::vector<std::byte> without_nibbles(const std::vector<std::byte>& in, const pstream::format::Metadata& meta) {
  using namespace pstream::format::particle;
  const WordPlan plan(meta.codec);
  const std::size_t coded = plan.coded.size();
  std::uint32_t head[4];  // count, prev_count, op_count, new_count
  std::memcpy(head, in.data(), sizeof head);
  std::size_t at = kBodyHeader + coded * kWordHeader + (plan.id_word >= 0 ? kIdHeader : 0);
  std::uint64_t survivors = 0;
  for (std::uint32_t o = 0; o < head[2]; ++o) {
    Op op;
    std::memcpy(&op, in.data() + at + o * kOpSize, kOpSize);
    survivors += op.keep;
  }
  at += std::size_t(head[2]) * kOpSize;
  std::vector<std::byte> out(in.begin(), in.begin() + std::ptrdiff_t(at));
  const auto copy = [&](std::size_t bytes) {
    out.insert(out.end(), in.begin() + std::ptrdiff_t(at), in.begin() + std::ptrdiff_t(at + bytes));
    at += bytes;
  };
  const auto s = static_cast<std::uint32_t>(survivors);
  for (std::size_t k = 0; k < coded; ++k) {
    const std::size_t header = kBodyHeader + k * kWordHeader;  // in `out`, which grows
    const auto byte = [&](std::size_t i) { return std::to_integer<std::size_t>(out[header + i]); };
    copy(byte(4) * ((s + kBlock - 1) / kBlock));  // bias planes
    if (byte(6) == kNibbles) {
      const auto* packed = reinterpret_cast<const std::uint8_t*>(in.data() + at);
      const auto escapes = static_cast<std::uint32_t>(count_escapes(packed, s));
      // The values (no bias, zigzagged again) as byte planes, as few as hold the largest.
      std::vector<std::uint32_t> values(s), none((s + kBlock - 1) / kBlock, 0);
      SurvivorResiduals residuals(in.data() + at, s, kNibbles, unsigned(byte(1)), in.data() + at + (s + 1) / 2, escapes,
                                  none.data());
      for (std::uint32_t b = 0; b * kBlock < s; ++b) residuals.fill(b, values.data() + std::size_t(b) * kBlock);
      std::uint32_t largest = 0;
      for (std::uint32_t& v : values) largest = std::max(largest, v = zigzag(v));
      const unsigned width = bytes_for(largest);
      at += (s + 1) / 2 + escapes * byte(1);
      write_planes(out, values, width);
      out[header + 1] = std::byte(width);
      out[header + 6] = std::byte{kBytePlanes};
    } else {
      copy(byte(1) * s);
    }
    copy((byte(2) + byte(3) + byte(5)) * head[3]);  // new, motion and prior planes
  }
  copy(in.size() - at);  // the id planes
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace pstream;
  if (argc != 2) return 2;
  for (std::uint8_t selector = 0; selector < 16; ++selector) {
    for (std::uint64_t n0 : {1u, 20u, 64u}) {
      const std::uint64_t n1 = n0 > 10 ? n0 - 7 : n0 + 3;  // deaths or births
      const format::Metadata meta = fuzz::particle_clip(selector, n0, n1);
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
      const auto encoded = format::encode_group(meta.codec, frames, {}, 0);
      const std::span<const std::byte> packets[2] = {encoded[0].packet, encoded[1].packet};
      auto bodies = test::decompress_packets(packets, 1 << 16);  // the packets are one zstd stream
      if (meta.version < format::particle::kFirstNibbleVersion) bodies[1] = without_nibbles(bodies[1], meta);
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
