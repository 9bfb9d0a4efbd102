// The records codec's decoding half: the packet is the frame's records, and every frame decodes
// alone. Its encoding half is records_encoder.cpp.
#include <cstring>

#include <fmt/format.h>

#include "format/frame_unit.hpp"

namespace pstream::format {
namespace {

// The records codec: the packet is the frame's records.
class RecordsUnit final : public FrameUnit {
 public:
  RecordsUnit(const Metadata& meta, std::string_view name) : meta_(meta), name_(name) {}
  std::size_t decode(std::uint64_t frame, bool /*keyframe*/, std::span<const std::byte> packet,
                     std::span<std::byte> out, std::span<MatchRun> /*matching*/) override {
    const std::uint64_t size = meta_.frames[frame].count * meta_.record_size;
    if (packet.size() != size || out.size() < size) {
      throw Error(
          fmt::format("{}: frame {}: a records packet of {} bytes, expected {}", name_, frame, packet.size(), size));
    }
    if (size != 0) std::memcpy(out.data(), packet.data(), size);
    return kNoMatching;  // every frame stands alone
  }
  void reset() override {}
  std::uint64_t state_bytes() const override { return 0; }

 private:
  const Metadata& meta_;
  std::string_view name_;
};

}  // namespace

std::unique_ptr<FrameUnit> make_records_unit(const Metadata& meta, std::string_view name) {
  return std::make_unique<RecordsUnit>(meta, name);
}

std::uint64_t records_unit_state_bytes(const Metadata& /*meta*/) { return 0; }
std::uint64_t records_unit_save_bytes(const Metadata& /*meta*/) { return 0; }

}  // namespace pstream::format
