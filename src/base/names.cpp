#include "base/names.hpp"

#include <charconv>

#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

#include <fmt/format.h>

#include "particlestream/error.hpp"

namespace pstream {
namespace {

// Edit distance with adjacent transpositions (the optimal string alignment distance): two
// letters typed the wrong way round, the commonest typo, cost 1 as one wrong letter does.
std::size_t edit_distance(std::string_view a, std::string_view b) {
  std::vector<std::size_t> before(b.size() + 1), previous(b.size() + 1), row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) previous[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      row[j] = std::min({previous[j] + 1, row[j - 1] + 1, previous[j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1)});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1]) row[j] = std::min(row[j], before[j - 2] + 1);
    }
    std::swap(before, previous);
    std::swap(previous, row);
  }
  return previous[b.size()];
}

}  // namespace

std::string closest_name(std::string_view word, std::span<const std::string_view> names) {
  std::string_view best;
  std::size_t best_distance = SIZE_MAX;
  for (const std::string_view n : names) {
    const std::size_t d = edit_distance(word, n);
    if (d < best_distance) best_distance = d, best = n;
  }
  return best_distance <= std::max<std::size_t>(1, word.size() / 3) ? std::string(best) : std::string();
}

std::string did_you_mean(std::string_view word, std::span<const std::string_view> names) {
  const std::string guess = closest_name(word, names);
  return guess.empty() ? std::string() : fmt::format(" (did you mean '{}'?)", guess);
}

std::string did_you_mean(std::string_view word, std::initializer_list<std::string_view> names) {
  return did_you_mean(word, std::span(names.begin(), names.size()));
}

std::pair<std::int64_t, std::int64_t> parse_frame_range(std::string_view text, std::string_view flag) {
  const auto colon = text.find(':');
  const auto number = [&](std::string_view part, std::int64_t open) {
    if (part.empty() && colon != std::string_view::npos) return open;
    std::int64_t v = 0;
    const auto [ptr, ec] = std::from_chars(part.data(), part.data() + part.size(), v);
    if (ec != std::errc() || ptr != part.data() + part.size() || v < 0 || v == INT64_MAX) {
      const bool dash = colon == std::string_view::npos && text.find('-') != std::string_view::npos;
      throw Error(
          fmt::format("{} '{}': expected A:B, frame numbers from 0 (A:B is from A up to but not including B; "
                      "either may be left out), or N for frame N alone{}",
                      flag, text, dash ? " (a range takes a colon, not a dash)" : ""));
    }
    return v;
  };
  if (colon == std::string_view::npos) {
    const std::int64_t frame = number(text, 0);
    return {frame, frame + 1};
  }
  return {number(text.substr(0, colon), 0), number(text.substr(colon + 1), -1)};
}

}  // namespace pstream
