#pragma once
// Large per-pixel buffers back to the operating system as soon as they are freed (issue 12: peak
// RSS). glibc raises its mmap threshold to the size of each mmapped block freed (up to 32 MB), so
// after the first 6-12 MB frame or per-pixel array is released the next ones come from the heap,
// and heap memory freed in the middle is not returned: the reconstruction's resident size then
// stays at its high-water mark and later stages add to it (a full-resolution run measured
// 763 MB instead of 631). A fixed threshold of 1 MB keeps every such buffer in its own mapping.
// Call once, early in a process that reconstructs (the CLI, the benchmark's child).

#include <malloc.h>

namespace mesoscan {

inline void MapLargeBuffersSeparately() {
#ifdef M_MMAP_THRESHOLD
  mallopt(M_MMAP_THRESHOLD, 1 << 20);
#endif
}

}  // namespace mesoscan
