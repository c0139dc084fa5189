#pragma once
// Reconstruction stage 8, mixed pixels (heightfield/mixed_pixels.h): kOk points at depth steps
// and shadow edges are removed from the scan's points (NaN, confidence 0) and moved to
// kDiscontinuity.

#include <vector>

#include "core/scan_folder.h"
#include "heightfield/mixed_pixels.h"
#include "heightfield/pixel_buffers.h"

namespace mesoscan {

// white_level, sigma_z: ROI grid (PixelClasses, TriangulatedPoints). Returns the pixels rejected.
int64_t RejectMixedPixels(const RoiGrid& grid, const std::vector<float>& white_level,
                          const std::vector<float>& sigma_z, const MixedPixelOptions& options,
                          ScanPoints* points, PixelStates* state);

}  // namespace mesoscan
