#include "heightfield/stage_classify.h"

#include <limits>

#include "core/error.h"
#include "core/image_io.h"

namespace mesoscan {

PixelClasses ClassifyPixels(const FrameStack& stack, const ReconstructPlan& plan, int camera_width,
                            int camera_height, const ClassifyOptions& options) {
  const RoiGrid grid = RoiGrid::Of(stack);
  const size_t np = grid.pixels();
  const int w = grid.width, h = grid.height;
  PixelClasses c;
  c.state.assign(np, PixelState::kActive);
  c.white_level.assign(np, std::numeric_limits<float>::quiet_NaN());
  c.black_value.assign(np, 0.0f);
  if (!options.mask_path.empty()) {
    ImageInfo info;
    const ImageF mask = ReadImageGrey(options.mask_path, &info);
    if (mask.width() != camera_width || mask.height() != camera_height)
      MESOSCAN_BAD_INPUT(options.mask_path << ": size " << mask.width() << "x" << mask.height()
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

}  // namespace mesoscan
