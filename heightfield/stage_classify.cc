#include "heightfield/stage_classify.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <limits>

#include "core/error.h"
#include "core/image_io.h"

namespace mesoscan {

void ClassifyOptions::Check() const {
  if (!(min_lit > 0)) MESOSCAN_BAD_INPUT("min_lit: expected > 0, got " << min_lit);
}

PixelClasses ClassifyPixels(const FrameStack& stack, const ReconstructPlan& plan, int camera_width,
                            int camera_height, const ClassifyOptions& options) {
  const RoiGrid grid = RoiGrid::Of(stack);
  const size_t np = grid.pixels();
  const int w = grid.width, h = grid.height;
  PixelClasses c;
  c.min_lit = options.min_lit;
  c.state.assign(np, PixelState::kActive);
  c.white_level.assign(np, std::numeric_limits<float>::quiet_NaN());
  c.black_value.assign(np, 0.0f);
  if (!options.mask_path.empty()) {
    ImageInfo info;
    const ImageF mask = ReadImageGrey(options.mask_path, &info);
    if (mask.width() != camera_width || mask.height() != camera_height)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(options.mask_path),
                            "size " << mask.width() << "x" << mask.height()
                                    << ", expected the camera's " << camera_width << "x"
                                    << camera_height);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        if (!(mask(x + grid.roi.x, y + grid.roi.y) > 0))
          c.state[static_cast<size_t>(y) * w + x] = PixelState::kOutside;
  }
  for (size_t i = 0; i < np; ++i) {
    if (c.state[i] == PixelState::kOutside) continue;
    ++c.pixels_roi;
    if (stack.saturated()[i]) {
      c.state[i] = PixelState::kSaturated;
      ++c.pixels_saturated;
      continue;
    }
    if (plan.black >= 0) c.black_value[i] = stack.Value(plan.black, i);
    if (plan.has_white()) {
      c.white_level[i] = stack.Value(plan.white, i) - c.black_value[i];
      if (!(c.white_level[i] >= options.min_lit)) c.state[i] = PixelState::kUnlit;
    }
  }
  return c;
}

int64_t ClassifyLateSaturation(const FrameStack& stack, PixelStates* classified_out,
                               PixelClasses* classes) {
  PixelStates& classified = *classified_out;
  PixelStates& state = classes->state;
  // Per block of pixels on the pool (right after the last frame; the count is a sum).
  constexpr size_t kBlock = 1 << 16;
  const size_t np = state.size();
  std::atomic<size_t> saturated{0};
  tbb::parallel_for<int64_t>(0, static_cast<int64_t>((np + kBlock - 1) / kBlock), [&](int64_t b) {
    size_t n_sat = 0;
    const size_t end = std::min(np, static_cast<size_t>(b + 1) * kBlock);
    for (size_t i = static_cast<size_t>(b) * kBlock; i < end; ++i) {
      if (stack.saturated()[i] && classified[i] != PixelState::kOutside &&
          classified[i] != PixelState::kSaturated) {
        classified[i] = state[i] = PixelState::kSaturated;  // saturation is checked first
        ++n_sat;
        classes->white_level[i] = std::numeric_limits<float>::quiet_NaN();
        classes->black_value[i] = 0.0f;
      }
    }
    saturated += n_sat;
  });
  classes->pixels_saturated += static_cast<int64_t>(saturated);
  return static_cast<int64_t>(saturated);
}

}  // namespace mesoscan
