// Counts every operator new of the test process (tests/alloc_counter.cpp replaces it), so a test
// can prove a code path allocates nothing.
#pragma once

#include <atomic>
#include <cstdint>

namespace pstream::test {

std::uint64_t allocation_count();

}  // namespace pstream::test
