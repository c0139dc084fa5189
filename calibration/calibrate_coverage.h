#pragma once
// Where a calibration's corners lie in each device's image (`mesoscan calibrate`: coverage in
// report.json and the advice line; the calibrated region a rig file carries so that scans can
// mark the points where the lens model extrapolates).
//
// The calibrated region of a device is the union of the views' corner hulls (convex hull of
// each view's corners in that device's pixels). Coverage is the share of the device's useful
// field that the region covers, the field being the pixels that see (camera) or light
// (projector) a point seen by the other device on the boards' mean plane; the field is cut in
// 3 x 3 blocks, and an outer block less than half covered is named in the advice.

#include <string>
#include <vector>

#include "core/camera.h"
#include "core/json.h"

namespace mesoscan {

// Convex polygons in one device's pixels (pixel centres at integers).
struct CalibratedRegion {
  int width = 0, height = 0;
  std::vector<std::vector<Vec2d>> hulls;
  bool empty() const { return hulls.empty(); }
  bool Contains(const Vec2d& px) const;
  Json ToJson() const;  // {"width", "height", "hulls": [[[x, y], ...], ...]}
  // Throws Error(kBadInput) naming `where` on a malformed object.
  static CalibratedRegion FromJson(const Json& j, const std::string& where);
};

// The convex hull of the finite points (empty if fewer than 3).
std::vector<Vec2d> ConvexHull(const std::vector<Vec2d>& points);

struct DeviceCoverage {
  std::string device;                // "camera" or "projector"
  double fraction = 0;               // of the field covered by the region
  double median_view_fraction = 0;   // one view's hull over the field (the board's size)
  std::vector<std::string> missing;  // outer blocks under half covered: "left", "top right"...
  bool poor = false;                 // fraction below the threshold or a side uncovered
  std::string advice;                // one line: what the corners cover and what to capture next
  Json ToJson() const;
};

// `field(px)`: whether pixel px belongs to the device's useful field. Cells of ~1/64 of the
// larger side. `poor_below`: coverage fraction under which coverage is poor.
template <typename Field>
DeviceCoverage MeasureCoverage(const std::string& device, const CalibratedRegion& region,
                               Field&& field, double poor_below);

// Implementation detail of MeasureCoverage (the field as a mask over the cells).
struct CoverageCells {
  int cols = 0, rows = 0;
  double cell = 1;
  std::vector<uint8_t> field;
};
DeviceCoverage MeasureCoverageCells(const std::string& device, const CalibratedRegion& region,
                                    const CoverageCells& cells, double poor_below);

template <typename Field>
DeviceCoverage MeasureCoverage(const std::string& device, const CalibratedRegion& region,
                               Field&& field, double poor_below) {
  CoverageCells c;
  c.cell = std::max(region.width, region.height) / 64.0;
  c.cols = std::max(1, static_cast<int>(std::ceil(region.width / c.cell)));
  c.rows = std::max(1, static_cast<int>(std::ceil(region.height / c.cell)));
  c.field.assign(static_cast<size_t>(c.cols) * c.rows, 0);
  for (int j = 0; j < c.rows; ++j)
    for (int i = 0; i < c.cols; ++i) {
      const Vec2d px((i + 0.5) * c.cell - 0.5, (j + 0.5) * c.cell - 0.5);
      c.field[static_cast<size_t>(j) * c.cols + i] =
          px.x() < region.width && px.y() < region.height && field(px);
    }
  return MeasureCoverageCells(device, region, c, poor_below);
}

}  // namespace mesoscan
