// A frame codec's decoding half: a pluggable unit that keeps its own reference state. Units are
// made by FrameDecoder from the clip's metadata (its layout and CodecInfo); decode() sees the
// frame's index, whether it is a keyframe, its packet and the output records, and hands back the
// matching to the frame before when it has one.
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <string_view>

#include "particlestream/codec.hpp"

namespace pstream::format {

class FrameUnit {
 public:
  virtual ~FrameUnit() = default;
  // Decodes frame `frame` (the successor of the last one, unless `keyframe`) into `out`
  // (count × record_size bytes). Throws pstream::Error naming the frame and the offset.
  // Returns the runs it wrote to `matching` (codec.hpp), or kNoMatching.
  virtual std::size_t decode(std::uint64_t frame, bool keyframe, std::span<const std::byte> packet,
                             std::span<std::byte> out, std::span<MatchRun> matching) = 0;
  virtual void reset() = 0;
  virtual std::uint64_t state_bytes() const = 0;
  // What decoding the next frame needs of the frame decoded last, saved as bytes (save_bytes() of
  // them, fixed at construction; 0: the codec keeps nothing between frames, or cannot save it
  // here) so that restore() can later continue after that frame (FrameDecoder's saved states).
  virtual std::uint64_t save_bytes() const { return 0; }
  virtual void save(std::span<std::byte> /*to*/) const {}
  virtual void restore(std::span<const std::byte> /*from*/) {}
};

// Each codec's decoding half (the registry, frame_codecs.cpp, lists them): its unit, and the
// bytes that unit allocates for `meta`, known before anything is allocated.
std::unique_ptr<FrameUnit> make_records_unit(const Metadata& meta, std::string_view name);
std::uint64_t records_unit_state_bytes(const Metadata& meta);
std::uint64_t records_unit_save_bytes(const Metadata& meta);  // 0: every records frame stands alone
std::unique_ptr<FrameUnit> make_particle_unit(const Metadata& meta, std::string_view name);
std::uint64_t particle_unit_state_bytes(const Metadata& meta);
std::uint64_t particle_unit_save_bytes(const Metadata& meta);  // its units' save_bytes()

}  // namespace pstream::format
