// Facts of the Ogawa/Abc file layout shared by the reader and the writer (docs/alembic.md).
#pragma once

#include <cstddef>
#include <cstdint>

namespace pstream::alembic::layout {

inline constexpr std::uint64_t kDataBit = 1ull << 63;  // a group child that is a data block
inline constexpr std::size_t kHeaderSize = 16;         // "Ogawa", frozen byte, version, root offset
inline constexpr unsigned char kFrozen = 0xFF, kNotFrozen = 0x00;

// Root group children.
enum RootChild : std::uint64_t {
  kFileVersion = 0,
  kLibraryVersion,
  kTopObject,
  kMetadata,
  kTimeSamplings,
  kIndexedMetadata
};
inline constexpr std::uint64_t kRootChildren = 6;

inline constexpr std::size_t kObjectHashBytes = 32;  // object headers end with two 16-byte hashes
inline constexpr std::size_t kSampleKeyBytes = 16;   // every stored sample starts with its content key
inline constexpr std::uint8_t kMetadataInline = 0xff;

// The 32-bit info word that starts a property header.
namespace info {
inline constexpr std::uint32_t kTypeMask = 0x3;  // 0 compound, 1 scalar, 2 array, 3 scalar-like array
inline constexpr int kSizeHintShift = 2;         // counts take 1, 2 or 4 bytes (hint 0, 1, 2)
inline constexpr int kPodShift = 4;
inline constexpr std::uint32_t kHasTimeSampling = 0x100;
inline constexpr std::uint32_t kHasFirstLast = 0x200;
inline constexpr std::uint32_t kHomogeneous = 0x400;
inline constexpr std::uint32_t kConstant = 0x800;
inline constexpr int kExtentShift = 12;
inline constexpr int kMetadataShift = 20;
}  // namespace info

}  // namespace pstream::alembic::layout
