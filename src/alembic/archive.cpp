// Opening an archive: the root group, archive metadata, time samplings, the indexed-metadata
// table and the object hierarchy with every property header.
#include <algorithm>
#include <cstdlib>
#include <limits>
#include <memory>

#include <fmt/format.h>

#include "alembic/archive_data.hpp"
#include "alembic/layout.hpp"
#include "base/memory.hpp"

namespace pstream::alembic {
namespace {

using detail::ArchiveData;
using detail::ObjectNode;
using detail::PropertyNode;

using namespace layout;

std::uint32_t read_u32_block(const ArchiveData& a, ogawa::Data data, std::string_view what) {
  ogawa::Reader in(a.file, data);
  const std::uint32_t v = in.u32(what);
  return v;
}

std::vector<TimeSampling> read_time_samplings(const ogawa::File& file, ogawa::Data data) {
  std::vector<TimeSampling> out;
  ogawa::Reader in(file, data);
  while (!in.done()) {
    TimeSampling ts;
    ts.max_num_samples = in.u32("time sampling max sample count");
    ts.time_per_cycle = in.f64("time sampling time per cycle");
    const std::uint64_t at = in.offset();
    const std::uint32_t n = in.u32("time sampling stored time count");
    if (n == 0) file.fail(at, "time sampling stores no times (expected at least one)");
    if (static_cast<std::uint64_t>(n) * 8 > in.remaining()) {
      file.fail(at, fmt::format("time sampling claims {} stored times but only {} bytes remain", n, in.remaining()));
    }
    ts.stored_times.clear();
    ts.stored_times.reserve(n);
    for (std::uint32_t i = 0; i < n; ++i) {
      const std::uint64_t time_at = in.offset();
      const double t = in.f64("time sampling stored time");
      // Every lookup by time does arithmetic on these: NaN or infinity would make nonsense of it.
      if (!std::isfinite(t)) {
        file.fail(time_at, fmt::format("time sampling {} stores time {} (sample {} of its cycle), expected a finite "
                                       "number of seconds",
                                       out.size(), t, i));
      }
      ts.stored_times.push_back(t);
    }
    if (ts.time_per_cycle == TimeSampling::kAcyclicTimePerCycle) {
      ts.type = TimeSamplingType::Acyclic;
      ts.samples_per_cycle = TimeSampling::kAcyclicSamplesPerCycle;
    } else {
      if (!(ts.time_per_cycle > 0.0) || !std::isfinite(ts.time_per_cycle)) {
        file.fail(at - 8,
                  fmt::format("time sampling has time per cycle {}, expected a positive number", ts.time_per_cycle));
      }
      ts.type = n == 1 ? TimeSamplingType::Uniform : TimeSamplingType::Cyclic;
      ts.samples_per_cycle = n;
    }
    out.push_back(std::move(ts));
  }
  if (out.empty()) out.emplace_back();  // the default identity sampling always exists
  return out;
}

std::vector<MetaData> read_indexed_metadata(const ogawa::File& file, ogawa::Data data) {
  std::vector<MetaData> out(1);  // entry 0 is the empty metadata
  ogawa::Reader in(file, data);
  while (!in.done()) {
    const std::uint8_t size = in.u8("indexed metadata size");
    out.push_back(MetaData::parse(in.str(size, "indexed metadata string")));
  }
  return out;
}

void read_object(const ArchiveData& a, ObjectNode& object, ogawa::Group group,
                 std::unordered_set<std::uint64_t>& visited, int depth) {
  const ogawa::File& file = a.file;
  if (depth > detail::kMaxHierarchyDepth) {
    file.fail(group.offset, fmt::format("objects nest deeper than {} levels", detail::kMaxHierarchyDepth));
  }
  if (group.offset != 0 && !visited.insert(group.offset).second) {
    file.fail(group.offset, fmt::format("object group of '{}' is reached twice: the hierarchy has a cycle or a "
                                        "corrupted offset",
                                        object.full_name));
  }
  object.properties = std::make_unique<PropertyNode>();
  object.properties->header.kind = PropertyKind::Compound;
  if (group.count == 0) return;
  object.properties->group = file.child_group(group, 0);
  detail::read_compound(a, *object.properties, visited, 0);
  if (group.count == 1) return;

  // The last child packs the child objects' headers, followed by hashes.
  const ogawa::Data headers = file.child_data(group, group.count - 1);
  const std::uint64_t child_count = group.count - 2;
  if (headers.size > kObjectHashBytes) {
    ogawa::Reader in(file, {headers.offset, headers.size - kObjectHashBytes});
    while (!in.done()) {
      if (object.children.size() >= child_count) {
        file.fail(in.offset(), fmt::format("object '{}' has {} child groups but its headers describe more",
                                           object.full_name, child_count));
      }
      auto child = std::make_unique<ObjectNode>();
      const std::uint32_t name_size = in.u32("object name size");
      child->name = std::string(in.str(name_size, "object name"));
      child->full_name = object.parent == nullptr ? std::string() : object.full_name;
      child->full_name.append("/").append(child->name);
      const std::uint64_t md_at = in.offset();
      const std::uint8_t md_index = in.u8("object metadata index");
      if (md_index == kMetadataInline) {
        const std::uint32_t md_size = in.u32("object metadata size");
        child->metadata = MetaData::parse(in.str(md_size, "object metadata"));
      } else if (md_index < a.indexed_metadata.size()) {
        child->metadata = a.indexed_metadata[md_index];
      } else {
        file.fail(md_at, fmt::format("object '{}' refers to metadata entry {} but the archive has {}", child->full_name,
                                     md_index, a.indexed_metadata.size()));
      }
      child->parent = &object;
      object.children.push_back(std::move(child));
    }
  }
  if (object.children.size() != child_count) {
    file.fail(headers.offset, fmt::format("object '{}' has {} child groups but its headers describe {}",
                                          object.full_name, child_count, object.children.size()));
  }
  for (std::size_t i = 0; i < object.children.size(); ++i) {
    read_object(a, *object.children[i], file.child_group(group, i + 1), visited, depth + 1);
  }
}

// ---- Instances ------------------------------------------------------------------------------

// More presented objects than this are refused: nested instances multiply, and a small file could
// otherwise ask for an exponential number of them.
constexpr std::size_t kMaxPresentedObjects = 1'000'000;

struct InstanceResolver {
  const ArchiveData& a;
  std::size_t presented = 0;

