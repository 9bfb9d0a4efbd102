// zstd contexts whose memory comes from the library's allocator (base/memory.hpp), so that an
// allocator installed through the C API sees zstd's allocations too. Free them with
// ZSTD_freeDCtx / ZSTD_freeCCtx as usual (the context remembers its allocator).
#pragma once

#include <zstd.h>

namespace pstream::format {

ZSTD_DCtx* make_zstd_dctx();  // null when out of memory
ZSTD_CCtx* make_zstd_cctx();

}  // namespace pstream::format
