// The comparator is itself under test: a comparison that accepts everything would prove nothing.
#include <gtest/gtest.h>

#include <algorithm>

#include "json_compare.hpp"

using nlohmann::json;
using pstream::test::compare_json;

TEST(JsonCompare, AcceptsEqualDocumentsAndTinyFloatDifferences) {
  const json e = json::parse(R"({"a": 1, "b": [1.0, 2.5, "x"], "c": {"d": null, "e": true}, "z": 0})");
  const json a = json::parse(R"({"a": 1, "b": [1.0000000000001, 2.5, "x"], "c": {"d": null, "e": true}, "z": -1e-17})");
  EXPECT_TRUE(compare_json(e, a).empty());
}

TEST(JsonCompare, FindsEveryKindOfDifference) {
  const json e = json::parse(R"({"int": 8589934592, "f": 1.0, "s": "x", "arr": [1, 2], "missing": 1, "n": null})");
  const json a = json::parse(R"({"int": 8589934593, "f": 1.00001, "s": "y", "arr": [1], "extra": 2, "n": 0})");
  const auto diffs = compare_json(e, a);
  ASSERT_EQ(diffs.size(), 7u);
  for (const char* path : {"/int", "/f", "/s", "/arr", "/missing", "/extra", "/n"}) {
    EXPECT_TRUE(std::any_of(diffs.begin(), diffs.end(), [&](const std::string& d) { return d.rfind(path, 0) == 0; }))
        << path;
  }
}

TEST(JsonCompare, IgnoresOnlyTheNamedPaths) {
  const json e = json::parse(R"({"reader": "official", "x": {"reader": "a"}})");
  const json a = json::parse(R"({"reader": "ours", "x": {"reader": "b"}})");
  const auto diffs = compare_json(e, a, {.ignore_keys = {"/reader"}});
  ASSERT_EQ(diffs.size(), 1u);
  EXPECT_NE(diffs[0].find("/x/reader"), std::string::npos);
}
