// The frame codecs' decoding halves, in one table (codec.hpp, "The registry").
#include "format/frame_unit.hpp"
#include "particlestream/codec.hpp"

namespace pstream::format {
namespace {

constexpr FrameCodecDecoding kDecoders[] = {
    {FrameCodec::Records, "records", records_unit_state_bytes, make_records_unit, records_unit_save_bytes},
    {FrameCodec::Particle, "particle", particle_unit_state_bytes, make_particle_unit, particle_unit_save_bytes},
};

}  // namespace

std::span<const FrameCodecDecoding> frame_codec_decoders() { return kDecoders; }

const FrameCodecDecoding* find_frame_codec(FrameCodec id) {
  for (const FrameCodecDecoding& c : kDecoders)
    if (c.id == id) return &c;
  return nullptr;
}

std::string_view frame_codec_name(FrameCodec codec) {
  const FrameCodecDecoding* c = find_frame_codec(codec);
  return c ? c->name : "?";
}

}  // namespace pstream::format
