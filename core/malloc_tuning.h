#pragma once
// Large per-pixel buffers back to the operating system as soon as they are freed (issue 12: peak
// RSS). glibc raises its mmap threshold to the size of each mmapped block freed (up to 32 MB), so
// after the first 6-12 MB frame or per-pixel array is released the next ones come from the heap,
// and heap memory freed in the middle is not returned: the reconstruction's resident size then
// stays at its high-water mark and later stages add to it (a full-resolution run measured
// 763 MB instead of 631). A fixed threshold of 8 MB keeps every per-pixel array (12.5 MB and up
// at full resolution) in its own mapping, while the 6.2 MB frames and smaller buffers are reused
// from the heap. Full-resolution coin, CLI, three runs each (report.json peak_rss_mb, system CPU):
// 1 MB 588 MB, 1.2-1.4 s; 8 MB 593 MB, 0.93-1.0 s; glibc's default 597-612 MB, 0.93-1.05 s.
// Call once, early in a process that reconstructs (the CLI, the benchmark's child).

#include <malloc.h>

namespace mesoscan {

inline void MapLargeBuffersSeparately() {
#ifdef M_MMAP_THRESHOLD
  mallopt(M_MMAP_THRESHOLD, 8 << 20);
#endif
}

// Returns the free memory of every malloc arena to the operating system (glibc malloc_trim): the
// 6.2 MB frames come from the heaps of the threads that decoded them, and once released they
// stay resident until trimmed. Called where the frames have been released and a large read
// follows (the CLI's ground truth), so that the read does not add to the resident peak.
inline void ReleaseFreedHeap() {
#ifdef M_MMAP_THRESHOLD
  malloc_trim(0);
#endif
}

}  // namespace mesoscan
