// Compound property groups: one child per property plus a last data block packing every
// property's header (see docs/alembic.md for the bit layout of the info word).
#include <fmt/format.h>

#include "alembic/archive_data.hpp"
#include "alembic/layout.hpp"

namespace pstream::alembic::detail {
namespace {

using namespace layout::info;
constexpr std::uint32_t kMetadataInline = layout::kMetadataInline;

PropertyHeader read_header(const ArchiveData& archive, ogawa::Reader& in) {
  const std::uint64_t at = in.offset();
  const std::uint32_t info = in.u32("property header info");
  PropertyHeader h;
  const std::uint32_t type = info & kTypeMask;
  const unsigned size_hint = (info >> kSizeHintShift) & 0x3;
  h.kind = type == 0 ? PropertyKind::Compound : type == 1 ? PropertyKind::Scalar : PropertyKind::Array;
  h.scalar_like = (type & 1) != 0 && type != 1;
  if (h.kind != PropertyKind::Compound) {
    const std::uint32_t pod = (info >> kPodShift) & 0xf;
    if (pod > static_cast<std::uint32_t>(Pod::WString)) {
      archive.file.fail(at, fmt::format("property header has invalid POD type {} (expected 0..13)", pod));
    }
    h.pod = static_cast<Pod>(pod);
    h.extent = static_cast<std::uint8_t>((info >> kExtentShift) & 0xff);
    if (h.extent == 0) archive.file.fail(at, "property header has extent 0 (expected at least 1)");
    h.homogeneous = (info & kHomogeneous) != 0;
    h.num_samples = in.sized(size_hint, "property sample count");
    if (info & kHasFirstLast) {
      h.first_changed = in.sized(size_hint, "property first changed index");
      h.last_changed = in.sized(size_hint, "property last changed index");
    } else if (info & kConstant) {
      h.first_changed = h.last_changed = 0;
    } else {
      h.first_changed = 1;
      h.last_changed = h.num_samples - 1;
    }
    if (info & kHasTimeSampling) h.time_sampling_index = in.sized(size_hint, "property time sampling index");
    if (h.time_sampling_index >= archive.time_samplings.size()) {
      archive.file.fail(at, fmt::format("property uses time sampling {} but the archive has {}", h.time_sampling_index,
                                        archive.time_samplings.size()));
    }
  }
  const std::uint32_t name_size = in.sized(size_hint, "property name size");
  h.name = std::string(in.str(name_size, "property name"));
  const std::uint32_t md_index = (info >> kMetadataShift) & 0xff;
  if (md_index == kMetadataInline) {
    const std::uint32_t md_size = in.sized(size_hint, "property metadata size");
    h.metadata = MetaData::parse(in.str(md_size, "property metadata"));
  } else if (md_index < archive.indexed_metadata.size()) {
    h.metadata = archive.indexed_metadata[md_index];
  } else {
    archive.file.fail(at, fmt::format("property '{}' refers to metadata entry {} but the archive has {}", h.name,
                                      md_index, archive.indexed_metadata.size()));
  }
  return h;
}

}  // namespace

void read_compound(const ArchiveData& archive, PropertyNode& compound, std::unordered_set<std::uint64_t>& visited,
                   int depth) {
  const ogawa::File& file = archive.file;
  const ogawa::Group group = compound.group;
  if (group.count == 0) return;
  if (depth > kMaxHierarchyDepth) {
    file.fail(group.offset, fmt::format("compound properties nest deeper than {} levels", kMaxHierarchyDepth));
  }
  if (group.offset != 0 && !visited.insert(group.offset).second) {
    file.fail(group.offset, "property group is reached twice: the hierarchy has a cycle or a corrupted offset");
  }
  const ogawa::Data headers = file.child_data(group, group.count - 1);
  ogawa::Reader in(file, headers);
  const std::uint64_t property_count = group.count - 1;
  while (!in.done()) {
    if (compound.children.size() >= property_count) {
      file.fail(in.offset(),
                fmt::format("compound property holds {} properties but its headers describe more", property_count));
    }
    auto node = std::make_unique<PropertyNode>();
    node->header = read_header(archive, in);
    node->group = file.child_group(group, compound.children.size());
    if (node->header.kind == PropertyKind::Compound) {
      read_compound(archive, *node, visited, depth + 1);
    } else if (node->header.kind == PropertyKind::Scalar) {
      node->stored_count = node->group.count;
    } else {
      if (node->group.count % 2 != 0) {
        file.fail(node->group.offset, fmt::format("array property '{}' has {} children, expected pairs of data and "
                                                  "dimensions",
                                                  node->header.name, node->group.count));
      }
      node->stored_count = node->group.count / 2;
    }
    compound.children.push_back(std::move(node));
  }
  if (compound.children.size() != property_count) {
    file.fail(headers.offset, fmt::format("compound property holds {} properties but its headers describe {}",
                                          property_count, compound.children.size()));
  }
}

}  // namespace pstream::alembic::detail