  // The stored object at `path`, walking stored children by name.
  ObjectNode* find_stored(ObjectNode& top, std::string_view path) {
    ObjectNode* node = &top;
    std::size_t at = 1;
    while (at < path.size()) {
      const std::size_t slash = std::min(path.find('/', at), path.size());
      const std::string_view name = path.substr(at, slash - at);
      ObjectNode* next = nullptr;
      for (auto& c : node->children) {
        if (c->name == name) next = c.get();
      }
      if (next == nullptr) return nullptr;
      node = next;
      at = slash + 1;
    }
    return node;
  }

  // Nodes for `source`'s children under `parent` (an instance root or one of its descendants).
  void clone_children(const ObjectNode& source, ObjectNode& parent, int depth) {
    if (depth > detail::kMaxHierarchyDepth) {
      a.file.fail(0, fmt::format("instances below '{}' nest deeper than {} levels", parent.full_name,
                                 detail::kMaxHierarchyDepth));
    }
    for (const auto& c : source.children) {
      if (++presented > kMaxPresentedObjects) {
        a.file.fail(
            0, fmt::format("instances present more than {} objects (at '{}')", kMaxPresentedObjects, parent.full_name));
      }
      auto node = std::make_unique<ObjectNode>();
      node->name = c->name;
      node->full_name = parent.full_name + "/" + c->name;
      node->metadata = c->stored->metadata;
      node->parent = &parent;
      node->stored = c->stored;
      node->instance_source = c->instance_source;
      node->instance_descendant = true;
      node->resolve = ObjectNode::Resolve::Done;
      clone_children(*c, *node, depth + 1);
      parent.children.push_back(std::move(node));
    }
  }

