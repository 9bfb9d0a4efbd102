#define ZSTD_STATIC_LINKING_ONLY  // ZSTD_customMem and the *_advanced constructors (exported by libzstd)
#include "format/zstd_memory.hpp"

#include "base/memory.hpp"

namespace pstream::format {
namespace {

void* zstd_allocate(void*, std::size_t size) { return memory::allocate(size); }
void zstd_free(void*, void* block) { memory::deallocate(block); }
constexpr ZSTD_customMem kMemory{zstd_allocate, zstd_free, nullptr};

}  // namespace

ZSTD_DCtx* make_zstd_dctx() { return ZSTD_createDCtx_advanced(kMemory); }
ZSTD_CCtx* make_zstd_cctx() { return ZSTD_createCCtx_advanced(kMemory); }

}  // namespace pstream::format
