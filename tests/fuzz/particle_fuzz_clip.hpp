// The small clip the particle-codec fuzz target decodes against, shared with its seed generator.
// A fuzz input is: [selector][u32 size of the keyframe body][keyframe body][predicted frame body],
// bodies uncompressed (the target compresses them, so mutations land in the body, not in zstd's
// framing). The selector picks the layout (bit 0), the frame order (bit 1), a relative scale and,
// with bit 0, a derived velocity (bit 2), and the version: the current one (6: survivors'
// residuals may be packed as nibbles, the second packet continues the first one's zstd frame),
// or with bit 3 an older one: 3 with bit 2 (a zstd frame a packet), else 4 (byte planes only).
// Bit 4, in the current version: the second frame is a keyframe too (each packet its own zstd
// frame), which in id order links its particles to the first's (version 6).
#pragma once

#include <cstring>
#include <span>
#include <vector>

#include "particlestream/codec.hpp"

namespace pstream::fuzz {

inline constexpr std::uint64_t kMaxParticles = 64;

inline format::Metadata particle_clip(std::uint8_t selector, std::uint64_t count0, std::uint64_t count1) {
  using namespace format;
  Metadata m;
  m.layout = default_layout();
  const bool more = (selector & 1) != 0;
  const bool derived = more && (selector & 4) != 0;
  if (more) {
    append_attribute(m.layout, "color", AttributeType::Unorm8, 4);
    append_attribute(m.layout, "id", AttributeType::Uint64, 1);
  }
  if (derived) append_attribute(m.layout, "velocity", AttributeType::Float32, 3);
  m.record_size = record_size_of(m.layout);
  m.codec.codec = FrameCodec::Particle;
  m.codec.order = (selector & 2) ? FrameOrder::Matched : more ? FrameOrder::Id : FrameOrder::Source;
  m.codec.keyframe_interval = 4;
  m.codec.error = 0.005;
  m.codec.words.resize(m.record_size / 4);
  for (int w = 0; w < 4; ++w) {
    m.codec.words[w] = {WordCoding::Quantized, 0.01f, 0.005f, 0};
  }
  if ((selector & 4) != 0) m.codec.words[3] = {WordCoding::Relative, 0.0f, 0.01f, 17};  // within 1 % of itself
  if ((selector & 8) != 0) m.version = (selector & 4) != 0 ? 3 : 4;
  if (more) {
    m.codec.words[4].coding = WordCoding::Exact;
    const WordCoding id = m.codec.order == FrameOrder::Id ? WordCoding::Id : WordCoding::Exact;
    m.codec.words[5].coding = m.codec.words[6].coding = id;
  }
  for (std::uint32_t c = 0; derived && c < 3; ++c)
    m.codec.words[7 + c] = {WordCoding::Derived, 0.01f * 24 / 2, 0.0f, c};
  const bool two_keyframes = (selector & 16) != 0 && (selector & 8) == 0;
  if (two_keyframes) m.codec.keyframe_interval = 1;
  for (std::uint64_t f = 0; f < 2; ++f) {
    FrameEntry e;
    e.count = f == 0 ? count0 : count1;
    e.keyframe = f == 0 || two_keyframes;
    m.frames.push_back(e);
  }
  m.max_count = std::max(count0, count1);
  return m;
}

}  // namespace pstream::fuzz
