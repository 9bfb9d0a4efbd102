// Running other programs (ffmpeg, this pstream for `bench all`) without a shell: an argument
// vector goes straight to execvp, so no path or option is ever parsed as shell syntax.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace pstream::app {

// Whether `name` is an executable file in one of PATH's folders.
bool have_program(const std::string& name);

struct ProgramResult {
  int exit_code = -1;  // -1: it did not start or ended on a signal
  std::string output;  // its standard output, when captured
};
// Runs argv[0] (looked up in PATH) with `argv` and waits. With `capture`, its standard output
// is returned (standard error is left to ours, or discarded with `quiet`). The program is killed
// if the calling thread ends first (PR_SET_PDEATHSIG): it never outlives pstream.
ProgramResult run_program(const std::vector<std::string>& argv, bool capture = false, bool quiet = false);

// This executable's path (to run pstream's own subcommands).
std::string self_executable();

// Encodes DIR/frame_{first}.png .. frame_{first + frames - 1}.png (five digits) into an H.264 MP4
// with ffmpeg (exactly those: other frames in the folder are not taken), then checks the file was
// written: throws pstream::Error saying what went wrong otherwise.
void encode_video(const std::string& frames_dir, std::uint64_t first, std::uint64_t frames, double fps,
                  const std::string& video);

}  // namespace pstream::app
