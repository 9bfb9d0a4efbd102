// The library's allocator. Every heap allocation the SDK's shared library makes goes through it:
// its operator new and delete (src/capi/allocator.cpp, inside libparticlestream only) and the
// zstd contexts (zstd_memory()). By default it is malloc/free; an engine installs its own with
// pstream_set_allocator(). The static libraries used by the CLI keep the global operator new;
// only their zstd contexts come through here, which then means malloc.
//
// Each block remembers the allocator that made it (a small header), so the allocator can be
// changed at any time: memory allocated before the change is freed with the one that made it.
#pragma once

#include <cstddef>
#include <cstdint>

namespace pstream::memory {

struct Allocator {
  void* user = nullptr;
  // Returns `size` bytes aligned to `alignment` (a power of two, at least 16), or null.
  void* (*allocate)(void* user, std::size_t size, std::size_t alignment) = nullptr;
  void (*free)(void* user, void* block) = nullptr;
};

// Installs `allocator` for allocations from now on (both functions null: malloc/free). At most
// 64 different allocators over a process's life (each is remembered for the blocks it made);
// returns false past that.
bool set_allocator(const Allocator& allocator);

// `alignment`: a power of two (rounded up to 16). Null when the allocator fails.
void* allocate(std::size_t size, std::size_t alignment = 16) noexcept;
void deallocate(void* block) noexcept;  // null is ignored

// What the current process has allocated through here and not freed (blocks), for tests.
std::uint64_t live_blocks() noexcept;

// The machine's memory in bytes (UINT64_MAX when it cannot be told): what work that would hold
// more than the machine has is measured against.
std::uint64_t physical_memory() noexcept;

}  // namespace pstream::memory
