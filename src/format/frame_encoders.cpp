// The frame codecs' encoding halves, in one table (codec.hpp, "The registry").
#include "particlestream/codec.hpp"

namespace pstream::format {

// records_encoder.cpp
CodecInfo plan_records(const std::vector<Attribute>& layout, const ClipStats& stats, double fps, bool has_ids,
                       const ParticleCodecOptions& options);
std::vector<EncodedFrame> encode_records_group(const CodecInfo& info, std::span<const SourceFrame> frames,
                                               std::span<const SourceFrame> before, std::uint64_t first_index);

namespace {

const FrameCodecEncoding kEncoders[] = {
    {FrameCodec::Records, "records", plan_records, encode_records_group},
    {FrameCodec::Particle, "particle", plan_particle_codec, encode_group},  // frame_plan.cpp, particle_encoder.cpp
};

}  // namespace

std::span<const FrameCodecEncoding> frame_codec_encoders() { return kEncoders; }

const FrameCodecEncoding* find_frame_codec_encoder(FrameCodec id) {
  for (const FrameCodecEncoding& c : kEncoders)
    if (c.id == id) return &c;
  return nullptr;
}

}  // namespace pstream::format
