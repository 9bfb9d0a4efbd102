// What the command line adds to the library: its own spelling of values (frame ranges, numbers
// checked with a message that says what is wanted) and of settings (flags instead of the
// library's option names in error messages).
#pragma once

#include <cstdint>
#include <string>
#include <utility>

#include <CLI/CLI.hpp>

#include "base/names.hpp"

namespace pstream::app {

// "A:B" frame ranges: the library's rule (base/names.hpp).
using pstream::parse_frame_range;

// A CLI11 check: a finite number > 0 (CLI11's PositiveNumber accepts nan and prints a range of
// 300 digits).
CLI::Validator positive_number();
// A finite number > 0, at most `max`.
CLI::Validator positive_number_up_to(double max);
// One of `names`, exactly; anything else is refused with the list and the nearest name ("'spark'
// is not one of sprites, smoke, sparks (did you mean 'sparks'?)").
CLI::Validator one_of(std::initializer_list<std::string_view> names);

// "512 B", "3.4 KiB", "9.2 MiB", "3.1 GiB".
std::string human_bytes(double bytes);

// "1 chunk", "2 chunks" (`plural` when it is not singular + "s").
std::string count_of(std::uint64_t n, std::string_view singular, std::string_view plural = {});

// A library message in the command line's terms: each `option` name is replaced by its flag
// (`drop_invalid` -> --drop-invalid).
std::string in_cli_terms(std::string message);

}  // namespace pstream::app
