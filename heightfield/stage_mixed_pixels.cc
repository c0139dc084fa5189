#include "heightfield/stage_mixed_pixels.h"

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
  std::vector<float> z(np, kNaN);
  std::vector<uint8_t> unlit(np, 0);
  for (size_t i = 0; i < np; ++i) {
    const int cx = static_cast<int>(i % w) + roi.x, cy = static_cast<int>(i / w) + roi.y;
    if (state[i] == PixelState::kOk) z[i] = points->xyz(cx, cy, 2);
    unlit[i] = state[i] == PixelState::kUnlit || state[i] == PixelState::kUnmodulated;
  }
  MixedPixelInput in;
  in.width = w;
  in.height = grid.height;
  in.z = z.data();
  in.sigma_z = sigma_z.data();
  in.white = white_level.data();
  in.unlit = unlit.data();
  in.footprint_m = CameraFootprint(points->xyz);
  const std::vector<uint8_t> reject = FindMixedPixels(in, options);
  int64_t n = 0;
  for (size_t i = 0; i < np; ++i) {
    if (!reject[i]) continue;
    ++n;
    state[i] = PixelState::kDiscontinuity;
    const int cx = static_cast<int>(i % w) + roi.x, cy = static_cast<int>(i / w) + roi.y;
    for (int c = 0; c < 3; ++c) points->xyz(cx, cy, c) = kNaN;
    points->confidence(cx, cy) = 0.0f;
    if (!points->source.empty()) points->source(cx, cy) = std::numeric_limits<float>::quiet_NaN();
  }
  return n;
}

}  // namespace mesoscan
