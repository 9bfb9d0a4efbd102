// The particle codec's word codings as small types (codec.hpp, "The registry"): each one's name,
// what it stores and promises, and the rule a clip's word table must keep for it
// (docs/format.md, "Word codings").
#include <bit>
#include <cmath>

#include <fmt/format.h>

#include "particlestream/codec.hpp"

namespace pstream::format {
namespace {

bool is_float(const Attribute& a) { return a.type == AttributeType::Float32; }

std::string check_quantized(const Metadata&, const Attribute& a, std::uint32_t w, const WordCodingEntry& e) {
  const float origin = std::bit_cast<float>(e.base);
  if (is_float(a) && e.step > 0.0f && std::isfinite(e.step) && std::isfinite(origin) && e.error >= 0.0f &&
      std::isfinite(e.error))
    return {};
  return fmt::format(
      "record word {} ('{}'): a quantised word needs a float32 attribute, a finite step > 0 and a finite origin "
      "(step {}, origin {}, error {})",
      w, a.name, e.step, origin, e.error);
}

std::string check_any(const Metadata&, const Attribute&, std::uint32_t, const WordCodingEntry&) { return {}; }

std::string check_id(const Metadata& m, const Attribute& a, std::uint32_t w, const WordCodingEntry&) {
  if (a.name == "id" && a.type == AttributeType::Uint64 && m.codec.order == FrameOrder::Id) return {};
  return fmt::format(
      "record word {} ('{}'): the id coding is for the two words of the uint64 'id' attribute of a clip ordered by "
      "id",
      w, a.name);
}

std::string check_relative(const Metadata& m, const Attribute& a, std::uint32_t w, const WordCodingEntry& e) {
  if (is_float(a) && m.version >= 3 && e.base >= 1 && e.base <= 23 && e.error > 0.0f && e.error < 1.0f) return {};
  return fmt::format(
      "record word {} ('{}'): a relative word needs a float32 attribute, format version 3, a shift of 1 to 23 and "
      "a bound in (0, 1) (shift {}, bound {})",
      w, a.name, e.base, e.error);
}

std::string check_derived(const Metadata& m, const Attribute& a, std::uint32_t w, const WordCodingEntry& e) {
  const Attribute* position = m.find("position");
  const bool from_position = position != nullptr && e.base >= position->offset / 4 &&
                             e.base < (position->offset + position->size()) / 4 &&
                             m.codec.words[e.base].coding == WordCoding::Quantized;
  if (a.name == "velocity" && is_float(a) && a.components == 3 && m.version >= 3 && from_position && e.step > 0.0f &&
      std::isfinite(e.step))
    return {};
  return fmt::format(
      "record word {} ('{}'): a derived word needs the float32x3 'velocity' attribute, format version 3, a "
      "quantised position word to derive from and a finite step > 0 (from word {}, step {})",
      w, a.name, e.base, e.step);
}

// Indexed by the coding's value.
constexpr WordCodingType kCodings[] = {
    {"quantized", check_quantized, WordCoding::Quantized, true, true, false},
    {"exact", check_any, WordCoding::Exact, true, false, false},
    {"constant", check_any, WordCoding::Constant, false, false, false},
    {"id", check_id, WordCoding::Id, false, false, false},
    {"relative", check_relative, WordCoding::Relative, true, true, true},
    {"derived", check_derived, WordCoding::Derived, false, false, false},
};

}  // namespace

const WordCodingType* find_word_coding(WordCoding id) {
  const auto i = static_cast<std::size_t>(id);
  return i < std::size(kCodings) ? &kCodings[i] : nullptr;
}

}  // namespace pstream::format
