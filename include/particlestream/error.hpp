// Errors thrown by every ParticleStream module.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>

namespace pstream {

// Every failure caused by input data or the environment is reported as an Error whose message
// names the file, where in it (offset, frame, object) and what was expected.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace pstream
