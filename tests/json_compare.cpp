#include "json_compare.hpp"

#include <algorithm>
#include <cmath>

namespace pstream::test {
namespace {

struct Comparer {
  const JsonCompareOptions& options;
  std::vector<std::string> diffs;

  void add(const std::string& path, const nlohmann::json& e, const nlohmann::json& a) {
    if (diffs.size() < options.max_differences) diffs.push_back(path + ": expected " + e.dump() + ", got " + a.dump());
  }

  bool numbers_match(const nlohmann::json& e, const nlohmann::json& a) const {
    if (e.is_number_integer() && a.is_number_integer()) {
      if (e.is_number_unsigned() && a.is_number_unsigned()) return e.get<std::uint64_t>() == a.get<std::uint64_t>();
      return e.get<std::int64_t>() == a.get<std::int64_t>();
    }
    const double x = e.get<double>(), y = a.get<double>();
    if (x == y) return true;
    const double diff = std::abs(x - y);
    return diff <= options.absolute_tolerance ||
           diff <= options.relative_tolerance * std::max(std::abs(x), std::abs(y));
  }

  void walk(const std::string& path, const nlohmann::json& e, const nlohmann::json& a) {
    if (std::find(options.ignore_keys.begin(), options.ignore_keys.end(), path) != options.ignore_keys.end()) return;
    if (e.is_number() && a.is_number()) {
      if (!numbers_match(e, a)) add(path, e, a);
      return;
    }
    if (e.type() != a.type()) return add(path, e, a);
    if (e.is_object()) {
      for (const auto& [key, value] : e.items()) {
        if (!a.contains(key)) {
          add(path + "/" + key, value, nullptr);
          continue;
        }
        walk(path + "/" + key, value, a.at(key));
      }
      for (const auto& [key, value] : a.items()) {
        if (!e.contains(key)) add(path + "/" + key + " (unexpected key)", nullptr, value);
      }
    } else if (e.is_array()) {
      if (e.size() != a.size()) {
        add(path + " (array length)", e.size(), a.size());
        return;
      }
      for (std::size_t i = 0; i < e.size(); ++i) walk(path + "/" + std::to_string(i), e[i], a[i]);
    } else if (e != a) {
      add(path, e, a);
    }
  }
};

}  // namespace

std::vector<std::string> compare_json(const nlohmann::json& expected, const nlohmann::json& actual,
                                      const JsonCompareOptions& options) {
  Comparer c{options, {}};
  c.walk("", expected, actual);
  return c.diffs;
}

}  // namespace pstream::test
