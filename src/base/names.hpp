// "Did you mean": the one rule every front end and parser uses for a mistyped name.
#pragma once

#include <initializer_list>
#include <span>
#include <string>
#include <string_view>

namespace pstream {

// The closest of `names` to `word` when it is near enough to be a typo of it (an edit distance of
// at most a third of the word's length, and at least 1); empty otherwise.
std::string closest_name(std::string_view word, std::span<const std::string_view> names);
// " (did you mean 'X'?)" for a message, or "" when nothing is close.
std::string did_you_mean(std::string_view word, std::initializer_list<std::string_view> names);

}  // namespace pstream
