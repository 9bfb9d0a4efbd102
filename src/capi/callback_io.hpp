// A pstream_io (the C API's IO callbacks, include/particlestream/particlestream.h) as the
// stream's IoBackend: synchronous reads through `read`, asynchronous ones through `read_async`
// (the load goes on when the host calls the completion). Its own unit so that the stream tests
// can run through exactly what the C API hands the stream.
#pragma once

#include <memory>

#include "particlestream/particlestream.h"
#include "particlestream/stream.hpp"

namespace pstream::capi {

// `io` must have `read` or `read_async` (or both); throws pstream::Error otherwise.
std::unique_ptr<stream::IoBackend> callback_io(const pstream_io& io);

}  // namespace pstream::capi
