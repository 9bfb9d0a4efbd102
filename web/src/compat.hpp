// Included first in every browser-build source (scripts/build-web.sh): what Debian's Emscripten
// 3.1.6 libc++ lacks from C++20 and the shared sources use.
#pragma once

#include <bit>
#include <cstring>
#include <type_traits>

#ifndef __cpp_lib_bit_cast
namespace std {
template <class To, class From>
requires(sizeof(To) == sizeof(From) && is_trivially_copyable_v<To> && is_trivially_copyable_v<From>) To
    bit_cast(const From& from)
noexcept { return __builtin_bit_cast(To, from); }
}  // namespace std
#endif
