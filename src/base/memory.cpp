#include "base/memory.hpp"

#include <array>
#include <atomic>
#include <cstdlib>
#include <cstring>
#include <mutex>

#include <unistd.h>

namespace pstream::memory {
namespace {

void* system_allocate(void*, std::size_t size, std::size_t alignment) {
  return std::aligned_alloc(alignment, (size + alignment - 1) / alignment * alignment);
}
void system_free(void*, void* block) { std::free(block); }

// Allocators ever installed; entry 0 is malloc/free. A block's header names its entry, so
// entries are never reused or removed.
constexpr std::size_t kMaxAllocators = 64;
std::array<Allocator, kMaxAllocators> g_allocators = {Allocator{nullptr, system_allocate, system_free}};
std::atomic<std::size_t> g_count{1};
std::atomic<std::size_t> g_current{0};
std::atomic<std::uint64_t> g_live{0};
std::mutex g_install;

// In front of each block, in the `pad` bytes before it (pad = max(16, alignment)): the pad
// itself and the allocator's entry.
struct Header {
  std::uint32_t pad;
  std::uint32_t entry;
};

}  // namespace

bool set_allocator(const Allocator& allocator) {
  std::lock_guard lock(g_install);
  if (allocator.allocate == nullptr && allocator.free == nullptr) {
    g_current.store(0, std::memory_order_release);
    return true;
  }
  if (allocator.allocate == nullptr || allocator.free == nullptr) return false;
  const std::size_t n = g_count.load(std::memory_order_relaxed);
  for (std::size_t i = 1; i < n; ++i) {  // the same one again: reuse its entry
    const Allocator& a = g_allocators[i];
    if (a.allocate == allocator.allocate && a.free == allocator.free && a.user == allocator.user) {
      g_current.store(i, std::memory_order_release);
      return true;
    }
  }
  if (n == kMaxAllocators) return false;
  g_allocators[n] = allocator;
  g_count.store(n + 1, std::memory_order_release);
  g_current.store(n, std::memory_order_release);
  return true;
}

void* allocate(std::size_t size, std::size_t alignment) noexcept {
  if (alignment < 16 || (alignment & (alignment - 1)) != 0) {
    std::size_t a = 16;
    while (a < alignment) a *= 2;
    alignment = a;
  }
  const std::size_t pad = alignment;
  if (size > SIZE_MAX - pad) return nullptr;
  const std::size_t entry = g_current.load(std::memory_order_acquire);
  const Allocator& a = g_allocators[entry];
  auto* raw = static_cast<unsigned char*>(a.allocate(a.user, size + pad, alignment));
  if (raw == nullptr) return nullptr;
  const Header h{static_cast<std::uint32_t>(pad), static_cast<std::uint32_t>(entry)};
  std::memcpy(raw + pad - sizeof h, &h, sizeof h);
  g_live.fetch_add(1, std::memory_order_relaxed);
  return raw + pad;
}

void deallocate(void* block) noexcept {
  if (block == nullptr) return;
  auto* p = static_cast<unsigned char*>(block);
  Header h{};
  std::memcpy(&h, p - sizeof h, sizeof h);
  const Allocator& a = g_allocators[h.entry];
  g_live.fetch_sub(1, std::memory_order_relaxed);
  a.free(a.user, p - h.pad);
}

std::uint64_t live_blocks() noexcept { return g_live.load(std::memory_order_relaxed); }

std::uint64_t physical_memory() noexcept {
  const long pages = ::sysconf(_SC_PHYS_PAGES), page = ::sysconf(_SC_PAGE_SIZE);
  return pages > 0 && page > 0 ? std::uint64_t(pages) * std::uint64_t(page) : UINT64_MAX;
}

}  // namespace pstream::memory
