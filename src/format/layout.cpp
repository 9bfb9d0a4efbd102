#include <cmath>

#include <fmt/format.h>

#include "particlestream/format.hpp"
#include "particlestream/frame.hpp"

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

std::uint64_t Metadata::stream_size() const {
  return frames.empty() ? 0 : frames.back().packet_offset + frames.back().packet_size;
}

std::uint64_t Metadata::decoded_size() const {
  return frames.empty() ? 0 : frames.back().byte_offset + frames.back().count * record_size;
}

std::uint64_t Metadata::total_particles() const {
  std::uint64_t n = 0;
  for (const FrameEntry& f : frames) n += f.count;
  return n;
}

std::uint64_t unbudgeted_memory_limit(const Metadata& meta) {
  const std::uint64_t stored = meta.stream_size();
  return std::max(kUnbudgetedMemoryFloor,
                  stored > UINT64_MAX / kMemoryPerStoredByte ? UINT64_MAX : stored * kMemoryPerStoredByte);
}

std::vector<std::byte> frame_buffer(const Metadata& meta, std::string_view name) {
  const std::uint64_t bytes = meta.max_count * meta.record_size;  // both bounded by the header's checks
  if (bytes > unbudgeted_memory_limit(meta)) {
    throw OptionError("budget", fmt::format("{}: max_count {} particles of {} bytes need {:.1f} MiB a frame, more "
                                            "than the clip's stored bytes justify ({:.1f} MiB)",
                                            name, meta.max_count, meta.record_size, bytes / 1048576.0,
                                            unbudgeted_memory_limit(meta) / 1048576.0));
  }
  return std::vector<std::byte>(bytes);
}

double Metadata::particles_per_chunk() const {
  const std::uint64_t stored = stream_size(), particles = total_particles();
  // Stored bytes per particle: the record size, or what the codec made of it.
  const double per_particle = stored && particles ? double(stored) / double(particles) : double(record_size);
  return double(chunk_size) / per_particle;
}

std::uint64_t Metadata::frame_at(double time) const {
  if (frames.empty()) return 0;
  const double f = std::round((time - time_of_frame0) * fps);
  if (!(f > 0.0)) return 0;  // also NaN
  return static_cast<std::uint64_t>(std::min(f, double(frames.size() - 1)));
}

std::pair<std::uint64_t, double> Metadata::frame_between(double time) const {
  if (frames.empty()) return {0, 0.0};
  const double q = (time - time_of_frame0) * fps;
  const double last = double(frames.size() - 1);
  if (!(q > 0.0)) return {0, 0.0};  // also NaN
  if (q >= last) return {frames.size() - 1, 0.0};
  double whole = std::floor(q);
  double fraction = q - whole;
  if (fraction > 1.0 - 1e-6) whole += 1.0, fraction = 0.0;
  if (fraction < 1e-6) fraction = 0.0;
  return {static_cast<std::uint64_t>(whole), fraction};
}

std::pair<std::uint64_t, std::uint64_t> Metadata::frame_chunks(std::uint64_t frame) const {
  const FrameEntry& f = frames[frame];
  const std::uint64_t last_chunk = chunks.empty() ? 0 : chunks.size() - 1;
  const std::uint64_t first = std::min(f.packet_offset / chunk_size, last_chunk);
  if (f.packet_size == 0) return {first, first};
  return {first, (f.packet_offset + f.packet_size - 1) / chunk_size};
}

std::uint64_t Metadata::chunk_raw_size(std::uint64_t chunk) const {
  const std::uint64_t begin = chunk * chunk_size;
  const std::uint64_t total = stream_size();
  return begin >= total ? 0 : std::min(chunk_size, total - begin);
}

const Attribute* find_attribute(const std::vector<Attribute>& layout, std::string_view name) {
  for (const Attribute& a : layout) {
    if (a.name == name) return &a;
  }
  return nullptr;
}

const Attribute* Metadata::find(std::string_view name) const { return find_attribute(layout, name); }

std::uint32_t record_size_of(const std::vector<Attribute>& layout) {
  std::uint32_t end = 0;
  for (const Attribute& a : layout) end = std::max<std::uint32_t>(end, a.offset + static_cast<std::uint32_t>(a.size()));
  return (end + 3u) & ~3u;
}

bool is_valid_name(std::string_view s) {
  if (s.empty()) return false;
  for (std::size_t i = 0; i < s.size();) {
    const auto c = static_cast<unsigned char>(s[i]);
    if (c < 0x20 || c == 0x7f) return false;
    if (c < 0x80) {
      ++i;
      continue;
    }
    const std::size_t n = c >= 0xf0 ? 4 : c >= 0xe0 ? 3 : c >= 0xc2 ? 2 : 0;
    if (n == 0 || c > 0xf4 || i + n > s.size()) return false;
    std::uint32_t cp = c & (0xff >> (n + 1));
    for (std::size_t k = 1; k < n; ++k) {
      const auto cc = static_cast<unsigned char>(s[i + k]);
      if ((cc & 0xc0) != 0x80) return false;
      cp = (cp << 6) | (cc & 0x3f);
    }
    const std::uint32_t least = n == 2 ? 0x80 : n == 3 ? 0x800 : 0x10000;
    if (cp < least || cp > 0x10ffff || (cp >= 0xd800 && cp <= 0xdfff) || (cp >= 0x80 && cp < 0xa0)) return false;
    i += n;
  }
  return true;
}

std::string escaped_name(std::string_view s) {
  std::string out;
  for (const char ch : s) {
    const auto c = static_cast<unsigned char>(ch);
    if (c >= 0x20 && c < 0x7f && c != '\\' && c != '"') {
      out += ch;
    } else {
      out += fmt::format("\\x{:02x}", c);
    }
  }
  return out;
}

std::uint32_t append_attribute(std::vector<Attribute>& layout, std::string name, AttributeType type,
                               std::uint8_t components) {
  if (name.empty() || name.size() >= kAttributeNameSize) {
    throw Error(
        fmt::format("attribute name \"{}\" must have 1 to {} bytes", escaped_name(name), kAttributeNameSize - 1));
  }
  if (!is_valid_name(name)) {
    throw Error(fmt::format("attribute name \"{}\" is not UTF-8 text without control characters", escaped_name(name)));
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
  return {{"position", AttributeType::Float32, 3, render::kPositionOffset},
          {"scale", AttributeType::Float32, 1, render::kScaleOffset}};
}

}  // namespace pstream::format
