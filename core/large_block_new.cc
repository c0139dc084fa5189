// The global operator new and delete, replaced so that blocks of kLargeBlockMinBytes and more
// come from the process-wide LargeBlockCache once a command enables it (core/large_block_cache.h):
// the per-pixel arrays, frame samples and images of the reconstruction are std containers, and
// this is where all of them allocate. Smaller blocks, and every block while the cache is not
// enabled, are malloc's as before. Linked into the executables that enable the cache (`mesoscan`,
// bench_reconstruct), not into the libraries. Not compiled under AddressSanitizer, whose own
// operator new checks bounds and new/delete pairing.

#if defined(__SANITIZE_ADDRESS__)
#define MESOSCAN_KEEP_LIBRARY_NEW 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define MESOSCAN_KEEP_LIBRARY_NEW 1
#endif
#endif

#ifndef MESOSCAN_KEEP_LIBRARY_NEW

#include <cstdint>
#include <cstdlib>
#include <new>

#include "core/large_block_cache.h"

namespace {

constexpr size_t kPageAlignment = 4096;  // the cache's blocks are page-aligned (at least this)

void* TryAllocate(size_t n, size_t alignment) {
  if (n >= mesoscan::kLargeBlockMinBytes && alignment <= kPageAlignment)
    if (mesoscan::LargeBlockCache* cache = mesoscan::ProcessLargeBlockCache())
      if (void* p = cache->Allocate(n)) return p;
  if (n == 0) n = 1;
  if (alignment <= __STDCPP_DEFAULT_NEW_ALIGNMENT__) return std::malloc(n);
  void* p = nullptr;
  return posix_memalign(&p, alignment, n) == 0 ? p : nullptr;
}

void* Allocate(size_t n, size_t alignment) {
  for (;;) {
    if (void* p = TryAllocate(n, alignment)) return p;
    const std::new_handler handler = std::get_new_handler();
    if (!handler) throw std::bad_alloc();
    handler();
  }
}

void* AllocateNoThrow(size_t n, size_t alignment) noexcept {
  try {
    return Allocate(n, alignment);
  } catch (...) {
    return nullptr;
  }
}

void Release(void* p) noexcept {
  if (!p) return;
  if (mesoscan::LargeBlockCache* cache = mesoscan::ProcessLargeBlockCache();
      cache && cache->Free(p))
    return;
  std::free(p);
}

constexpr size_t kDefault = __STDCPP_DEFAULT_NEW_ALIGNMENT__;

}  // namespace

void* operator new(size_t n) { return Allocate(n, kDefault); }
void* operator new[](size_t n) { return Allocate(n, kDefault); }
void* operator new(size_t n, const std::nothrow_t&) noexcept {
  return AllocateNoThrow(n, kDefault);
}
void* operator new[](size_t n, const std::nothrow_t&) noexcept {
  return AllocateNoThrow(n, kDefault);
}
void* operator new(size_t n, std::align_val_t a) { return Allocate(n, static_cast<size_t>(a)); }
void* operator new[](size_t n, std::align_val_t a) { return Allocate(n, static_cast<size_t>(a)); }
void* operator new(size_t n, std::align_val_t a, const std::nothrow_t&) noexcept {
  return AllocateNoThrow(n, static_cast<size_t>(a));
}
void* operator new[](size_t n, std::align_val_t a, const std::nothrow_t&) noexcept {
  return AllocateNoThrow(n, static_cast<size_t>(a));
}

void operator delete(void* p) noexcept { Release(p); }
void operator delete[](void* p) noexcept { Release(p); }
void operator delete(void* p, size_t) noexcept { Release(p); }
void operator delete[](void* p, size_t) noexcept { Release(p); }
void operator delete(void* p, const std::nothrow_t&) noexcept { Release(p); }
void operator delete[](void* p, const std::nothrow_t&) noexcept { Release(p); }
void operator delete(void* p, std::align_val_t) noexcept { Release(p); }
void operator delete[](void* p, std::align_val_t) noexcept { Release(p); }
void operator delete(void* p, size_t, std::align_val_t) noexcept { Release(p); }
void operator delete[](void* p, size_t, std::align_val_t) noexcept { Release(p); }
void operator delete(void* p, std::align_val_t, const std::nothrow_t&) noexcept { Release(p); }
void operator delete[](void* p, std::align_val_t, const std::nothrow_t&) noexcept { Release(p); }

#endif  // MESOSCAN_KEEP_LIBRARY_NEW
