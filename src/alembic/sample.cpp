// Reading one sample of a scalar or array property out of the mapping.
#include <algorithm>
#include <cmath>
#include <cstring>

#include <fmt/format.h>

#include "alembic/archive_data.hpp"
#include "alembic/layout.hpp"

namespace pstream::alembic {
namespace {

constexpr std::size_t kKeyBytes = layout::kSampleKeyBytes;

float half_to_float(std::uint16_t h) {
  const std::uint32_t sign = (h >> 15) & 1u, exp = (h >> 10) & 0x1fu, mant = h & 0x3ffu;
  float v;
  if (exp == 0) {
    v = std::ldexp(static_cast<float>(mant), -24);
  } else if (exp == 31) {
    v = mant ? std::numeric_limits<float>::quiet_NaN() : std::numeric_limits<float>::infinity();
  } else {
    v = std::ldexp(static_cast<float>(mant | 0x400u), static_cast<int>(exp) - 25);
  }
  return sign ? -v : v;
}

template <class T>
T at(std::span<const std::byte> bytes, std::uint64_t i) {
  return ogawa::load_le<T>(bytes.data() + i * sizeof(T));
}

bool multiply_overflows(std::uint64_t a, std::uint64_t b, std::uint64_t& out) {
  return __builtin_mul_overflow(a, b, &out);
}

}  // namespace

std::size_t pod_size(Pod pod) {
  switch (pod) {
    case Pod::Bool:
    case Pod::Uint8:
    case Pod::Int8:
    case Pod::String: return 1;
    case Pod::Uint16:
    case Pod::Int16:
    case Pod::Float16: return 2;
    case Pod::Uint32:
    case Pod::Int32:
    case Pod::Float32:
    case Pod::WString: return 4;
    case Pod::Uint64:
    case Pod::Int64:
    case Pod::Float64: return 8;
  }
  return 1;
}

std::string_view pod_name(Pod pod) {
  static constexpr std::string_view names[] = {"bool",   "uint8", "int8",    "uint16",  "int16",   "uint32", "int32",
                                               "uint64", "int64", "float16", "float32", "float64", "string", "wstring"};
  return names[static_cast<std::size_t>(pod)];
}

bool pod_is_float(Pod pod) { return pod == Pod::Float16 || pod == Pod::Float32 || pod == Pod::Float64; }
bool pod_is_integer(Pod pod) { return !pod_is_float(pod) && pod != Pod::String && pod != Pod::WString; }

std::uint32_t PropertyHeader::stored_index(std::uint32_t index) const {
  if (index < first_changed || (first_changed == 0 && last_changed == 0)) return 0;
  if (index >= last_changed) return last_changed - first_changed + 1;
  return index - first_changed + 1;
}

std::size_t SampleView::copy_raw(std::span<std::byte> out) const {
  if (out.size() < bytes_.size()) {
    throw Error(fmt::format("buffer of {} bytes is too small for a sample of {} bytes", out.size(), bytes_.size()));
  }
  if (!bytes_.empty()) std::memcpy(out.data(), bytes_.data(), bytes_.size());
  return static_cast<std::size_t>(scalar_count());
}

double SampleView::value_f64(std::uint64_t i) const {
  switch (pod_) {
    case Pod::Float16: return half_to_float(at<std::uint16_t>(bytes_, i));
    case Pod::Float32: return at<float>(bytes_, i);
    case Pod::Float64: return at<double>(bytes_, i);
    case Pod::Uint64: return static_cast<double>(value_u64(i));
    default: return static_cast<double>(value_i64(i));
  }
}

std::int64_t SampleView::value_i64(std::uint64_t i) const {
  switch (pod_) {
    case Pod::Bool: return at<std::uint8_t>(bytes_, i) != 0;
    case Pod::Uint8: return at<std::uint8_t>(bytes_, i);
    case Pod::Int8: return at<std::int8_t>(bytes_, i);
    case Pod::Uint16: return at<std::uint16_t>(bytes_, i);
    case Pod::Int16: return at<std::int16_t>(bytes_, i);
    case Pod::Uint32: return at<std::uint32_t>(bytes_, i);
    case Pod::Int32: return at<std::int32_t>(bytes_, i);
    case Pod::Uint64: return static_cast<std::int64_t>(at<std::uint64_t>(bytes_, i));
    case Pod::Int64: return at<std::int64_t>(bytes_, i);
    case Pod::Float16:
    case Pod::Float32:
    case Pod::Float64: return static_cast<std::int64_t>(value_f64(i));
    case Pod::String:
    case Pod::WString: return 0;
  }
  return 0;
}

std::uint64_t SampleView::value_u64(std::uint64_t i) const {
  return pod_ == Pod::Uint64 ? at<std::uint64_t>(bytes_, i) : static_cast<std::uint64_t>(value_i64(i));
}

namespace {

void append_utf8(std::string& out, std::uint32_t cp) {
  if (cp < 0x80) {
    out.push_back(static_cast<char>(cp));
  } else if (cp < 0x800) {
    out.push_back(static_cast<char>(0xC0 | (cp >> 6)));
    out.push_back(static_cast<char>(0x80 | (cp & 0x3F)));
  } else if (cp < 0x10000) {
    out.push_back(static_cast<char>(0xE0 | (cp >> 12)));
    out.push_back(static_cast<char>(0x80 | ((cp >> 6) & 0x3F)));
    out.push_back(static_cast<char>(0x80 | (cp & 0x3F)));
  } else {
    out.push_back(static_cast<char>(0xF0 | (cp >> 18)));
    out.push_back(static_cast<char>(0x80 | ((cp >> 12) & 0x3F)));
    out.push_back(static_cast<char>(0x80 | ((cp >> 6) & 0x3F)));
    out.push_back(static_cast<char>(0x80 | (cp & 0x3F)));
  }
}

}  // namespace

std::vector<std::string> SampleView::strings() const {
  if (pod_ != Pod::String && pod_ != Pod::WString)
    throw Error(fmt::format("a {} sample holds no strings", pod_name(pod_)));
  const std::uint64_t wanted = scalar_count();
  std::vector<std::string> out;
  out.reserve(static_cast<std::size_t>(std::min<std::uint64_t>(wanted, bytes_.size())));
  std::string current;
  if (pod_ == Pod::String) {
    for (std::byte b : bytes_) {
      if (out.size() == wanted) break;
      if (b == std::byte{0}) {
        out.push_back(std::move(current));
        current.clear();
      } else {
        current.push_back(static_cast<char>(b));
      }
    }
  } else {
    for (std::size_t i = 0; i + 4 <= bytes_.size() && out.size() < wanted; i += 4) {
      std::uint32_t cp = 0;
      std::memcpy(&cp, bytes_.data() + i, 4);
      if (cp == 0) {
        out.push_back(std::move(current));
        current.clear();
      } else if (cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) {
        throw Error(fmt::format("wstring element {} holds U+{:X}, not a Unicode code point", out.size(), cp));
      } else {
        append_utf8(current, cp);
      }
    }
  }
  if (out.size() != wanted) {
    throw Error(
        fmt::format("a {} sample of {} elements holds only {} terminated strings", pod_name(pod_), wanted, out.size()));
  }
  return out;
}

SampleView Property::sample(std::uint32_t index) const {
  const PropertyHeader& h = node_->header;
  const ogawa::File& file = archive_->file;
  if (h.kind == PropertyKind::Compound)
    throw Error(fmt::format("{}: property '{}' is a compound, it has no samples", file.name(), h.name));
  if (index >= h.num_samples) {
    throw Error(fmt::format("{}: property '{}' has {} samples, sample {} was asked for", file.name(), h.name,
                            h.num_samples, index));
  }
  const std::uint32_t stored = h.stored_index(index);
  if (stored >= node_->stored_count) {
    file.fail(node_->group.offset, fmt::format("property '{}' sample {} maps to stored sample {} but {} are stored",
                                               h.name, index, stored, node_->stored_count));
  }
  const std::uint64_t elem_bytes = pod_size(h.pod) * h.extent;
  const bool is_text = h.pod == Pod::String || h.pod == Pod::WString;

  if (h.kind == PropertyKind::Scalar) {
    const ogawa::Data data = file.child_data(node_->group, stored);
    if (data.size < kKeyBytes) {
      file.fail(data.offset, fmt::format("scalar sample of '{}' has {} bytes, expected a 16-byte key and values",
                                         h.name, data.size));
    }
    const auto values = file.payload(data).subspan(kKeyBytes);
    if (!is_text && values.size() != elem_bytes) {
      file.fail(data.offset, fmt::format("scalar sample of '{}' has {} value bytes, expected {} ({} x {})", h.name,
                                         values.size(), elem_bytes, pod_name(h.pod), int(h.extent)));
    }
    return SampleView(h.pod, h.extent, 1, values);
  }

  const ogawa::Data data = file.child_data(node_->group, 2ull * stored);
  const ogawa::Data dims = file.child_data(node_->group, 2ull * stored + 1);
  if (data.size == 0) return SampleView(h.pod, h.extent, 0, {});
  if (data.size < kKeyBytes) {
    file.fail(data.offset,
              fmt::format("array sample of '{}' has {} bytes, expected a 16-byte key and values", h.name, data.size));
  }
  const auto values = file.payload(data).subspan(kKeyBytes);
  std::uint64_t count = 0;
  if (dims.size == 0) {
    if (values.size() % elem_bytes != 0) {
      file.fail(data.offset, fmt::format("array sample of '{}' has {} value bytes, not a multiple of {} ({} x {})",
                                         h.name, values.size(), elem_bytes, pod_name(h.pod), int(h.extent)));
    }
    count = values.size() / elem_bytes;
  } else {
    if (dims.size % 8 != 0)
      file.fail(dims.offset,
                fmt::format("dimensions of '{}' take {} bytes, expected a multiple of 8", h.name, dims.size));
    count = 1;
    for (std::uint64_t r = 0; r < dims.size / 8; ++r) {
      const std::uint64_t d = file.read_u64(dims.offset + r * 8, "array dimension");
      if (multiply_overflows(count, d, count))
        file.fail(dims.offset, fmt::format("dimensions of '{}' overflow", h.name));
    }
    std::uint64_t expected = 0;
    if (!is_text && (multiply_overflows(count, elem_bytes, expected) || expected != values.size())) {
      file.fail(data.offset,
                fmt::format("array sample of '{}' has {} value bytes but its dimensions say {} elements of {} bytes",
                            h.name, values.size(), count, elem_bytes));
    }
  }
  if (is_text && dims.size == 0) {  // no dimensions: as many strings as terminators
    count = 0;
    const std::size_t unit = pod_size(h.pod);
    for (std::size_t i = 0; i + unit <= values.size(); i += unit) {
      bool zero = true;
      for (std::size_t b = 0; b < unit; ++b) zero = zero && values[i + b] == std::byte{0};
      count += zero ? 1 : 0;
    }
    count /= std::max<std::uint64_t>(h.extent, 1);
  }
  if (is_text && count * std::max<std::uint64_t>(h.extent, 1) > values.size() / pod_size(h.pod)) {
    file.fail(data.offset,
              fmt::format("string array '{}' claims {} strings but has only {} bytes", h.name, count, values.size()));
  }
  return SampleView(h.pod, h.extent, count, values);
}

std::pair<SampleView, std::uint32_t> Property::sample_at(double time) const {
  const auto index = static_cast<std::uint32_t>(time_sampling().near_index(time, header().num_samples).first);
  return {sample(index), index};
}

}  // namespace pstream::alembic
