// Errors thrown by every ParticleStream module.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <utility>

namespace pstream {

// Every failure caused by input data or the environment is reported as an Error whose message
// names the file, where in it (offset, frame, object) and what was expected.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// An Error that a setting of the caller fixes. `option` is the setting's name in the library's API
// (the member of the options struct: "drop_invalid", "max_frames"). Messages of every Error name
// settings that way between backquotes (`drop_invalid`), so a front end that calls them something
// else (a command-line flag) can say it its own way by replacing the quoted names.
class OptionError : public Error {
 public:
  OptionError(std::string option, const std::string& what) : Error(what), option_(std::move(option)) {}
  const std::string& option() const { return option_; }

 private:
  std::string option_;
};

}  // namespace pstream
