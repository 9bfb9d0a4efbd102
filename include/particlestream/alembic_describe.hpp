// An archive described as a JSON document of the schema "alembic-fixture-expected/1", the one the
// reference fixtures' expected files use (tests/data/alembic/README.md). Comparing this with what
// the official Alembic library reports for the same file checks every value we read.
#pragma once

#include <cstdint>
#include <limits>
#include <string>

#include "particlestream/alembic.hpp"

namespace pstream::alembic {

struct DescribeOptions {
  int indent = 1;                                                         // -1: one line
  std::uint32_t max_samples = std::numeric_limits<std::uint32_t>::max();  // per object (fuzzing)
};

std::string describe_json(const Archive& archive, const DescribeOptions& options = {});

}  // namespace pstream::alembic
