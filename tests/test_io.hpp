// The IO the stream tests read through, chosen by the environment variable PSTREAM_TEST_IO, so
// that the same tests run through every backend a host can give the stream:
//   file       (default) the built-in pread backend;
//   callbacks  the C API's pstream_io with a synchronous `read` (src/capi/callback_io.hpp),
//              50..250 us of latency a read;
//   async      pstream_io's `read_async`, served by a host IO thread after the same latency
//              (every fourth read completes before read_async returns);
//   http       the HTTP(S) source (io::open_url) against the server tests/http/with_server.sh
//              started: nginx, or tests/http/fault_server.py (single ranges, like S3).
// CTest runs the stream tests once per mode.
#pragma once

#include <filesystem>
#include <memory>
#include <string>

#include "particlestream/stream.hpp"

namespace pstream::test {

const char* io_mode();
// The URL of a local file on the test server (PSTREAM_TEST_URL_BASE), with fault segments
// ("/~latency=50") before its path.
std::string test_url(const std::filesystem::path& file, const std::string& faults = "");
std::unique_ptr<io::ByteSource> test_io(const std::filesystem::path& file);

}  // namespace pstream::test
