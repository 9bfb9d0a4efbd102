// The Ogawa container: a tree of groups and data blocks addressed by 64-bit file offsets.
//
// Layout (all little-endian): a 16-byte header ("Ogawa", frozen byte 0xFF, version 0x00 0x01,
// uint64 offset of the root group); a group is uint64 n then n uint64 child offsets, bit 63
// marking a data block; a data block is uint64 size then the bytes. Offset 0 is an empty group
// or block. Every offset and size is checked against the file before it is used.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>

namespace pstream::alembic::ogawa {

struct Group {
  std::uint64_t offset = 0;  // of the group's count field; 0 for an empty group
  std::uint64_t count = 0;   // number of children
};

struct Data {
  std::uint64_t offset = 0;  // of the payload (after the size field)
  std::uint64_t size = 0;
};

class File {
 public:
  // Checks the header; throws pstream::Error naming `name` on any problem.
  File(std::span<const std::byte> bytes, std::string name);

  const std::string& name() const { return name_; }
  std::span<const std::byte> bytes() const { return bytes_; }
  std::uint64_t size() const { return bytes_.size(); }
  Group root() const { return root_; }

  bool child_is_data(const Group& group, std::uint64_t index) const;
  Group child_group(const Group& group, std::uint64_t index) const;
  Data child_data(const Group& group, std::uint64_t index) const;
  std::span<const std::byte> payload(const Data& data) const { return bytes_.subspan(data.offset, data.size); }

  std::uint64_t read_u64(std::uint64_t offset, std::string_view what) const;
  [[noreturn]] void fail(std::uint64_t offset, std::string_view what) const;

 private:
  Group group_at(std::uint64_t offset, std::string_view what) const;
  std::uint64_t child_offset(const Group& group, std::uint64_t index) const;

  std::span<const std::byte> bytes_;
  std::string name_;
  Group root_;
};

// Little-endian cursor over a data block's bytes, failing with the file offset of the field.
class Reader {
 public:
  Reader(const File& file, const Data& data) : file_(file), base_(data.offset), bytes_(file.payload(data)) {}
  bool done() const { return pos_ >= bytes_.size(); }
  std::size_t remaining() const { return bytes_.size() - pos_; }
  std::uint64_t offset() const { return base_ + pos_; }
  std::uint8_t u8(std::string_view what);
  std::uint32_t u32(std::string_view what);
  std::uint64_t u64(std::string_view what);
  double f64(std::string_view what);
  std::uint32_t sized(unsigned size_hint, std::string_view what);  // 1, 2 or 4 bytes by hint 0/1/2
  std::string_view str(std::size_t n, std::string_view what);

 private:
  const std::byte* need(std::size_t n, std::string_view what);
  const File& file_;
  std::uint64_t base_;
  std::span<const std::byte> bytes_;
  std::size_t pos_ = 0;
};

template <class T>
T load_le(const std::byte* p) {
  T v;
  __builtin_memcpy(&v, p, sizeof(T));  // the targets are little-endian; unaligned-safe
  return v;
}

}  // namespace pstream::alembic::ogawa