  void resolve(ObjectNode& top, ObjectNode& node, int depth) {
    if (node.resolve == ObjectNode::Resolve::Done) return;
    if (node.resolve == ObjectNode::Resolve::InProgress) {
      a.file.fail(0, fmt::format("instance '{}' refers to itself through its instance sources", node.full_name));
    }
    node.resolve = ObjectNode::Resolve::InProgress;
    if (node.metadata.get("isInstance") == "1") {
      const auto source = detail::Access::property(&a, node.properties.get()).find(".instanceSource");
      if (!source || source->kind() != PropertyKind::Scalar || source->header().pod != Pod::String ||
          source->header().num_samples == 0) {
        a.file.fail(node.properties->group.offset,
                    fmt::format("instance '{}' has no string property .instanceSource", node.full_name));
      }
      const std::vector<std::string> path = source->sample(0).strings();
      ObjectNode* target = path.empty() ? nullptr : find_stored(top, path[0]);
      if (target == nullptr || target == &top) {
        a.file.fail(node.properties->group.offset,
                    fmt::format("instance '{}' refers to '{}', which is not an object of the archive", node.full_name,
                                path.empty() ? std::string() : path[0]));
      }
      if (depth > detail::kMaxHierarchyDepth)
        a.file.fail(0, fmt::format("instance '{}' resolves through too many instances", node.full_name));
      resolve(top, *target, depth + 1);
      node.stored = target->stored;
      node.metadata = target->stored->metadata;
      node.instance_source = target->full_name;
      node.instance_descendant = true;
      node.children.clear();
      clone_children(*target, node, 0);
    } else {
      for (auto& c : node.children) resolve(top, *c, depth + 1);
    }
    node.resolve = ObjectNode::Resolve::Done;
  }
};

std::unique_ptr<ArchiveData> parse(std::unique_ptr<ArchiveData> a) {
  const ogawa::File& file = a->file;
  const ogawa::Group root = file.root();
  if (root.count < kRootChildren) {
    file.fail(root.offset,
              fmt::format("root group has {} children, an Alembic archive has at least {}", root.count, kRootChildren));
  }
  a->ogawa_version = read_u32_block(*a, file.child_data(root, kFileVersion), "Ogawa file version");
  a->archive_version = read_u32_block(*a, file.child_data(root, kLibraryVersion), "Alembic library version");
  const ogawa::Data md = file.child_data(root, kMetadata);
  a->metadata = MetaData::parse(std::string_view(reinterpret_cast<const char*>(file.payload(md).data()), md.size));
  a->time_samplings = read_time_samplings(file, file.child_data(root, kTimeSamplings));
  a->indexed_metadata = read_indexed_metadata(file, file.child_data(root, kIndexedMetadata));

  a->top = std::make_unique<ObjectNode>();
  a->top->name.assign("ABC");
  a->top->full_name.assign(1, '/');

  std::unordered_set<std::uint64_t> visited;
  read_object(*a, *a->top, file.child_group(root, kTopObject), visited, 0);
  InstanceResolver{*a}.resolve(*a->top, *a->top, 0);
  return a;
}

void collect(const detail::ArchiveData* a, const ObjectNode& node, std::vector<Object>& out, auto make) {
  for (const auto& child : node.children) {
    out.push_back(make(a, child.get()));
    collect(a, *child, out, make);
  }
}

}  // namespace

// ---- Archive --------------------------------------------------------------------------------

Archive::Archive(std::unique_ptr<detail::ArchiveData> data) : d_(std::move(data)) {}
Archive::Archive(Archive&&) noexcept = default;
Archive& Archive::operator=(Archive&&) noexcept = default;
Archive::~Archive() = default;

Archive Archive::open(const std::filesystem::path& path, const Fetched& fetched) {
  if (io::is_url(path.string())) return open(io::open_url(path.string()), fetched);
  MappedFile mapping = MappedFile::open(path);
  const auto bytes = mapping.bytes();
  return Archive(parse(std::make_unique<ArchiveData>(std::move(mapping), bytes, path.string())));
}

Archive Archive::open(std::unique_ptr<io::ByteSource> source, const Fetched& fetched) {
  const std::span<const std::byte> mapped = source->mapped();
  if (!mapped.empty()) {
    auto data = std::make_unique<ArchiveData>(MappedFile(), mapped, source->name());
    data->source = std::move(source);
    return Archive(parse(std::move(data)));
  }
  // One allocation, not filled first: its pages are taken as the reads fill them, so a source
  // that claims more than it delivers costs the bytes that came.
  const std::uint64_t size = source->size();
  const std::uint64_t machine = memory::physical_memory();
  if (size > machine) {
    throw Error(fmt::format("{}: the archive is {} bytes; it is read whole into memory, and this machine has {}",
                            source->name(), size, machine));
  }
  std::unique_ptr<std::byte[]> bytes = std::make_unique_for_overwrite<std::byte[]>(size);
  constexpr std::uint64_t kPiece = std::uint64_t{8} << 20;
  for (std::uint64_t at = 0; at < size;) {
    const std::uint64_t n = std::min(kPiece, size - at);
    source->read(at, std::span(bytes.get() + at, n));
    at += n;
    if (fetched) fetched(at, size);
  }
  auto data =
      std::make_unique<ArchiveData>(MappedFile(), std::span<const std::byte>(bytes.get(), size), source->name());
  data->owned = std::move(bytes);
  return Archive(parse(std::move(data)));
}

Archive Archive::from_memory(std::span<const std::byte> bytes, std::string name) {
  return Archive(parse(std::make_unique<ArchiveData>(MappedFile(), bytes, std::move(name))));
}

const std::string& Archive::name() const { return d_->file.name(); }
std::uint64_t Archive::file_size() const { return d_->file.size(); }
std::span<const std::byte> Archive::bytes() const { return d_->file.bytes(); }
std::uint32_t Archive::ogawa_file_version() const { return d_->ogawa_version; }
std::uint32_t Archive::archive_version() const { return d_->archive_version; }
const MetaData& Archive::metadata() const { return d_->metadata; }
const std::vector<TimeSampling>& Archive::time_samplings() const { return d_->time_samplings; }

const TimeSampling& Archive::time_sampling(std::uint32_t index) const {
  if (index >= d_->time_samplings.size()) {
    throw Error(
        fmt::format("{}: time sampling {} requested, the archive has {}", name(), index, d_->time_samplings.size()));
  }
  return d_->time_samplings[index];
}

ArchiveInfo Archive::info() const {
  ArchiveInfo info;
  info.app_name = d_->metadata.get("_ai_Application");
  info.alembic_version_string = d_->metadata.get("_ai_AlembicVersion");
  info.alembic_api_version = d_->archive_version;
  info.date_written = d_->metadata.get("_ai_DateWritten");
  info.user_description = d_->metadata.get("_ai_Description");
  const std::string fps = d_->metadata.get("_ai_DCC_FPS");
  info.dcc_fps = fps.empty() ? 0.0 : std::strtod(fps.c_str(), nullptr);
  return info;
}

std::pair<double, double> Archive::start_end_time() const {
  // Abc::GetArchiveStartAndEndTime's three tiers, the first that finds anything wins:
  //   1. samplings other than the default (index 0) with more than one sample;
  //   2. else those samplings with exactly one sample;
  //   3. else the default sampling, when anything is sampled on it.
  // Nothing sampled at all: +DBL_MAX, -DBL_MAX, as the official library reports.
  double start = std::numeric_limits<double>::max();
  double end = -std::numeric_limits<double>::max();
  const auto take = [&](const TimeSampling& ts) {
    start = std::min(start, ts.sample_time(0));
    end = std::max(end, ts.sample_time(ts.max_num_samples - 1));
  };
  const auto& samplings = d_->time_samplings;
  for (const auto fits : {+[](std::uint32_t n) { return n > 1; }, +[](std::uint32_t n) { return n == 1; }}) {
    for (std::size_t i = 1; i < samplings.size(); ++i) {
      if (fits(samplings[i].max_num_samples)) take(samplings[i]);
    }
    if (start <= end) return {start, end};
  }
  if (!samplings.empty() && samplings[0].max_num_samples > 0) take(samplings[0]);
  return {start, end};
}

void Archive::check_intact() const { d_->mapping.check_intact(); }

Object Archive::top() const { return Object(d_.get(), d_->top.get()); }

std::optional<Object> Archive::find(std::string_view full_name) const {
  if (full_name == "/") return top();
  for (const Object& o : objects()) {
    if (o.full_name() == full_name) return o;
  }
  return std::nullopt;
}

std::vector<Object> Archive::objects() const {
  std::vector<Object> out;
  collect(d_.get(), *d_->top, out, [](const ArchiveData* a, const ObjectNode* n) { return Object(a, n); });
  return out;
}

// ---- Object ---------------------------------------------------------------------------------

const std::string& Object::name() const { return node_->name; }
const std::string& Object::full_name() const { return node_->full_name; }
const MetaData& Object::metadata() const { return node_->stored->metadata; }
std::size_t Object::child_count() const { return node_->children.size(); }
Object Object::child(std::size_t i) const { return Object(archive_, node_->children.at(i).get()); }
Property Object::properties() const { return Property(archive_, node_->stored->properties.get()); }
bool Object::is_instance_root() const { return !node_->instance_source.empty(); }
bool Object::is_instance_descendant() const { return node_->instance_descendant; }
const std::string& Object::instance_source_path() const { return node_->instance_source; }
const std::string& Object::stored_full_name() const { return node_->stored->full_name; }

std::optional<Object> Object::parent() const {
  if (node_->parent == nullptr) return std::nullopt;
  return Object(archive_, node_->parent);
}

// ---- Property -------------------------------------------------------------------------------

const PropertyHeader& Property::header() const { return node_->header; }
const TimeSampling& Property::time_sampling() const {
  return archive_->time_samplings[node_->header.time_sampling_index];
}
std::size_t Property::child_count() const { return node_->children.size(); }
Property Property::child(std::size_t i) const { return Property(archive_, node_->children.at(i).get()); }

std::optional<Property> Property::find(std::string_view name) const {
  for (const auto& c : node_->children) {
    if (c->header.name == name) return Property(archive_, c.get());
  }
  return std::nullopt;
}

std::string_view property_kind_name(PropertyKind kind) {
  switch (kind) {
    case PropertyKind::Compound: return "compound";
    case PropertyKind::Scalar: return "scalar";
    case PropertyKind::Array: return "array";
  }
  return "?";
}

}  // namespace pstream::alembic
