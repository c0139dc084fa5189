#pragma once
// A scan folder's content made without the rig, for tests and benchmarks: a surface z(x, y)
// sampled directly on a height grid (by default the paper rig's full 2176 x 1434 camera grid of
// 55 um), with Gaussian noise, normals from the grid and an empty points.exr. Fast (no rendering,
// no reconstruction); the virtual rig (sim/virtual_rig.h) makes the realistic scans.

#include <cstdint>
#include <functional>

#include "core/scan_folder.h"

namespace mesoscan {

struct SyntheticScanOptions {
  int width = 2176, height = 1434;  // grid size (pixels), centred on the world origin
  double pixel_size_m = 55e-6;
  // Each pixel's height is the mean of supersample x supersample samples over its footprint
  // (a camera pixel integrates its footprint: steep steps become one-pixel ramps), >= 1.
  int supersample = 1;
  double noise_m = 1e-6;     // Gaussian noise added to every height (metres), >= 0
  uint64_t seed = 1;         // the noise's seed
  float confidence = 0.95f;  // of every sampled pixel (0 where the surface is NaN)
  // report.json summary.predicted_depth_rms_m; 0: not written (a scan without a prediction).
  double predicted_depth_rms_m = 1e-6;
};

// `surface(x, y)`: the height (world metres) at world (x, y); NaN where the scan has no sample.
// It is called from several threads.
Scan SyntheticScan(const std::function<double(double x, double y)>& surface,
                   const SyntheticScanOptions& options = {});

}  // namespace mesoscan
