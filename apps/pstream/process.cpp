#include "process.hpp"

#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <sstream>

#include <fmt/format.h>

#include "base/output_file.hpp"
#include "particlestream/error.hpp"

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
  // fork + exec rather than posix_spawn, for one call in between: the child is SIGKILLed when
  // this thread ends (a SIGKILL of pstream included), so no ffmpeg runs on as an orphan.
  // Between fork and exec only async-signal-safe calls.
  const pid_t parent = ::getpid();
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::prctl(PR_SET_PDEATHSIG, SIGKILL);
    if (::getppid() != parent) ::_exit(127);  // the parent is already gone
    if (capture) ::dup2(pipe_fds[1], STDOUT_FILENO);
    if (quiet) {
      const int null = ::open("/dev/null", O_WRONLY);
      if (null >= 0) ::dup2(null, STDERR_FILENO);
    }
    ::execvp(args[0], args.data());
    ::_exit(127);
  }
  const int spawned = pid < 0 ? errno : 0;
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

void encode_video(const std::string& frames_dir, std::uint64_t first, std::uint64_t frames, double fps,
                  const std::string& video) {
  if (!have_program("ffmpeg")) {
    throw Error(
        fmt::format("{}: writing a video needs the ffmpeg program, which is not installed (apt-get install "
                    "ffmpeg); the PNG frames are in {}",
                    video, frames_dir));
  }
  // ffmpeg writes the file in place: it writes our locked temporary beside the video (removed on
  // signals, recognised after a SIGKILL like every other), which is renamed when done.
  OutputFile out = OutputFile::create(video);
  const std::filesystem::path temp = out.temporary();
  if (temp.empty()) throw Error(fmt::format("{}: a video is written to a regular file", video));
  const ProgramResult r = run_program({"ffmpeg",
                                       "-nostdin",
                                       "-y",
                                       "-loglevel",
                                       "error",
                                       "-framerate",
                                       fmt::format("{}", fps),
                                       "-start_number",
                                       fmt::format("{}", first),
                                       "-i",
                                       (std::filesystem::path(frames_dir) / "frame_%05d.png").string(),
                                       "-frames:v",
                                       fmt::format("{}", frames),
                                       "-c:v",
                                       "libx264",
                                       "-pix_fmt",
                                       "yuv420p",
                                       "-vf",
                                       "pad=ceil(iw/2)*2:ceil(ih/2)*2",
                                       "-f",
                                       "mp4",
                                       temp.string()});
  struct stat st {};
  const bool written = ::stat(temp.c_str(), &st) == 0 && S_ISREG(st.st_mode) && st.st_size > 0;
  if (r.exit_code != 0 || !written) {
    throw Error(fmt::format("{}: ffmpeg could not write the video (exit code {}); the PNG frames are in {}", video,
                            r.exit_code, frames_dir));
  }
  out.commit();
}

}  // namespace pstream::app
