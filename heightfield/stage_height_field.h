#pragma once
// Reconstruction stage 9, height field: the camera-grid points resampled onto a regular world
// grid (heightfield/resample.h) and its normals. A scan with no point gets a 1x1 unknown grid,
// which keeps the scan folder's layout.

#include "core/scan_folder.h"
#include "heightfield/resample.h"

namespace mesoscan {

struct HeightFieldResult {
  HeightField height;
  ImageF normals;  // 3 channels on the height grid
};

HeightFieldResult MakeHeightField(const ScanPoints& points, const ResampleOptions& options);

}  // namespace mesoscan
