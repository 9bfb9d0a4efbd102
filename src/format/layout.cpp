#include <fmt/format.h>

#include "particlestream/format.hpp"

namespace pstream::format {

std::string_view attribute_type_name(AttributeType type) {
  switch (type) {
    case AttributeType::Float32: return "float32";
    case AttributeType::Unorm8: return "unorm8";
    case AttributeType::Uint32: return "uint32";
    case AttributeType::Uint64: return "uint64";
  }
  return "?";
}

std::size_t attribute_type_size(AttributeType type) {
  switch (type) {
    case AttributeType::Float32:
    case AttributeType::Uint32: return 4;
    case AttributeType::Unorm8: return 1;
    case AttributeType::Uint64: return 8;
  }
  return 0;
}

std::string_view codec_name(Codec codec) {
  switch (codec) {
    case Codec::Raw: return "raw";
    case Codec::Lz4: return "lz4";
    case Codec::Zstd: return "zstd";
  }
  return "?";
}

std::uint64_t Metadata::stream_size() const {
  return frames.empty() ? 0 : frames.back().byte_offset + frames.back().count * record_size;
}

std::uint64_t Metadata::chunk_raw_size(std::uint64_t chunk) const {
  const std::uint64_t begin = chunk * chunk_size;
  const std::uint64_t total = stream_size();
  return begin >= total ? 0 : std::min(chunk_size, total - begin);
}

const Attribute* Metadata::find(std::string_view name) const {
  for (const Attribute& a : layout) {
    if (a.name == name) return &a;
  }
  return nullptr;
}

std::uint32_t record_size_of(const std::vector<Attribute>& layout) {
  std::uint32_t end = 0;
  for (const Attribute& a : layout) end = std::max<std::uint32_t>(end, a.offset + static_cast<std::uint32_t>(a.size()));
  return (end + 3u) & ~3u;
}

std::uint32_t append_attribute(std::vector<Attribute>& layout, std::string name, AttributeType type,
                               std::uint8_t components) {
  if (name.empty() || name.size() >= kAttributeNameSize) {
    throw Error(fmt::format("attribute name '{}' must have 1 to {} characters", name, kAttributeNameSize - 1));
  }
  for (const Attribute& a : layout) {
    if (a.name == name) throw Error(fmt::format("attribute '{}' appears twice in the record layout", name));
  }
  if (layout.size() >= kMaxAttributes) throw Error(fmt::format("a record holds at most {} attributes", kMaxAttributes));
  const std::uint32_t offset = record_size_of(layout);
  layout.push_back({std::move(name), type, components, offset});
  return record_size_of(layout);
}

std::vector<Attribute> default_layout() {
  return {{"position", AttributeType::Float32, 3, 0}, {"scale", AttributeType::Float32, 1, 12}};
}

}  // namespace pstream::format
