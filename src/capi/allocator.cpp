// Inside libparticlestream only: the global operator new and delete of the library's own code,
// routed to the library's allocator (base/memory.hpp), which an engine replaces with
// pstream_set_allocator(). libstdc++ is linked statically into the shared library and fmt is used
// header-only, so the standard containers, strings, threads and formatting of the library all
// allocate here. The version script keeps these definitions local: the host's operator new is
// untouched, and no block ever crosses between the two (the C API hands out no C++ objects).
#include <cstddef>
#include <new>

#include "base/memory.hpp"

namespace {

void* allocate_or_throw(std::size_t size, std::size_t alignment) {
  void* p = pstream::memory::allocate(size == 0 ? 1 : size, alignment);
  if (p == nullptr) throw std::bad_alloc();
  return p;
}

}  // namespace

void* operator new(std::size_t size) { return allocate_or_throw(size, 16); }
void* operator new[](std::size_t size) { return allocate_or_throw(size, 16); }
void* operator new(std::size_t size, std::align_val_t a) {
  return allocate_or_throw(size, static_cast<std::size_t>(a));
}
void* operator new[](std::size_t size, std::align_val_t a) {
  return allocate_or_throw(size, static_cast<std::size_t>(a));
}
void* operator new(std::size_t size, const std::nothrow_t&) noexcept {
  return pstream::memory::allocate(size == 0 ? 1 : size);
}
void* operator new[](std::size_t size, const std::nothrow_t&) noexcept {
  return pstream::memory::allocate(size == 0 ? 1 : size);
}
void* operator new(std::size_t size, std::align_val_t a, const std::nothrow_t&) noexcept {
  return pstream::memory::allocate(size == 0 ? 1 : size, static_cast<std::size_t>(a));
}
void* operator new[](std::size_t size, std::align_val_t a, const std::nothrow_t&) noexcept {
  return pstream::memory::allocate(size == 0 ? 1 : size, static_cast<std::size_t>(a));
}

void operator delete(void* p) noexcept { pstream::memory::deallocate(p); }
void operator delete[](void* p) noexcept { pstream::memory::deallocate(p); }
void operator delete(void* p, std::size_t) noexcept { pstream::memory::deallocate(p); }
void operator delete[](void* p, std::size_t) noexcept { pstream::memory::deallocate(p); }
void operator delete(void* p, std::align_val_t) noexcept { pstream::memory::deallocate(p); }
void operator delete[](void* p, std::align_val_t) noexcept { pstream::memory::deallocate(p); }
void operator delete(void* p, std::size_t, std::align_val_t) noexcept { pstream::memory::deallocate(p); }
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept { pstream::memory::deallocate(p); }
void operator delete(void* p, const std::nothrow_t&) noexcept { pstream::memory::deallocate(p); }
void operator delete[](void* p, const std::nothrow_t&) noexcept { pstream::memory::deallocate(p); }
void operator delete(void* p, std::align_val_t, const std::nothrow_t&) noexcept { pstream::memory::deallocate(p); }
void operator delete[](void* p, std::align_val_t, const std::nothrow_t&) noexcept { pstream::memory::deallocate(p); }
