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
  // Known words still parse (and fail, here, on the missing file, as before).
  const auto r = run_cli("info /no/such/file.abc");
  EXPECT_NE(r.output.find("/no/such/file.abc"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("did you mean"), std::string::npos) << r.output;
}

}  // namespace
