#pragma once
// The height field on a regular world grid (scan-outputs.md "height.exr") from the per-camera-pixel
// points: neighbouring camera pixels form triangles (two per 2x2 quad of valid points) that are
// rasterised into the grid with barycentric interpolation of z and confidence, keeping the highest
// surface where two overlap (the view from +z). Triangles that span a depth discontinuity (an edge
// much longer than the camera footprint) are dropped, so holes stay NaN and nothing is invented.

#include <vector>

#include "core/height_field.h"
#include "core/image.h"

namespace mesoscan {

struct ResampleOptions {
  // Grid pixel size in metres, >= 0; 0 = the camera footprint (median distance between
  // horizontally neighbouring valid points).
  double pixel_size = 0.0;
  // A triangle whose longest 3-D edge exceeds this many footprints spans a depth
  // discontinuity and is dropped, > 1. 4 keeps surfaces up to ~75 degrees of slope.
  double max_edge_footprints = 4.0;
  void Check() const;
};

// Median spacing (metres) of horizontally adjacent valid points of `xyz` (3 channels, NaN where
// invalid); 0 if there are none.
double CameraFootprint(const ImageF& xyz);
// The element at position n / 2 of the parts joined, as std::nth_element puts it there (the
// upper median); the values must be non-negative and finite. 0 if there are none.
float MedianOfNonNegative(const std::vector<std::vector<float>>& parts);

// `xyz`: camera-grid points (3 channels X, Y, Z, NaN = none); `confidence`: same grid, [0, 1].
// Returns a grid covering the valid points' x-y bounding box. Empty (0x0) if no valid point.
HeightField ResampleToGrid(const ImageF& xyz, const ImageF& confidence,
                           const ResampleOptions& options);

}  // namespace mesoscan
