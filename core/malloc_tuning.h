#pragma once
// The allocator of a process that reconstructs (peak RSS and system time).
// - Blocks of 1 MB and more (frames, per-pixel arrays, images, the PNG decoder's scratch) come
//   from the large block cache (core/large_block_cache.h), which keeps freed pages for the next
//   allocations instead of mapping fresh ones. Full-resolution coin, CLI: minor page faults
//   ~310 k -> ~188 k per run, system time 0.82 -> 0.53 s, outputs identical.
// - The cache keeps at most kLargeBlockCacheLimit of freed pages: when the lens-shift stage frees
//   its 312 MB of frames, the rest is unmapped. Live blocks + cached pages stay below the decode
//   stage's peak that way (474 MB after the lens shift with 192 MB, against the 592 MB peak),
//   while the later stages still find most of their arrays in the cache (with 96 MB: 203 k
//   faults; with 512 MB: 189 k faults but the peak rose to 612 MB, the ground truth read on top
//   of 320 MB of cached pages).
// - glibc's mmap threshold is fixed at 8 MB for what is still malloc's (blocks under 1 MB, and
//   libraries that call malloc themselves): glibc raises it to the size of each mmapped block
//   freed (up to 32 MB), and heap memory freed in the middle is not returned, so a run kept 100+
//   MB of dead buffers resident (763 MB instead of 631 measured before the cache).
// - glibc's trim threshold is raised to 32 MB: with the default 128 kB every free at the top of a
//   heap gave its pages back (brk, or madvise in the worker threads' arenas) and the next
//   allocation faulted them in again: ~1260 brk and ~350 madvise calls per full-resolution run,
//   most of them the frame corrections' per-block matrices right after the last frame (~70 and 3
//   at 4 MB). Compute after the last frame 0.64 -> 0.61 s at 2 MB, then 0.531 -> 0.514 s at
//   32 MB (medians of alternated CLI runs); each arena keeps up to the threshold: peak RSS +11 MB
//   (CLI 493 -> 504 MB, the benchmark's child 478 -> 490 MB). (At 2 MB the child had measured
//   the benchmark's own bare decode too, 110 MB of it, and stood 4 MB below its 600 MB goal.)
// Call once, early in a process that reconstructs (the CLI, the benchmark's child).

#include <malloc.h>

#include <cstddef>

#include "core/large_block_cache.h"

namespace mesoscan {

// Freed pages the large block cache keeps at most (see above).
inline constexpr size_t kLargeBlockCacheLimit = size_t{192} << 20;

inline void TuneAllocatorForReconstruction() {
#ifdef M_MMAP_THRESHOLD
  mallopt(M_MMAP_THRESHOLD, 8 << 20);
  mallopt(M_TRIM_THRESHOLD, 32 << 20);
#endif
  EnableProcessLargeBlockCache(kLargeBlockCacheLimit);
}

// Returns the free memory of every malloc arena to the operating system (glibc malloc_trim): what
// the decoding threads freed stays resident in their arenas until trimmed. Called where the
// frames have been released and a large read follows (the CLI's ground truth), so that the read
// does not add to the resident peak.
inline void ReleaseFreedHeap() {
#ifdef M_MMAP_THRESHOLD
  malloc_trim(0);
#endif
}

}  // namespace mesoscan
