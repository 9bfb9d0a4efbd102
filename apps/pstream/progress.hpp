// A progress bar on a terminal, plain lines every 10 % otherwise (logs, CI).
#pragma once

#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <optional>
#include <string>

#include <fmt/format.h>

#include "particlestream/cook.hpp"

namespace pstream::app {

class ProgressBar {
 public:
  explicit ProgressBar(std::string label, bool enabled = true)
      : label_(std::move(label)), enabled_(enabled), tty_(::isatty(STDERR_FILENO) != 0) {}

  // `done` of `total` units; `detail` follows the counts, `rate_unit` names the rate's unit.
  void update(std::uint64_t done, std::uint64_t total, const std::string& detail = {},
              const std::string& rate_unit = {}) {
    if (!enabled_ || total == 0) return;
    const int percent = static_cast<int>(100 * done / total);
    // The rate so far and the time left at that rate (once there is a rate to speak of).
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    std::string pace;
    if (done > 0 && seconds > 0.2) {
      const double rate = double(done) / seconds, left = double(total - done) / rate;
      pace = fmt::format(" · {:.3g}{}{}/s", rate, rate_unit.empty() ? "" : " ", rate_unit);
      if (done < total)
        pace += left < 90 ? fmt::format(", {:.0f} s left", left) : fmt::format(", {:.0f} min left", left / 60);
    }
    if (tty_) {
      const auto now = std::chrono::steady_clock::now();
      if (done != total && now - last_ < std::chrono::milliseconds(50)) return;
      last_ = now;
      constexpr int width = 30;
      const int filled = static_cast<int>(width * done / total);
      fmt::print(stderr, "\r{} [{}{}] {:3d}% {}/{} {}{}\x1b[K", label_, std::string(filled, '#'),
                 std::string(width - filled, '.'), percent, done, total, detail, pace);
      if (done == total) fmt::print(stderr, "\n");
    } else if (std::chrono::steady_clock::now() - start_ > std::chrono::seconds(1) &&
               (percent / 10 != last_decile_ || done == total)) {  // short jobs print nothing
      last_decile_ = percent / 10;
      fmt::print(stderr, "{}: {}% ({}/{}) {}{}\n", label_, percent, done, total, detail, pace);
    }
    std::fflush(stderr);
  }

  // Bytes read or written, shown in MiB with a MiB/s rate.
  void update_bytes(std::uint64_t done, std::uint64_t total) { update(done >> 20, total >> 20, "MiB", "MiB"); }

 private:
  std::string label_;
  bool enabled_, tty_;
  int last_decile_ = -1;
  std::chrono::steady_clock::time_point last_{};
  std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now();
};

// A cook's progress: one bar a stage (the fetch of a URL, the particle codec's scan, the writing),
// each with its own clock, so that a stage's rate and time left are its own and not the stages'
// before it.
class CookProgress {
 public:
  CookProgress(std::string label, bool enabled) : label_(std::move(label)), enabled_(enabled) {}
  void operator()(const cook::Progress& p) {
    if (p.stage != stage_ || !bar_) {
      stage_ = p.stage;
      bar_.reset();  // the last stage's line ends
      bar_.emplace(p.stage == cook::Stage::Fetch  ? label_ + ": fetch"
                   : p.stage == cook::Stage::Scan ? label_ + ": scan"
                                                  : label_,
                   enabled_);
    }
    if (p.stage == cook::Stage::Fetch)
      bar_->update_bytes(p.bytes_in, p.bytes_total);
    else if (p.stage == cook::Stage::Scan)
      bar_->update(p.frames_done, p.frame_count, "frames");
    else
      bar_->update(p.frames_done, p.frame_count, fmt::format("frames, {:.1f} MiB written", p.bytes_out / 1048576.0));
  }

 private:
  std::string label_;
  bool enabled_;
  cook::Stage stage_ = cook::Stage::Fetch;
  std::optional<ProgressBar> bar_;
};

}  // namespace pstream::app
