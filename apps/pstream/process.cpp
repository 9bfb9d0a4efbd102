#include "process.hpp"

#include <fcntl.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <sstream>

#include <fmt/format.h>

#include "particlestream/error.hpp"

extern char** environ;

namespace pstream::app {

bool have_program(const std::string& name) {
  const char* path = std::getenv("PATH");
  std::istringstream dirs(path ? path : "");
  for (std::string dir; std::getline(dirs, dir, ':');) {
    if (!dir.empty() && ::access((std::filesystem::path(dir) / name).c_str(), X_OK) == 0) return true;
  }
  return false;
}

ProgramResult run_program(const std::vector<std::string>& argv, bool capture, bool quiet) {
  ProgramResult result;
  if (argv.empty()) return result;
  std::vector<char*> args;
  for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  int pipe_fds[2] = {-1, -1};
  if (capture && ::pipe2(pipe_fds, O_CLOEXEC) != 0)
    throw Error(fmt::format("cannot run {}: {}", argv[0], std::strerror(errno)));
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  if (capture) posix_spawn_file_actions_adddup2(&actions, pipe_fds[1], STDOUT_FILENO);
  if (quiet) posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, "/dev/null", O_WRONLY, 0);
  pid_t pid = 0;
  const int spawned = ::posix_spawnp(&pid, argv[0].c_str(), &actions, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (capture) ::close(pipe_fds[1]);
  if (spawned != 0) {
    if (capture) ::close(pipe_fds[0]);
    throw Error(fmt::format("cannot run {}: {}", argv[0], std::strerror(spawned)));
  }
  if (capture) {
    char buffer[65536];
    for (;;) {
      const ssize_t n = ::read(pipe_fds[0], buffer, sizeof buffer);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) break;
      result.output.append(buffer, static_cast<std::size_t>(n));
    }
    ::close(pipe_fds[0]);
  }
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0) {
    if (errno != EINTR) throw Error(fmt::format("{}: cannot wait for it: {}", argv[0], std::strerror(errno)));
  }
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return result;
}

std::string self_executable() { return std::filesystem::read_symlink("/proc/self/exe").string(); }

void encode_video(const std::string& frames_dir, double fps, const std::string& video) {
  if (!have_program("ffmpeg")) {
    throw Error(
        fmt::format("{}: writing a video needs the ffmpeg program, which is not installed (apt-get install "
                    "ffmpeg); the PNG frames are in {}",
                    video, frames_dir));
  }
  // ffmpeg writes the file in place: give it a temporary beside the video and rename when done.
  const std::filesystem::path out(video);
  const std::filesystem::path temp =
      out.parent_path() / fmt::format(".{}.partial-{}{}", out.stem().string(), ::getpid(), out.extension().string());
  const ProgramResult r =
      run_program({"ffmpeg", "-nostdin", "-y", "-loglevel", "error", "-framerate", fmt::format("{}", fps), "-i",
                   (std::filesystem::path(frames_dir) / "frame_%05d.png").string(), "-c:v", "libx264", "-pix_fmt",
                   "yuv420p", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-f", "mp4", temp.string()});
  struct stat st {};
  const bool written = ::stat(temp.c_str(), &st) == 0 && S_ISREG(st.st_mode) && st.st_size > 0;
  if (r.exit_code != 0 || !written) {
    std::error_code ec;
    std::filesystem::remove(temp, ec);
    throw Error(fmt::format("{}: ffmpeg could not write the video (exit code {}); the PNG frames are in {}", video,
                            r.exit_code, frames_dir));
  }
  if (::rename(temp.c_str(), out.c_str()) != 0) {
    const int err = errno;
    std::error_code ec;
    std::filesystem::remove(temp, ec);
    throw Error(fmt::format("{}: cannot rename {} over it: {}", video, temp.string(), std::strerror(err)));
  }
}

}  // namespace pstream::app
