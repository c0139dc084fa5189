#pragma once
// Comparing two scans of one object (docs/compare.md): B registered onto A (features + RANSAC,
// then robust point-to-plane ICP on confident points, Open3D), the signed deviation of B from A
// on A's height grid, the area that changed beyond k sigma of the two scans' own predicted
// noise, and the repeatability figure. Open3D is used only inside this module.

#include <filesystem>
#include <optional>
#include <string>

#include "core/height_field.h"
#include "core/image.h"
#include "core/json.h"
#include "core/scan_folder.h"
#include "core/transform.h"

namespace mesoscan {

struct CompareOptions {
  // Which of A's height-grid pixels are compared (and register): kObject the points higher than
  // mount_clearance_m above the mount plane z = 0 in both scans (a re-placed object moves, its
  // mount does not), kAll every valid point.
  enum class Region { kObject, kAll } region = Region::kObject;
  double mount_clearance_m = 50e-6;
  // Optional masks on A's height grid (same size): `mask` restricts to its nonzero pixels,
  // `exclude` removes its nonzero pixels. Empty: none.
  ImageF mask, exclude;
  // Points with a confidence below this do not register (they are still compared), in [0, 1).
  double min_confidence = 0.5;
  // Change test: a pixel changed if the mean deviation over the window x window pixels around it
  // lies beyond k_sigma times that mean's predicted sigma. k_sigma > 0, window odd >= 1.
  double k_sigma = 3.0;
  int window = 5;
  // Coarse registration voxel in metres; 0: 4 x the larger height-grid pixel, or larger so that
  // A's points fill at most ~20000 voxels.
  double coarse_voxel_m = 0.0;
  // Fine registration: at most this many points of B (evenly subsampled; they cost the ICP's
  // iterations) and four times as many of A (a dense target keeps the point-to-plane fit
  // unbiased on steep relief), >= 1000.
  int max_icp_points = 50000;
  int seed = 1;  // RANSAC's random seed
  void Check() const;
};

struct CompareResult {
  Mat4d b_to_a = Mat4d::Identity();  // B's world to A's world (metres)
  // Covariance of the small rotation (rx, ry, rz, rad) and translation (m) correcting b_to_a,
  // from the final point-to-plane fit.
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
  HeightField grid;  // A's grid (x0, y0, pixel size); z unused
  ImageF deviation;  // signed metres of B from A along A's normal, NaN where not compared
  ImageF sigma;      // its predicted sigma (metres), NaN where not compared
  ImageF changed;    // 1 where changed, 0 where compared and unchanged, NaN where not compared
  Json report;       // report.json
  std::string BriefReport() const;
};

// A scan's predicted depth noise per height-grid pixel (metres): the reconstruction's
// report.json summary.predicted_depth_rms_m where the height is valid; nullopt if the scan
// carries no prediction.
std::optional<double> PredictedSigma(const Scan& scan);

// Another scanner's mesh (PLY, STL, OBJ in metres with z up; glTF/GLB as export writes it) as a
// scan to compare: seen from above on a grid of `pixel_size_m` (the mean height in each
// pixel of dense samples of its top surface, Open3D), confidence 1 where it has a surface, normals
// from that grid, no predicted noise (so no change test). Throws Error(kBadInput) naming the file.
Scan ScanFromMesh(const std::filesystem::path& path, double pixel_size_m);

// Registers b onto a and measures the deviation. Throws Error(kBadInput) naming `a_name` or
// `b_name` for a scan with too few valid points, and when the coarse alignment finds no
// consistent transform.
CompareResult CompareScans(const Scan& a, const Scan& b, const CompareOptions& options,
                           const std::string& a_name = "A", const std::string& b_name = "B");

// deviation.exr (channel Z: signed metres; sigma; changed; the grid attributes), deviation.png
// (a diverging colour scale with legend and scale bar), report.json.
void WriteComparison(const std::filesystem::path& dir, const CompareResult& result);

}  // namespace mesoscan
