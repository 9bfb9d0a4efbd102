// A fixture cooked into a temporary file for a benchmark to read, removed again when the
// benchmark's clip goes: the benchmarks leave nothing behind, even when a cook fails.
#pragma once

#include <unistd.h>

#include <filesystem>
#include <string>
#include <string_view>

#include "particlestream/cook.hpp"

namespace pstream::bench {

class TemporaryCook {
 public:
  // Cooks `options` (its output replaced) into the temporary folder, named by `label`.
  TemporaryCook(cook::Options options, std::string_view label)
      : path_(std::filesystem::temp_directory_path() /
              ("pstream-bench-" + std::string(label) + "-" + std::to_string(::getpid()) + ".pstream")) {
    options.output = path_;
    try {
      cook::cook(options);
    } catch (...) {
      std::filesystem::remove(path_);
      throw;
    }
  }
  ~TemporaryCook() {
    std::error_code ignored;
    std::filesystem::remove(path_, ignored);
  }
  TemporaryCook(const TemporaryCook&) = delete;
  TemporaryCook& operator=(const TemporaryCook&) = delete;
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

}  // namespace pstream::bench
