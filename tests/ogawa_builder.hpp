// Writes small Ogawa files by hand, so tests can build the malformed archives that no exporter
// writes (cycles, impossible sizes, bad indices).
#pragma once

#include <cstdint>
#include <cstring>
#include <string_view>
#include <vector>

namespace pstream::test {

class OgawaBuilder {
 public:
  static constexpr std::uint64_t kData = 1ull << 63;

  OgawaBuilder() : out_(16) {}

  // Appends a data block; returns its child reference (bit 63 set).
  std::uint64_t data(std::string_view bytes) {
    if (bytes.empty()) return kData;
    const std::uint64_t at = out_.size();
    u64(bytes.size());
    for (char c : bytes) out_.push_back(static_cast<std::byte>(c));
    return at | kData;
  }
  // Appends a group of `children` references; returns its offset.
  std::uint64_t group(const std::vector<std::uint64_t>& children) {
    if (children.empty()) return 0;
    const std::uint64_t at = out_.size();
    u64(children.size());
    for (std::uint64_t c : children) u64(c);
    return at;
  }
  // The offset the next group or data block will get.
  std::uint64_t next_offset() const { return out_.size(); }

  // Root group with the six children of an Alembic archive and the given top object group.
  std::uint64_t alembic_root(std::uint64_t top_object) {
    const std::uint64_t file_version = data(le32(0));
    const std::uint64_t lib_version = data(le32(10812));
    const std::uint64_t metadata = data("_ai_Application=builder");
    std::string ts = le32(0);
    ts += le64(1.0);
    ts += le32(1);
    ts += le64(0.0);
    const std::uint64_t samplings = data(ts);
    const std::uint64_t indexed = data("");
    return group({file_version, lib_version, top_object, metadata, samplings, indexed});
  }

  std::vector<std::byte> finish(std::uint64_t root, unsigned char frozen = 0xFF) {
    std::vector<std::byte> file = out_;
    std::memcpy(file.data(), "Ogawa", 5);
    file[5] = static_cast<std::byte>(frozen);
    file[6] = std::byte{0};
    file[7] = std::byte{1};
    std::memcpy(file.data() + 8, &root, 8);
    return file;
  }

  static std::string le32(std::uint32_t v) { return std::string(reinterpret_cast<const char*>(&v), 4); }
  static std::string le64(double v) { return std::string(reinterpret_cast<const char*>(&v), 8); }
  static std::string le64u(std::uint64_t v) { return std::string(reinterpret_cast<const char*>(&v), 8); }
  // Object headers block: one entry per child name, metadata index 0, then 32 hash bytes.
  static std::string object_headers(const std::vector<std::string>& names) {
    std::string s;
    for (const auto& n : names) s += le32(static_cast<std::uint32_t>(n.size())) + n + std::string(1, '\0');
    return s + std::string(32, '\0');
  }

 private:
  void u64(std::uint64_t v) {
    const auto* p = reinterpret_cast<const std::byte*>(&v);
    out_.insert(out_.end(), p, p + 8);
  }
  std::vector<std::byte> out_;
};

}  // namespace pstream::test
