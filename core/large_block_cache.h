#pragma once
// A bounded cache of large memory blocks whose freed pages back the next allocations
// (system time). A full-resolution reconstruction allocates ~1.3 GB of large blocks in turn (the
// frame stack, the PNG decoders' buffers, the per-pixel arrays of every stage, the EXR writers'),
// while at most ~450 MB of them are alive at once. Each fresh page costs a minor fault, ~1.8 us
// in the VM we measure on (the kernel zeroes and maps it), against ~0.07 us to overwrite a page
// already mapped: 334 k faults were ~0.8 s of system time per run, a fifth of the process's CPU.
//
// The cache keeps the pages of freed blocks mapped (up to a limit) and hands them to the next
// allocation: a cached run at least as large is used in place (its tail, if longer, stays
// cached); otherwise the new block is assembled from cached runs with mremap(2), which moves
// their pages to the new addresses (page-table entries only, ~0.25 us a page, no copy and no
// zeroing), and only what the cache lacks is mapped fresh. So the lens-shift frames released
// after their stage (312 MB in 6.2 MB blocks) back the later stages' 12.5 MB arrays. Contents of
// a block are undefined, as malloc's.
//
// The resident size is live blocks + cached pages: a stage's freed blocks stay resident until the
// next ones take them, so the peak never exceeds the highest live total plus the limit, and in
// practice stays at the highest live total (every stage allocates at least as much as the one
// before freed). Blocks are separate mappings, so this is for blocks of a megabyte and more; the
// process-wide instance serves the global operator new (core/large_block_new.cc) in the
// processes that enable it (EnableProcessLargeBlockCache), and the PNG decoder's scratch.

#include <cstddef>
#include <cstdint>
#include <mutex>
#include <unordered_map>
#include <vector>

namespace mesoscan {

class LargeBlockCache {
 public:
  // Freed pages are kept up to `cache_limit_bytes`; beyond that they are unmapped at once.
  explicit LargeBlockCache(size_t cache_limit_bytes);
  ~LargeBlockCache();  // unmaps the cache and every block still allocated
  LargeBlockCache(const LargeBlockCache&) = delete;
  LargeBlockCache& operator=(const LargeBlockCache&) = delete;

  // A page-aligned block of at least `bytes` (> 0) bytes, contents undefined; nullptr if the
  // system has no memory for it.
  void* Allocate(size_t bytes);
  // Frees `p` if it is a block of this cache (returns true), else does nothing (false).
  // Cheap for a pointer that is not page-aligned (no lock).
  bool Free(void* p);
  // Unmaps every cached page (the live blocks stay).
  void Trim();

  struct Stats {
    size_t live_bytes = 0;    // in allocated blocks
    size_t cached_bytes = 0;  // freed, still mapped
    // Since construction, pages of allocated blocks that were: cached pages used in place,
    // cached pages moved to a new address, fresh (each a minor fault when first written).
    size_t reused_bytes = 0, moved_bytes = 0, fresh_bytes = 0;
    size_t unmapped_bytes = 0;  // freed pages unmapped (over the limit, or Trim)
  };
  Stats stats() const;

 private:
  // A contiguous range of pages made of pieces, each lying in one mapping of the kernel's (a
  // VMA: mremap moves one at a time), in address order.
  struct Run {
    char* addr = nullptr;
    std::vector<size_t> pieces;  // bytes of each piece, page multiples
    size_t bytes() const;
    // Splits off and returns the part from `at` bytes on (a page multiple < bytes()).
    Run SplitTail(size_t at);
  };
  static void Unmap(const Run& run);

  mutable std::mutex mutex_;
  const size_t cache_limit_;
  std::unordered_map<const void*, Run> live_;
  std::vector<Run> cached_;
  Stats stats_;
};

// Creates the process-wide cache (once; later calls do nothing), so that large allocations of the
// global operator new, where core/large_block_new.cc is linked in, and LargeBlockAllocate come from
// it. For processes that run a reconstruction stage by stage (`mesoscan reconstruct`, the
// benchmark's child). Blocks allocated before stay malloc's.
void EnableProcessLargeBlockCache(size_t cache_limit_bytes);
// The process-wide cache, or nullptr if not enabled.
LargeBlockCache* ProcessLargeBlockCache();

// Blocks of `bytes` from the process-wide cache if enabled, else mapped alone (mmap): for
// scratch buffers of a megabyte and more that are not std containers (the PNG decoder's).
// nullptr if out of memory. LargeBlockFree takes the same size.
void* LargeBlockAllocate(size_t bytes);
void LargeBlockFree(void* p, size_t bytes);

// The size from which the global operator new serves a request from the process-wide cache.
inline constexpr size_t kLargeBlockMinBytes = size_t{1} << 20;

}  // namespace mesoscan
