#pragma once
// Parallel loops over rows and tiles (TBB). Work functions must not allocate per pixel.

#include <tbb/blocked_range.h>
#include <tbb/blocked_range2d.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include <memory>

namespace mesoscan {

// fn(y_begin, y_end) over row blocks of `grain` rows.
template <typename Fn>
void ParallelForRows(int height, Fn&& fn, int grain = 8) {
  tbb::parallel_for(tbb::blocked_range<int>(0, height, grain),
                    [&](const tbb::blocked_range<int>& r) { fn(r.begin(), r.end()); });
}

// fn(x0, x1, y0, y1) over tiles of about tile x tile pixels.
template <typename Fn>
void ParallelForTiles(int width, int height, Fn&& fn, int tile = 64) {
  tbb::parallel_for(tbb::blocked_range2d<int>(0, height, tile, 0, width, tile),
                    [&](const tbb::blocked_range2d<int>& r) {
                      fn(r.cols().begin(), r.cols().end(), r.rows().begin(), r.rows().end());
                    });
}

// fn(i) for i in [0, n).
template <typename Fn>
void ParallelFor(int64_t n, Fn&& fn, int64_t grain = 1) {
  tbb::parallel_for(tbb::blocked_range<int64_t>(0, n, grain),
                    [&](const tbb::blocked_range<int64_t>& r) {
                      for (int64_t i = r.begin(); i != r.end(); ++i) fn(i);
                    });
}

// Limits TBB to n threads while alive (n <= 0: no limit). The CLI's --threads.
class ThreadLimit {
 public:
  explicit ThreadLimit(int n) {
    if (n > 0)
      control_ = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                       static_cast<size_t>(n));
  }

 private:
  std::unique_ptr<tbb::global_control> control_;
};

}  // namespace mesoscan
