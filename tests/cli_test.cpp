// The command line a user types: typos get "did you mean" (issue #27's first CLI item).
#include <gtest/gtest.h>

#include <string>

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
