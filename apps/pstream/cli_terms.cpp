#include "cli_terms.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <vector>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "particlestream/error.hpp"

namespace pstream::app {

CLI::Validator positive_number_up_to(double max) {
  return CLI::Validator(
      [max](std::string& value) -> std::string {
        double v = 0;
        const auto [ptr, ec] = std::from_chars(value.data(), value.data() + value.size(), v);
        if (ec != std::errc() || ptr != value.data() + value.size() || !std::isfinite(v) || !(v > 0)) {
          return fmt::format("'{}' is not a positive number", value);
        }
        if (v > max) return fmt::format("{} is more than {:g}", value, max);
        return {};
      },
      fmt::format("POSITIVE (up to {:g})", max));
}

CLI::Validator one_of(std::initializer_list<std::string_view> names) {
  std::vector<std::string> list(names.begin(), names.end());
  return CLI::Validator(
      [list](std::string& value) -> std::string {
        if (std::find(list.begin(), list.end(), value) != list.end()) return {};
        const std::vector<std::string_view> views(list.begin(), list.end());
        return fmt::format("'{}' is not one of {}{}", value, fmt::join(list, ", "), did_you_mean(value, views));
      },
      fmt::format("{{{}}}", fmt::join(list, ",")));
}

CLI::Validator positive_number() {
  return CLI::Validator(
      [](std::string& value) -> std::string {
        double v = 0;
        const auto [ptr, ec] = std::from_chars(value.data(), value.data() + value.size(), v);
        if (ec != std::errc() || ptr != value.data() + value.size() || !std::isfinite(v) || !(v > 0)) {
          return fmt::format("'{}' is not a positive number", value);
        }
        return {};
      },
      "POSITIVE");
}

std::string count_of(std::uint64_t n, std::string_view singular, std::string_view plural) {
  if (n == 1) return fmt::format("1 {}", singular);
  return plural.empty() ? fmt::format("{} {}s", n, singular) : fmt::format("{} {}", n, plural);
}

std::string in_cli_terms(std::string message) {
  static const std::pair<const char*, const char*> flags[] = {
      {"`frame_begin`:`frame_end`", "--frames"},
      {"`drop_invalid`", "--drop-invalid"},
      {"`keep_source_order`", "--keep-order"},
      {"`max_particles`", "--max-particles"},
      {"`max_frames`", "--max-frames"},
      {"`chunk_size`", "--chunk-size"},
      {"`codec`", "--codec"},
      {"`color_from`", "--color-from"},
      {"`scale_from`", "--scale-from"},
      {"`attributes`", "--attributes"},
      {"`interpolate`", "--interpolate"},
      {"`object`", "--object"},
      {"`merge`", "--merge"},
      {"`fps`", "--fps"},
      {"`seconds`", "--seconds"},
      {"`particles`", "--particles"},
      {"`ramp_attribute`", "--ramp-attribute"},
      {"`budget`", "a memory budget (the library's StreamOptions::budget)"},
  };
  for (const auto& [name, flag] : flags) {
    for (auto at = message.find(name); at != std::string::npos; at = message.find(name, at)) {
      message.replace(at, std::string_view(name).size(), flag);
      at += std::string_view(flag).size();
    }
  }
  return message;
}

std::string human_bytes(double bytes) {
  const char* units[] = {"B", "KiB", "MiB", "GiB", "TiB"};
  int u = 0;
  while (bytes >= 1024.0 && u < 4) {
    bytes /= 1024.0;
    ++u;
  }
  return u == 0 ? fmt::format("{:.0f} {}", bytes, units[u]) : fmt::format("{:.1f} {}", bytes, units[u]);
}

}  // namespace pstream::app
