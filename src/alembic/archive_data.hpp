// What an open archive keeps in memory: the object and property hierarchy with every header
// (small), parsed eagerly at open; sample data stays in the mapping until it is asked for.
#pragma once

#include <memory>
#include <optional>
#include <unordered_set>
#include <vector>

#include "alembic/ogawa.hpp"
#include "base/mapped_file.hpp"
#include "particlestream/alembic.hpp"
#include "particlestream/io.hpp"

namespace pstream::alembic::detail {

struct PropertyNode {
  PropertyHeader header;
  ogawa::Group group;                                   // samples, or the children of a compound
  std::uint64_t stored_count = 0;                       // stored samples (scalar/array)
  std::vector<std::unique_ptr<PropertyNode>> children;  // compound only
};

// An object as the official IObject API presents it. A stored object holds its own metadata and
// properties. An instance (metadata isInstance=1, a `.instanceSource` path) is presented as its
// target: own name, path and parent, the target's metadata, properties and children; the
// children are nodes made for the instanced paths, `stored` pointing at the target's nodes.
struct ObjectNode {
  std::string name;
  std::string full_name;
  MetaData metadata;
  const ObjectNode* parent = nullptr;
  std::unique_ptr<PropertyNode> properties;  // the top compound; never null on a stored object
  std::vector<std::unique_ptr<ObjectNode>> children;
  const ObjectNode* stored = this;  // the stored object whose metadata and properties this presents
  std::string instance_source;      // an instance root: the target's path
  bool instance_descendant = false;
  enum class Resolve : std::uint8_t { No, InProgress, Done } resolve = Resolve::No;
};

struct ArchiveData {
  ArchiveData(MappedFile m, std::span<const std::byte> bytes, std::string name)
      : mapping(std::move(m)), file(bytes, std::move(name)) {}
  MappedFile mapping;                      // empty for from_memory archives
  std::unique_ptr<io::ByteSource> source;  // a mapped byte source, kept open
  std::unique_ptr<std::byte[]> owned;      // the bytes of a source read into memory
  ogawa::File file;
  std::uint32_t ogawa_version = 0;
  std::uint32_t archive_version = 0;
  MetaData metadata;
  std::vector<TimeSampling> time_samplings;
  std::vector<MetaData> indexed_metadata;  // [0] is the empty metadata
  std::unique_ptr<ObjectNode> top;
};

struct Access {
  static Property property(const ArchiveData* archive, const PropertyNode* node) { return {archive, node}; }
};

// Parses the property headers of the compound property group `group` (src/alembic/property_headers.cpp).
// `visited` holds every hierarchy group seen so far: a group met twice is a cycle or a
// corrupted offset, and walking it again could loop or blow up.
void read_compound(const ArchiveData& archive, PropertyNode& compound, std::unordered_set<std::uint64_t>& visited,
                   int depth);

// Deeper hierarchies are rejected: real files stay far below, and recursion must stay bounded.
inline constexpr int kMaxHierarchyDepth = 1000;

}  // namespace pstream::alembic::detail
