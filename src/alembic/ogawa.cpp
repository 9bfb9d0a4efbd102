#include "alembic/ogawa.hpp"
#include "alembic/layout.hpp"

#include <cstring>
#include <string_view>

#include <fmt/format.h>

#include "particlestream/error.hpp"

namespace pstream::alembic::ogawa {
namespace {

using layout::kDataBit;
using layout::kHeaderSize;
constexpr unsigned char kHdf5Signature[8] = {0x89, 'H', 'D', 'F', '\r', '\n', 0x1a, '\n'};

bool has_hdf5_signature(std::span<const std::byte> bytes) {
  // HDF5 puts its superblock at offset 0, 512, 1024, 2048, ...
  for (std::uint64_t at = 0; at + 8 <= bytes.size(); at = at == 0 ? 512 : at * 2) {
    if (std::memcmp(bytes.data() + at, kHdf5Signature, 8) == 0) return true;
  }
  return false;
}

}  // namespace

File::File(std::span<const std::byte> bytes, std::string name) : bytes_(bytes), name_(std::move(name)) {
  if (bytes_.empty()) throw Error(fmt::format("{}: empty file (expected an Ogawa Alembic archive)", name_));
  if (has_hdf5_signature(bytes_)) {
    throw Error(
        fmt::format("{}: this Alembic archive uses the legacy HDF5 backend, which ParticleStream does not read; "
                    "re-export it with the Ogawa backend (the default of every current exporter)",
                    name_));
  }
  const std::string_view start(reinterpret_cast<const char*>(bytes_.data()), std::min<std::size_t>(bytes_.size(), 8));
  if (start.starts_with("PSTREAM")) {
    throw Error(
        fmt::format("{}: is a cooked .pstream clip, not an Alembic archive (it is already cooked: play, "
                    "render or export it)",
                    name_));
  }
  if (start.starts_with("ply")) {
    throw Error(
        fmt::format("{}: is a PLY file, not an Alembic archive (cook reads PLY sequences: name a file whose "
                    "extension is .ply)",
                    name_));
  }
  if (bytes_.size() < kHeaderSize) {
    fail(bytes_.size(), fmt::format("truncated header: {} bytes, an Ogawa header has {}", bytes_.size(), kHeaderSize));
  }
  if (std::memcmp(bytes_.data(), "Ogawa", 5) != 0) fail(0, "not an Alembic file: expected the magic \"Ogawa\"");
  const auto frozen = static_cast<unsigned char>(bytes_[5]);
  if (frozen == 0x00)
    fail(5, "the file is still being written or its writer crashed (frozen byte is 0x00, expected 0xFF)");
  if (frozen != 0xFF) fail(5, fmt::format("invalid frozen byte 0x{:02X}, expected 0xFF", frozen));
  const auto v0 = static_cast<unsigned char>(bytes_[6]), v1 = static_cast<unsigned char>(bytes_[7]);
  if (v0 != 0 || v1 != 1) fail(6, fmt::format("unsupported Ogawa version {}.{}, expected 0.1", v0, v1));
  const std::uint64_t root = read_u64(8, "root group offset");
  if (root & kDataBit) fail(8, "root offset points at a data block, expected a group");
  if (root == 0) fail(8, "root group is empty");
  root_ = group_at(root, "root group");
}

void File::fail(std::uint64_t offset, std::string_view what) const {
  throw Error(fmt::format("{}: at offset {}: {}", name_, offset, what));
}

std::uint64_t File::read_u64(std::uint64_t offset, std::string_view what) const {
  if (offset > bytes_.size() || bytes_.size() - offset < 8) {
    fail(offset,
         fmt::format("{} lies past the end of the file ({} bytes): truncated or corrupted", what, bytes_.size()));
  }
  return load_le<std::uint64_t>(bytes_.data() + offset);
}

Group File::group_at(std::uint64_t offset, std::string_view what) const {
  if (offset == 0) return {};
  if (offset < kHeaderSize) fail(offset, fmt::format("{} overlaps the file header", what));
  const std::uint64_t count = read_u64(offset, what);
  const std::uint64_t room = (bytes_.size() - offset - 8) / 8;
  if (count > room) {
    fail(offset, fmt::format("{} claims {} children but only {} fit before the end of the file", what, count, room));
  }
  return {offset, count};
}

std::uint64_t File::child_offset(const Group& group, std::uint64_t index) const {
  if (index >= group.count) {
    fail(group.offset, fmt::format("group has {} children, child {} was expected", group.count, index));
  }
  return load_le<std::uint64_t>(bytes_.data() + group.offset + 8 + index * 8);
}

bool File::child_is_data(const Group& group, std::uint64_t index) const {
  return (child_offset(group, index) & kDataBit) != 0;
}

Group File::child_group(const Group& group, std::uint64_t index) const {
  const std::uint64_t raw = child_offset(group, index);
  if (raw & kDataBit) fail(group.offset, fmt::format("child {} is a data block, expected a group", index));
  return group_at(raw, fmt::format("group (child {} of the group at {})", index, group.offset));
}

Data File::child_data(const Group& group, std::uint64_t index) const {
  const std::uint64_t raw = child_offset(group, index);
  if (!(raw & kDataBit)) fail(group.offset, fmt::format("child {} is a group, expected a data block", index));
  const std::uint64_t offset = raw & ~kDataBit;
  if (offset == 0) return {};
  if (offset < kHeaderSize) fail(offset, "data block overlaps the file header");
  const std::uint64_t size = read_u64(offset, "data block size");
  if (size > bytes_.size() - offset - 8) {
    fail(offset, fmt::format("data block of {} bytes runs past the end of the file ({} bytes left)", size,
                             bytes_.size() - offset - 8));
  }
  return {offset + 8, size};
}

const std::byte* Reader::need(std::size_t n, std::string_view what) {
  if (remaining() < n) {
    file_.fail(offset(), fmt::format("{}: needs {} bytes, the block has {} left", what, n, remaining()));
  }
  const std::byte* p = bytes_.data() + pos_;
  pos_ += n;
  return p;
}

std::uint8_t Reader::u8(std::string_view what) { return static_cast<std::uint8_t>(*need(1, what)); }
std::uint32_t Reader::u32(std::string_view what) { return load_le<std::uint32_t>(need(4, what)); }
std::uint64_t Reader::u64(std::string_view what) { return load_le<std::uint64_t>(need(8, what)); }
double Reader::f64(std::string_view what) { return load_le<double>(need(8, what)); }

std::uint32_t Reader::sized(unsigned size_hint, std::string_view what) {
  switch (size_hint) {
    case 0: return u8(what);
    case 1: return load_le<std::uint16_t>(need(2, what));
    case 2: return u32(what);
    default: file_.fail(offset(), fmt::format("{}: invalid size hint {}", what, size_hint));
  }
}

std::string_view Reader::str(std::size_t n, std::string_view what) {
  const std::byte* p = need(n, what);
  return {reinterpret_cast<const char*>(p), n};
}

}  // namespace pstream::alembic::ogawa
