// How users spell things, one rule for every front end (CLI, C API, Python): "did you mean" for a
// mistyped name, and frame ranges.
#pragma once

#include <cstdint>
#include <initializer_list>
#include <span>
#include <string>
#include <string_view>
#include <utility>

namespace pstream {

// The closest of `names` to `word` when it is near enough to be a typo of it (an edit distance of
// at most a third of the word's length, and at least 1); empty otherwise.
std::string closest_name(std::string_view word, std::span<const std::string_view> names);
// " (did you mean 'X'?)" for a message, or "" when nothing is close.
std::string did_you_mean(std::string_view word, std::span<const std::string_view> names);
std::string did_you_mean(std::string_view word, std::initializer_list<std::string_view> names);

// "A:B", "A:" or ":B" -> {A, B} (from A up to but not including B); B is -1 when left open.
// "N" -> {N, N + 1}, frame N alone.
// Throws pstream::Error naming `what` (the flag or argument).
std::pair<std::int64_t, std::int64_t> parse_frame_range(std::string_view text, std::string_view what = "--frames");

}  // namespace pstream
