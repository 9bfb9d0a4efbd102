#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <vector>

namespace pstream::test {

// An empty folder of its own for a test under /tmp/pstream-tests/: named `name`, or after the
// running GoogleTest test (characters that are awkward in paths become '_').
inline std::filesystem::path fresh_dir(std::string name = {}) {
  if (name.empty()) {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    name = std::string(info->test_suite_name()) + "." + info->name();
  }
  for (char& c : name) {
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '.' && c != '-' && c != '_') c = '_';
  }
  // The stream suite runs again through other IO backends (PSTREAM_TEST_IO) and, over HTTP,
  // against each test server (PSTREAM_TEST_SERVER), maybe all at the same time: each run gets
  // folders of its own.
  if (const char* io = std::getenv("PSTREAM_TEST_IO")) name += std::string(".") + io;
  if (const char* server = std::getenv("PSTREAM_TEST_SERVER")) name += std::string(".") + server;
  const auto dir = std::filesystem::temp_directory_path() / "pstream-tests" / name;
  std::error_code ec;  // a file that vanishes while this removes the folder: try again
  for (int attempt = 0; attempt < 3 && (std::filesystem::remove_all(dir, ec), ec); ++attempt) {
  }
  std::filesystem::create_directories(dir);
  return dir;
}

// A clip that several tests or runs cook alike, cooked once per CTest run. Under CTest,
// PSTREAM_TEST_CLIPS names a folder that the fixture SharedClips (tests/CMakeLists.txt) empties
// before the tests and removes after them: the clip is `key`.pstream there, made by `cook` when it
// is not there yet, and tests only read it (one that alters a clip alters a copy). Without the
// variable (the test program run by hand), `cook` makes `own`.
//
// Two tests may find the clip missing at once. Each cooks under a name of its own process and
// links it into place only where no other got there first: renamed over the first, the second
// would change a file that a test already reads, and a test server that names it by path (nginx)
// then serves another file under it (the stream fails: "the file changed since it was opened").
inline std::filesystem::path shared_clip(const std::string& key, const std::filesystem::path& own,
                                         const std::function<void(const std::filesystem::path&)>& cook) {
  const char* shared = std::getenv("PSTREAM_TEST_CLIPS");
  if (shared == nullptr || *shared == 0) {
    cook(own);
    return own;
  }
  const std::filesystem::path path = std::filesystem::path(shared) / (key + ".pstream");
  if (std::filesystem::exists(path)) return path;
  const std::filesystem::path mine =
      std::filesystem::path(shared) / (key + ".cooking-" + std::to_string(getpid()) + ".pstream");
  cook(mine);
  std::error_code ec;
  std::filesystem::create_hard_link(mine, path, ec);  // fails where another test's is there: it stays
  if (ec && !std::filesystem::exists(path)) std::filesystem::rename(mine, path);  // no hard links here
  std::filesystem::remove(mine, ec);
  return path;
}

inline std::string data_path(const std::string& relative) {
  std::string path = PSTREAM_TEST_DATA;
  path.append("/").append(relative);
  return path;
}

// The k-th image (in number order) of a `pstream render` folder: images are numbered by source
// frame (frame_NNNNN.png), so a clip that starts at frame 1 has no frame_00000.png. An empty path
// when there are not that many.
inline std::filesystem::path nth_frame(const std::filesystem::path& dir, std::size_t k) {
  std::vector<std::filesystem::path> frames;
  std::error_code ec;
  for (const auto& e : std::filesystem::directory_iterator(dir, ec)) {
    const std::string name = e.path().filename().string();
    if (name.size() == 15 && name.starts_with("frame_") && name.ends_with(".png")) frames.push_back(e.path());
  }
  std::sort(frames.begin(), frames.end());
  return k < frames.size() ? frames[k] : std::filesystem::path();
}

inline std::string read_text(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

inline std::vector<std::byte> read_bytes(const std::string& path) {
  const std::string s = read_text(path);
  std::vector<std::byte> out(s.size());
  for (std::size_t i = 0; i < s.size(); ++i) out[i] = static_cast<std::byte>(s[i]);
  return out;
}

struct CommandResult {
  int exit_code = -1;
  std::string output;  // stdout and stderr together
};

// Runs a shell command line, capturing stdout and stderr.
inline CommandResult run_cli_raw(const std::string& command) {
  CommandResult r;
  const std::string cmd = command + " 2>&1";
  FILE* pipe = popen(cmd.c_str(), "r");
  if (pipe == nullptr) return r;
  char buf[65536];
  std::size_t n;
  while ((n = fread(buf, 1, sizeof buf, pipe)) > 0) r.output.append(buf, n);
  const int status = pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

// `p` in single quotes, for the shell commands the CLI tests run.
inline std::string q(const std::filesystem::path& p) {
  std::string quoted = "'";
  quoted.append(p.string()).append("'");
  return quoted;
}

// Runs the pstream command-line tool with `args` (already shell-quoted).
// (Appended, not `+`: GCC 12 warns falsely of a bound overflow in `std::string(literal) + ...`.)
inline CommandResult run_cli(const std::string& args) {
  std::string command = PSTREAM_CLI;
  command.append(" ").append(args);
  return run_cli_raw(command);
}

// A CLI run that must fail cleanly: a non-zero exit code that is not a signal, `fragment` in the
// output, never "internal error".
inline void expect_error(const CommandResult& r, const std::string& fragment) {
  EXPECT_NE(r.exit_code, 0) << r.output;
  EXPECT_LT(r.exit_code, 128) << "ended by a signal: " << r.output;
  EXPECT_EQ(r.output.find("internal error"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find(fragment), std::string::npos) << "expected '" << fragment << "' in:\n" << r.output;
}

}  // namespace pstream::test
