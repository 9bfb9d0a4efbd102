// Generic comparison of two JSON documents: same keys, same array lengths, strings, booleans and
// integers equal, other numbers equal to a relative tolerance.
#pragma once

#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace pstream::test {

struct JsonCompareOptions {
  double relative_tolerance = 1e-9;
  double absolute_tolerance = 1e-12;     // for values that are zero in one document (rotations)
  std::vector<std::string> ignore_keys;  // paths such as "/reader"
  std::size_t max_differences = 20;
};

// Returns the differences found, each "path: expected X, got Y"; empty when the documents match.
std::vector<std::string> compare_json(const nlohmann::json& expected, const nlohmann::json& actual,
                                      const JsonCompareOptions& options = {});

}  // namespace pstream::test
