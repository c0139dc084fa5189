#include "heightfield/stage_mixed_pixels.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <atomic>
#include <limits>

#include "heightfield/resample.h"

namespace mesoscan {

int64_t RejectMixedPixels(const RoiGrid& grid, const std::vector<float>& white_level,
                          const std::vector<float>& sigma_z, const MixedPixelOptions& options,
                          ScanPoints* points, PixelStates* state_out) {
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  PixelStates& state = *state_out;
  const int w = grid.width;
  const size_t np = grid.pixels();
  const PixelRect& roi = grid.roi;
  std::vector<float> z;
  std::vector<uint8_t> unlit;
  tbb::parallel_for<int64_t>(0, 2,
                             [&](int64_t a) {  // one array per task (their page faults and fills)
                               if (a == 0)
                                 z.assign(np, kNaN);
                               else
                                 unlit.assign(np, 0);
                             });
  tbb::parallel_for(tbb::blocked_range<int>(0, grid.height, 8), [&](const auto& range) {
    const int y0 = range.begin(), y1 = range.end();
    for (int y = y0; y < y1; ++y)
      for (int x = 0; x < w; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        if (state[i] == PixelState::kOk) z[i] = points->xyz(x + roi.x, y + roi.y, 2);
        unlit[i] = state[i] == PixelState::kUnlit || state[i] == PixelState::kUnmodulated;
      }
  });
  MixedPixelInput in;
  in.width = w;
  in.height = grid.height;
  in.z = z.data();
  in.sigma_z = sigma_z.data();
  in.white = white_level.data();
  in.unlit = unlit.data();
  in.footprint_m = CameraFootprint(points->xyz);
  const std::vector<uint8_t> reject = FindMixedPixels(in, options);
  std::atomic<int64_t> n{0};
  tbb::parallel_for(tbb::blocked_range<int>(0, grid.height, 8), [&](const auto& range) {
    const int y0 = range.begin(), y1 = range.end();
    int64_t rows_n = 0;
    for (int y = y0; y < y1; ++y)
      for (int x = 0; x < w; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        if (!reject[i]) continue;
        ++rows_n;
        state[i] = PixelState::kDiscontinuity;
        const int cx = x + roi.x, cy = y + roi.y;
        for (int c = 0; c < 3; ++c) points->xyz(cx, cy, c) = kNaN;
        points->confidence(cx, cy) = 0.0f;
        if (!points->source.empty()) points->source(cx, cy) = kNaN;
      }
    n += rows_n;
  });
  return n.load();
}

}  // namespace mesoscan
