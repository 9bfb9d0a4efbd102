// A pstream_io (the C API's IO callbacks, include/particlestream/particlestream.h) as the
// stream's io::ByteSource: synchronous reads through `read`, asynchronous ones through `read_async`
// (the load goes on when the host calls the completion). Its own unit so that the stream tests
// can run through exactly what the C API hands the stream.
#pragma once

#include <memory>

#include "particlestream/particlestream.h"
#include "particlestream/stream.hpp"

namespace pstream::capi {

// A read_async completion not called within this long puts the clip in its error state.
inline constexpr double kDefaultIoTimeoutSeconds = 30.0;

// `io` must have `read` or `read_async` (or both); throws pstream::Error otherwise. A host's
// completion called twice, or not within `timeout_seconds` (0: kDefaultIoTimeoutSeconds), is
// reported by fault(), so the stream fails with it instead of crashing or waiting forever.
std::unique_ptr<io::ByteSource> callback_io(const pstream_io& io, double timeout_seconds = 0.0);

}  // namespace pstream::capi
