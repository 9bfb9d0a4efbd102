// The command line a user types: typos get "did you mean" (issue #27's first CLI item).
#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "test_util.hpp"

namespace {

using pstream::test::run_cli;

void expect_suggestion(const std::string& args, const std::string& message) {
  const auto r = run_cli(args);
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find(message), std::string::npos) << "expected '" << message << "' in:\n" << r.output;
}

TEST(Cli, TyposGetDidYouMean) {
  expect_suggestion("rendr x.pstream", "unknown command `rendr`; did you mean `render`?");
  expect_suggestion("bench strem", "unknown command `strem`; did you mean `stream`?");
  expect_suggestion("cook --codc particle x.abc", "unknown option --codc; did you mean --codec?");
  expect_suggestion("render x.pstream --presett smoke", "unknown option --presett; did you mean --preset?");
  expect_suggestion("cook --helpp", "did you mean --help?");
  // Far from every name: said plainly, with where to look.
  expect_suggestion("cook x.abc --zzzzzzzz", "unknown option --zzzzzzzz for `cook` (see its --help)");
  // Choices the library parses: its message, with the nearest choice.
  const std::string abc = pstream::test::data_path("alembic/points_constant.abc");
  const auto codec = run_cli("cook '" + abc + "' -o /nonexistent/dir/x.pstream --codec partcle");
  EXPECT_NE(codec.output.find("--codec 'partcle': expected particle"), std::string::npos) << codec.output;
  EXPECT_NE(codec.output.find("(did you mean 'particle'?)"), std::string::npos) << codec.output;
  const auto look = run_cli("render '" + pstream::test::data_path("pstream_v1/points_varying_lz4.pstream") +
                            "' --out /nonexistent/dir -q --look liqud");
  EXPECT_NE(look.output.find("look 'liqud': expected sprites or liquid (did you mean 'liquid'?)"), std::string::npos)
      << look.output;
  // Known words still parse (and fail, here, on the missing file, as before).
  const auto r = run_cli("info /no/such/file.abc");
  EXPECT_NE(r.output.find("/no/such/file.abc"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("did you mean"), std::string::npos) << r.output;
}

}  // namespace

namespace {

// export: a clip with empty frames round-trips through Alembic and through PLY exactly; -o's
// extension chooses the format (.ply a sequence), and another extension is refused with nothing
// written.
TEST(Cli, ExportRoundTripsEmptyFramesAndTheExtensionChoosesTheFormat) {
  namespace fs = std::filesystem;
  const fs::path dir = pstream::test::fresh_dir();
  const std::string abc = pstream::test::data_path("alembic/points_empty_frames.abc");
  const auto q = [](const fs::path& p) { return fmt::format("'{}'", p.string()); };
  ASSERT_EQ(run_cli("cook -q --codec raw " + q(abc) + " -o " + q(dir / "clip.pstream")).exit_code, 0);
  auto r = run_cli("export -q " + q(dir / "clip.pstream") + " -o " + q(dir / "back.abc"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = run_cli("export -q " + q(dir / "clip.pstream") + " -o " + q(dir / "seq" / "fx.ply"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(fs::exists(dir / "seq" / "fx.0001.ply"));
  ASSERT_EQ(run_cli("cook -q --codec raw " + q(dir / "back.abc") + " -o " + q(dir / "from_abc.pstream")).exit_code, 0);
  r = run_cli("cook -q --codec raw " + q(dir / "seq" / "fx.0001.ply") + " --fps 24 -o " + q(dir / "from_ply.pstream"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  // Every frame's count and sums equal the clip's (info --json --frames: float64 sums of x y z scale).
  const auto frames = [&](const fs::path& clip) {
    const auto j = nlohmann::json::parse(run_cli("info --json --frames " + q(clip)).output);
    return j["frames"];
  };
  const auto original = frames(dir / "clip.pstream");
  std::size_t empty = 0;
  for (const fs::path& copy : {dir / "from_abc.pstream", dir / "from_ply.pstream"}) {
    const auto back = frames(copy);
    ASSERT_EQ(back.size(), original.size()) << copy;
    for (std::size_t f = 0; f < original.size(); ++f) {
      EXPECT_EQ(back[f]["count"], original[f]["count"]) << copy << " frame " << f;
      EXPECT_EQ(back[f]["sum"], original[f]["sum"]) << copy << " frame " << f;
      empty += original[f]["count"] == 0;
    }
  }
  EXPECT_GT(empty, 0u) << "the fixture's empty frames";
  // Writing over the clip's own source (its name and content hash, as the cook recorded them) is
  // refused, and the source is left as it was.
  fs::copy_file(abc, dir / "points_empty_frames.abc");
  r = run_cli("export -q " + q(dir / "clip.pstream") + " -o " + q(dir / "points_empty_frames.abc"));
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("is the source"), std::string::npos) << r.output;
  EXPECT_EQ(fs::file_size(dir / "points_empty_frames.abc"), fs::file_size(abc));
  r = run_cli("export -q " + q(dir / "clip.pstream") + " -o " + q(dir / "x.txt"));
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("the extension chooses the format"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "x.txt"));
}

}  // namespace

namespace {

// info says when an Alembic cache has ids in name only (Blender's FLIP writes empty .pointIds).
TEST(Cli, InfoSaysWhenIdsAreEmpty) {
  const auto flip = run_cli("info '" + pstream::test::data_path("sims/blender_flip_pour_small.abc") + "'");
  EXPECT_NE(flip.output.find(".pointIds      uint64      varying  empty: written without ids"), std::string::npos)
      << flip.output;
  const auto sparks = run_cli("info '" + pstream::test::data_path("sims/blender_sparks.abc") + "'");
  EXPECT_EQ(sparks.output.find("written without ids"), std::string::npos) << sparks.output;
}

}  // namespace
