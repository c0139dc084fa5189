#include "core/large_block_cache.h"

#include <sys/mman.h>
#include <unistd.h>

#include <atomic>
#include <utility>

namespace mesoscan {
namespace {

size_t PageSize() {
  static const size_t page = static_cast<size_t>(::sysconf(_SC_PAGESIZE));
  return page;
}

size_t RoundUpToPages(size_t bytes) {
  const size_t page = PageSize();
  return (bytes + page - 1) / page * page;
}

void* MapFresh(size_t bytes) {
  void* p = ::mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  return p == MAP_FAILED ? nullptr : p;
}

std::atomic<LargeBlockCache*> g_process_cache{nullptr};

// Set while this thread holds a cache's lock: the small containers the cache updates allocate and
// free through the global operator new, which, in a process that routes it here
// (core/large_block_new.cc), must not take the lock again. Such blocks are never the cache's.
thread_local bool t_in_cache = false;

class CacheLock {
 public:
  explicit CacheLock(std::mutex& mutex) : lock_(mutex) { t_in_cache = true; }
  ~CacheLock() { t_in_cache = false; }
  CacheLock(const CacheLock&) = delete;
  CacheLock& operator=(const CacheLock&) = delete;

 private:
  std::lock_guard<std::mutex> lock_;
};

}  // namespace

size_t LargeBlockCache::Run::bytes() const {
  size_t sum = 0;
  for (const size_t piece : pieces) sum += piece;
  return sum;
}

LargeBlockCache::Run LargeBlockCache::Run::SplitTail(size_t at) {
  Run tail;
  tail.addr = addr + at;
  size_t offset = 0;
  size_t k = 0;
  while (offset + pieces[k] <= at) offset += pieces[k++];
  // Piece k holds byte `at`: its part from `at` on opens the tail.
  if (offset < at) {
    tail.pieces.push_back(offset + pieces[k] - at);
    pieces[k] = at - offset;
    ++k;
  }
  tail.pieces.insert(tail.pieces.end(), pieces.begin() + static_cast<std::ptrdiff_t>(k),
                     pieces.end());
  pieces.resize(k);
  return tail;
}

void LargeBlockCache::Unmap(const Run& run) {
  if (run.addr && !run.pieces.empty()) ::munmap(run.addr, run.bytes());
}

LargeBlockCache::LargeBlockCache(size_t cache_limit_bytes)
    : cache_limit_(cache_limit_bytes / PageSize() * PageSize()) {}

LargeBlockCache::~LargeBlockCache() {
  for (const Run& run : cached_) Unmap(run);
  for (const auto& [p, run] : live_) Unmap(run);
}

void* LargeBlockCache::Allocate(size_t bytes) {
  if (bytes == 0 || bytes > SIZE_MAX / 2 || t_in_cache) return nullptr;
  const size_t n = RoundUpToPages(bytes);
  const CacheLock lock(mutex_);
  // Takes cached_[i] out of the cache, leaving its part beyond `need` bytes there.
  const auto take = [&](size_t i, size_t need) {
    Run run = std::move(cached_[i]);
    cached_.erase(cached_.begin() + static_cast<std::ptrdiff_t>(i));
    const size_t run_bytes = run.bytes();
    stats_.cached_bytes -= run_bytes;
    if (run_bytes > need) {
      Run tail = run.SplitTail(need);
      stats_.cached_bytes += run_bytes - need;
      cached_.push_back(std::move(tail));
    }
    return run;
  };
  // The smallest cached run that holds the block: used where it is.
  size_t best = cached_.size();
  for (size_t i = 0; i < cached_.size(); ++i) {
    const size_t b = cached_[i].bytes();
    if (b >= n && (best == cached_.size() || b < cached_[best].bytes())) best = i;
  }
  Run block;
  if (best < cached_.size()) {
    block = take(best, n);
    stats_.reused_bytes += n;
  } else {
    // A fresh mapping, its start replaced by the cached runs' pages (largest first, so that
    // fewer pieces move), the rest left to fault in.
    block.addr = static_cast<char*>(MapFresh(n));
    if (!block.addr) return nullptr;
    size_t filled = 0;
    while (filled < n && !cached_.empty()) {
      size_t largest = 0;
      for (size_t i = 1; i < cached_.size(); ++i)
        if (cached_[i].bytes() > cached_[largest].bytes()) largest = i;
      const Run source = take(largest, n - filled);
      char* from = source.addr;
      for (const size_t piece : source.pieces) {
        void* to = ::mremap(from, piece, piece, MREMAP_MAYMOVE | MREMAP_FIXED, block.addr + filled);
        if (to == MAP_FAILED) {  // not expected; the target pages stay fresh
          ::munmap(from, piece);
          stats_.unmapped_bytes += piece;
        } else {
          block.pieces.push_back(piece);
          filled += piece;
          stats_.moved_bytes += piece;
        }
        from += piece;
      }
    }
    if (filled < n) {
      block.pieces.push_back(n - filled);  // the rest of the fresh mapping: one piece
      stats_.fresh_bytes += n - filled;
    }
  }
  stats_.live_bytes += n;
  void* p = block.addr;
  live_.emplace(p, std::move(block));
  return p;
}

bool LargeBlockCache::Free(void* p) {
  if (!p || reinterpret_cast<uintptr_t>(p) % PageSize() != 0 || t_in_cache) return false;
  Run unmap;  // unmapped outside the lock
  {
    const CacheLock lock(mutex_);
    const auto it = live_.find(p);
    if (it == live_.end()) return false;
    Run run = std::move(it->second);
    live_.erase(it);
    const size_t run_bytes = run.bytes();
    stats_.live_bytes -= run_bytes;
    const size_t room = cache_limit_ - stats_.cached_bytes;  // page multiple
    if (run_bytes > room) {
      if (room == 0)
        unmap = std::move(run);
      else
        unmap = run.SplitTail(room);
      stats_.unmapped_bytes += run_bytes - room;
    }
    if (!run.pieces.empty()) {
      stats_.cached_bytes += run.bytes();
      cached_.push_back(std::move(run));
    }
  }
  Unmap(unmap);
  return true;
}

void LargeBlockCache::Trim() {
  std::vector<Run> unmap;
  {
    const CacheLock lock(mutex_);
    unmap.swap(cached_);
    stats_.unmapped_bytes += stats_.cached_bytes;
    stats_.cached_bytes = 0;
  }
  for (const Run& run : unmap) Unmap(run);
}

LargeBlockCache::Stats LargeBlockCache::stats() const {
  const CacheLock lock(mutex_);
  return stats_;
}

void EnableProcessLargeBlockCache(size_t cache_limit_bytes) {
  static std::once_flag once;
  // Never deleted: blocks may be freed by static destructors at exit.
  std::call_once(once, [&] { g_process_cache.store(new LargeBlockCache(cache_limit_bytes)); });
}

LargeBlockCache* ProcessLargeBlockCache() {
  return g_process_cache.load(std::memory_order_acquire);
}

void* LargeBlockAllocate(size_t bytes) {
  if (LargeBlockCache* cache = ProcessLargeBlockCache()) return cache->Allocate(bytes);
  return bytes ? MapFresh(bytes) : nullptr;
}

void LargeBlockFree(void* p, size_t bytes) {
  if (!p) return;
  if (LargeBlockCache* cache = ProcessLargeBlockCache(); cache && cache->Free(p)) return;
  ::munmap(p, bytes);
}

}  // namespace mesoscan
