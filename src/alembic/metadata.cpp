#include <string>

#include "particlestream/alembic.hpp"

namespace pstream::alembic {

MetaData MetaData::parse(std::string_view serialized) {
  MetaData md;
  while (!serialized.empty()) {
    const auto end = serialized.find(';');
    const std::string_view token = serialized.substr(0, end);
    const auto eq = token.find('=');
    if (eq != std::string_view::npos) md.entries_[std::string(token.substr(0, eq))] = std::string(token.substr(eq + 1));
    if (end == std::string_view::npos) break;
    serialized.remove_prefix(end + 1);
  }
  return md;
}

std::string MetaData::get(std::string_view key) const {
  const auto it = entries_.find(key);
  return it == entries_.end() ? std::string() : it->second;
}

bool MetaData::has(std::string_view key) const { return entries_.find(key) != entries_.end(); }

std::string MetaData::serialize() const {
  std::string out;
  for (const auto& [key, value] : entries_) {
    if (!out.empty()) out += ';';
    out += key;
    out += '=';
    out += value;
  }
  return out;
}

}  // namespace pstream::alembic
