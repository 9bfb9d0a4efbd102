// The IO the stream tests read through, chosen by the environment variable PSTREAM_TEST_IO, so
// that the same tests run through every backend a host can give the stream:
//   file       (default) the built-in pread backend;
//   callbacks  the C API's pstream_io with a synchronous `read` (src/capi/callback_io.hpp),
//              50..250 us of latency a read;
//   async      pstream_io's `read_async`, served by a host IO thread after the same latency
//              (every fourth read completes before read_async returns).
// CTest runs the stream tests once per mode.
#pragma once

#include <filesystem>
#include <memory>

#include "particlestream/stream.hpp"

namespace pstream::test {

const char* io_mode();
std::unique_ptr<stream::IoBackend> test_io(const std::filesystem::path& file);

}  // namespace pstream::test
