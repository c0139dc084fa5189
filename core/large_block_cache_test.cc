#include "core/large_block_cache.h"

#include <gtest/gtest.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <unistd.h>

#include <cstring>
#include <thread>
#include <vector>

namespace mesoscan {
namespace {

constexpr size_t kMB = size_t{1} << 20;

long MinorFaults() {
  rusage ru{};
  getrusage(RUSAGE_THREAD, &ru);
  return ru.ru_minflt;
}

// Pages of [p, p + bytes) that are resident (mapped to memory, not yet to fault in).
size_t ResidentPages(void* p, size_t bytes) {
  const size_t page = static_cast<size_t>(sysconf(_SC_PAGESIZE));
  std::vector<unsigned char> in((bytes + page - 1) / page);
  if (mincore(p, bytes, in.data()) != 0) return 0;
  size_t n = 0;
  for (const unsigned char c : in) n += c & 1;
  return n;
}

void Fill(void* p, size_t bytes, unsigned char value) { std::memset(p, value, bytes); }

bool AllEqual(const void* p, size_t bytes, unsigned char value) {
  const auto* c = static_cast<const unsigned char*>(p);
  for (size_t i = 0; i < bytes; ++i)
    if (c[i] != value) return false;
  return true;
}

TEST(LargeBlockCache, FreedBlockIsUsedInPlaceWithItsPagesAndNoFaults) {
  LargeBlockCache cache(64 * kMB);
  void* a = cache.Allocate(8 * kMB);
  ASSERT_NE(a, nullptr);
  Fill(a, 8 * kMB, 7);
  EXPECT_TRUE(cache.Free(a));
  EXPECT_EQ(cache.stats().cached_bytes, 8 * kMB);
  const long faults0 = MinorFaults();
  void* b = cache.Allocate(6 * kMB);  // the smaller block takes the cached run's start
  EXPECT_EQ(b, a);
  EXPECT_TRUE(AllEqual(b, 6 * kMB, 7));  // the same pages, not fresh ones
  Fill(b, 6 * kMB, 1);
  // 1536 pages written: fresh ones would fault each (4 KB pages). Allow for the test's own few
  // and a sanitizer's shadow memory (ThreadSanitizer: ~250).
  EXPECT_LT(MinorFaults() - faults0, 1536 / 4);
  const LargeBlockCache::Stats s = cache.stats();
  EXPECT_EQ(s.reused_bytes, 6 * kMB);
  EXPECT_EQ(s.fresh_bytes, 8 * kMB);
  EXPECT_EQ(s.cached_bytes, 2 * kMB);  // the tail stays cached
  EXPECT_EQ(s.live_bytes, 6 * kMB);
  EXPECT_TRUE(cache.Free(b));
}

TEST(LargeBlockCache, LargerBlockIsAssembledFromCachedPagesByMovingThem) {
  LargeBlockCache cache(64 * kMB);
  void* a = cache.Allocate(3 * kMB);
  void* b = cache.Allocate(2 * kMB);
  ASSERT_TRUE(a && b);
  Fill(a, 3 * kMB, 0xA);
  Fill(b, 2 * kMB, 0xB);
  cache.Free(a);
  cache.Free(b);
  void* c = cache.Allocate(6 * kMB);  // 5 MB moved (the larger run first), 1 MB fresh
  ASSERT_NE(c, nullptr);
  const size_t page = static_cast<size_t>(sysconf(_SC_PAGESIZE));
  EXPECT_EQ(ResidentPages(c, 6 * kMB), 5 * kMB / page);
  char* p = static_cast<char*>(c);
  EXPECT_TRUE(AllEqual(p, 3 * kMB, 0xA));
  EXPECT_TRUE(AllEqual(p + 3 * kMB, 2 * kMB, 0xB));
  EXPECT_TRUE(AllEqual(p + 5 * kMB, kMB, 0));  // fresh pages
  LargeBlockCache::Stats s = cache.stats();
  EXPECT_EQ(s.moved_bytes, 5 * kMB);
  EXPECT_EQ(s.fresh_bytes, 3 * kMB + 2 * kMB + kMB);
  EXPECT_EQ(s.cached_bytes, 0u);
  // The assembled block (three pieces, each moved or mapped on its own) moves again as a whole,
  // split across two new blocks.
  Fill(c, 6 * kMB, 0xC);
  cache.Free(c);
  void* d = cache.Allocate(kMB + page);
  void* e = cache.Allocate(8 * kMB);
  ASSERT_TRUE(d && e);
  EXPECT_TRUE(AllEqual(d, kMB + page, 0xC));
  EXPECT_TRUE(AllEqual(e, 6 * kMB - kMB - page, 0xC));
  EXPECT_TRUE(AllEqual(static_cast<char*>(e) + 5 * kMB - page, 3 * kMB + page, 0));
  s = cache.stats();
  EXPECT_EQ(s.moved_bytes, 5 * kMB + 5 * kMB - page);
  EXPECT_EQ(s.cached_bytes, 0u);
  Fill(e, 8 * kMB, 0xE);
  EXPECT_TRUE(cache.Free(d));
  EXPECT_TRUE(cache.Free(e));
  EXPECT_EQ(cache.stats().live_bytes, 0u);
}

TEST(LargeBlockCache, KeepsNoMoreThanItsLimitAndTrimUnmapsTheRest) {
  LargeBlockCache cache(3 * kMB);
  void* a = cache.Allocate(2 * kMB);
  void* b = cache.Allocate(2 * kMB);
  Fill(a, 2 * kMB, 1);
  Fill(b, 2 * kMB, 1);
  cache.Free(a);
  cache.Free(b);
  LargeBlockCache::Stats s = cache.stats();
  EXPECT_EQ(s.cached_bytes, 3 * kMB);
  EXPECT_EQ(s.unmapped_bytes, kMB);
  EXPECT_EQ(ResidentPages(b, kMB), kMB / static_cast<size_t>(sysconf(_SC_PAGESIZE)));
  cache.Trim();
  s = cache.stats();
  EXPECT_EQ(s.cached_bytes, 0u);
  EXPECT_EQ(s.unmapped_bytes, 4 * kMB);
  void* c = cache.Allocate(kMB);
  EXPECT_EQ(cache.stats().fresh_bytes, 5 * kMB);
  cache.Free(c);
}

TEST(LargeBlockCache, FreeIgnoresPointersItDidNotAllocate) {
  LargeBlockCache cache(8 * kMB);
  std::vector<char> foreign(2 * kMB);
  EXPECT_FALSE(cache.Free(foreign.data()));
  EXPECT_FALSE(cache.Free(nullptr));
  void* page_aligned = nullptr;
  ASSERT_EQ(posix_memalign(&page_aligned, 4096, 4096), 0);
  EXPECT_FALSE(cache.Free(page_aligned));
  free(page_aligned);
  void* a = cache.Allocate(kMB);
  EXPECT_FALSE(cache.Free(static_cast<char*>(a) + 4096));  // inside a block, not its start
  EXPECT_TRUE(cache.Free(a));
  EXPECT_FALSE(cache.Free(a));  // already freed
  EXPECT_EQ(cache.Allocate(0), nullptr);
}

TEST(LargeBlockCache, ThreadsAllocatingAndFreeingKeepTheirContents) {
  LargeBlockCache cache(16 * kMB);
  const auto work = [&](unsigned char tag, bool* ok) {
    for (int i = 0; i < 40; ++i) {
      const size_t bytes = (1 + (i * 7 + tag) % 5) * kMB + 4096 * tag;
      auto* p = static_cast<unsigned char*>(cache.Allocate(bytes));
      if (!p) {
        *ok = false;
        return;
      }
      Fill(p, bytes, tag);
      std::this_thread::yield();
      if (!AllEqual(p, bytes, tag)) *ok = false;
      cache.Free(p);
    }
  };
  bool ok1 = true, ok2 = true;
  std::thread t1(work, 1, &ok1), t2(work, 2, &ok2);
  t1.join();
  t2.join();
  EXPECT_TRUE(ok1);
  EXPECT_TRUE(ok2);
  const LargeBlockCache::Stats s = cache.stats();
  EXPECT_EQ(s.live_bytes, 0u);
  EXPECT_LE(s.cached_bytes, 16 * kMB);
  EXPECT_GT(s.reused_bytes + s.moved_bytes, 0u);
}

}  // namespace
}  // namespace mesoscan
