// The records codec's encoding half: each frame's packet is its records as they are, a keyframe
// (records_decoder.cpp is the other half).
#include <algorithm>
#include <cstring>
#include <limits>

#include <fmt/format.h>

#include "particlestream/codec.hpp"

namespace pstream::format {

CodecInfo plan_records(const std::vector<Attribute>& /*layout*/, const ClipStats& /*stats*/, double /*fps*/,
                       bool /*has_ids*/, const ParticleCodecOptions& /*options*/) {
  CodecInfo info;
  info.codec = FrameCodec::Records;
  info.keyframe_interval = 1;
  return info;
}

std::vector<EncodedFrame> encode_records_group(const CodecInfo& /*info*/, std::span<const SourceFrame> frames,
                                               std::span<const SourceFrame> /*before*/, std::uint64_t first_index) {
  std::vector<EncodedFrame> out;
  out.reserve(frames.size());
  for (std::size_t f = 0; f < frames.size(); ++f) {
    const SourceFrame& frame = frames[f];
    const std::size_t record = frame.count ? frame.records.size() / frame.count : 0;
    if (frame.count != 0 && (record < 12 || record * frame.count != frame.records.size())) {
      throw Error(fmt::format("frame {}: {} bytes of records for {} particles", first_index + f, frame.records.size(),
                              frame.count));
    }
    EncodedFrame e;
    e.packet.assign(frame.records.begin(), frame.records.end());
    e.keyframe = true;
    e.count = frame.count;
    constexpr float inf = std::numeric_limits<float>::infinity();
    e.bounds = {inf, inf, inf, -inf, -inf, -inf};
    for (std::uint64_t i = 0; i < frame.count; ++i) {  // the position leads every record
      float p[3];
      std::memcpy(p, frame.records.data() + i * record, 12);
      for (int a = 0; a < 3; ++a) {
        e.bounds[std::size_t(a)] = std::min(e.bounds[std::size_t(a)], p[a]);
        e.bounds[std::size_t(a) + 3] = std::max(e.bounds[std::size_t(a) + 3], p[a]);
      }
    }
    out.push_back(std::move(e));
  }
  return out;
}

}  // namespace pstream::format
