// Every Ogawa fixture, written by the official Alembic 1.8.12 library, must read back with
// exactly the values the official reader reported for it (tests/data/alembic/*.expected.json).
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "json_compare.hpp"
#include "particlestream/alembic.hpp"
#include "particlestream/alembic_describe.hpp"
#include "test_util.hpp"

namespace {

using namespace pstream;
using nlohmann::json;

const char* const kOgawaFixtures[] = {"points_constant",
                                      "points_varying",
                                      "points_xform",
                                      "points_multi",
                                      "points_empty_frames",
                                      "points_large",
                                      "points_widths_constant",
                                      "mesh_vertices",
                                      "strings_attributes",
                                      "instancing",
                                      "no_samples",
                                      "times_default_only",
                                      "times_default_plus_animated",
                                      "times_singles_only",
                                      "times_animated_plus_single"};

std::string report(const std::vector<std::string>& diffs) {
  std::string s;
  for (const auto& d : diffs) s += "  " + d + "\n";
  return s;
}

class OgawaFixture : public ::testing::TestWithParam<const char*> {};

TEST_P(OgawaFixture, LibraryDescriptionEqualsOfficialReader) {
  const std::string name = GetParam();
  const json expected = json::parse(test::read_text(test::data_path("alembic/" + name + ".expected.json")));
  const auto archive = alembic::Archive::open(test::data_path("alembic/" + name + ".abc"));
  const json actual = json::parse(alembic::describe_json(archive));
  const auto diffs = test::compare_json(expected, actual, {.ignore_keys = {"/reader"}});
  EXPECT_TRUE(diffs.empty()) << name << " differs from the official reader:\n" << report(diffs);
  // Guard against a vacuous pass: the documents hold real content (the times_* archives hold
  // only time samplings, which is what they test).
  if (name.starts_with("times_")) {
    EXPECT_LT(expected.at("archive").at("start_time").get<double>(),
              expected.at("archive").at("end_time").get<double>());
    EXPECT_EQ(actual.at("archive").at("start_time"), expected.at("archive").at("start_time"));
    EXPECT_EQ(actual.at("archive").at("end_time"), expected.at("archive").at("end_time"));
  } else {
    EXPECT_GT(expected.at("objects").size(), 0u);
  }
}

TEST_P(OgawaFixture, CommandLineJsonEqualsOfficialReader) {
  const std::string name = GetParam();
  const auto result = test::run_cli("info '" + test::data_path("alembic/" + name + ".abc") + "' --json");
  ASSERT_EQ(result.exit_code, 0) << result.output;
  const json expected = json::parse(test::read_text(test::data_path("alembic/" + name + ".expected.json")));
  const auto diffs = test::compare_json(expected, json::parse(result.output), {.ignore_keys = {"/reader"}});
  EXPECT_TRUE(diffs.empty()) << report(diffs);
}

INSTANTIATE_TEST_SUITE_P(Alembic, OgawaFixture, ::testing::ValuesIn(kOgawaFixtures));

TEST(OgawaFixtureText, InfoSummarisesPointsObjects) {
  const auto result = test::run_cli("info '" + test::data_path("alembic/points_varying.abc") + "'");
  ASSERT_EQ(result.exit_code, 0) << result.output;
  EXPECT_NE(result.output.find("/particles"), std::string::npos);
  EXPECT_NE(result.output.find("60 samples"), std::string::npos);
  EXPECT_NE(result.output.find("min 0 / avg"), std::string::npos);
  EXPECT_NE(result.output.find("max 725"), std::string::npos);
  EXPECT_NE(result.output.find("Cd"), std::string::npos);
  EXPECT_NE(result.output.find("uniform, 0.0333333 s per sample (30 fps)"), std::string::npos) << result.output;
}

TEST(OgawaFixtureText, InfoSummarisesMeshesWhoseVerticesCook) {
  const auto result = test::run_cli("info '" + test::data_path("alembic/mesh_vertices.abc") + "'");
  ASSERT_EQ(result.exit_code, 0) << result.output;
  EXPECT_NE(result.output.find("/grid  [AbcGeom_PolyMesh_v1]\n"
                               "    24 samples, 0.0416667 s .. 1 s (time sampling 1)\n"
                               "    vertices per sample: min 400 / avg 400.0 / max 400\n"
                               "    attributes (its vertices cook as particles):\n"),
            std::string::npos)
      << result.output;
}

}  // namespace
