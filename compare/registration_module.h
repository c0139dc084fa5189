#pragma once
// Open3D's registration behind a module loaded on first use (core/module.h:
// libmesoscan_open3d.so, built from compare/registration_module.cc): Open3D links ~100 shared
// libraries that no other command needs. Coarse alignment by FPFH features and RANSAC (with the
// identity and the caller's starts, or a sweep of rotations about z, as further starts; the
// best-fitting refinement kept),
// then robust point-to-plane ICP (Tukey's kernel), then the points beyond 3 robust sigmas excluded
// and a refit (a changed area must not pull the registration).

#include <cstdint>
#include <functional>
#include <vector>

#include "core/transform.h"

namespace mesoscan {

struct RegistrationInput {
  // Target A and source B: points (world metres) with unit normals.
  std::vector<Vec3d> a_points, a_normals, b_points, b_normals;
  double voxel_m = 0;         // coarse voxel (features, RANSAC), > 0
  double max_distance_m = 0;  // fine correspondences' largest distance, > 0
  int seed = 1;               // RANSAC's random seed
  // Further starts for the coarse alignment (B's world to A's), e.g. from the height images
  // (compare/planar_alignment.h): refined and scored with RANSAC's. When empty, rotations about
  // z every 10 degrees are tried instead (slower).
  std::vector<Mat4d> starts;
  // Optional: whether A has a measured surface under a point (A's world metres). When given, the
  // fine registration uses only B's points that land on A's surface (re-checked as the transform
  // moves): B's points over A's holes (shadows A did not see, and that B saw or filled) would
  // pair with A's points at the holes' edges, one-sided pairs that pull the transform.
  std::function<bool(const Vec3d&)> a_has_surface;
  // Refined hypotheses turning B by more than this (degrees) are not kept: a placement known
  // to within a few degrees (a mosaic's tiles) is not traded for a better-scoring wrong match of
  // a repetitive relief. 180: any.
  double max_rotation_deg = 180;
  // Iterations of each robust fine ICP stage at most (a narrow overlap slides slowly into
  // place along its relief's slopes).
  int fine_iterations = 30;
};

struct RegistrationOutput {
  Mat4d b_to_a = Mat4d::Identity();
  double coarse_fitness = 0, coarse_rmse_m = 0;  // RANSAC's, at the voxel scale
  double coarse_icp_fitness = 0;                 // after the coarse point-to-plane refinement
  int coarse_hypotheses = 0;  // starts refined and scored (RANSAC seeds, identity, rotations)
  double robust_sigma_m = 0;  // 1.4826 MAD of the point-to-plane residuals at the solution
  int64_t b_on_a = 0;         // B's points on A's surface (a_has_surface; all without it)
  int64_t b_inliers = 0;      // of those, within 3 robust sigmas (the final fit's)
  // The final fit's normal equations at the solution, for the uncertainty: J^T J of the
  // residuals' derivatives by a correction (rx, ry, rz, tx, ty, tz) applied after b_to_a, the sum
  // of squared inlier residuals and their count.
  Eigen::Matrix<double, 6, 6> jtj = Eigen::Matrix<double, 6, 6>::Zero();
  double sum_squares = 0;
  int64_t inliers = 0;
  double seconds_coarse = 0, seconds_fine = 0;
};

// A mesh seen from above on a regular x-y grid (the layout of core/height_field.h).
struct MeshRaster {
  int width = 0, height = 0;
  double x0 = 0, y0 = 0, pixel_size = 0;
  std::vector<float> z;  // row-major, metres; NaN where no triangle lies under the pixel
  int64_t triangles = 0;
};

class RegistrationModule {
 public:
  virtual ~RegistrationModule() = default;
  virtual RegistrationOutput Register(const RegistrationInput& input) const = 0;
  // Reads a triangle mesh (PLY, STL, OBJ: metres, z up; glTF/GLB: metres, +Y up, as export
  // writes it) and sees it from above on a grid of `pixel_size_m` covering its x-y extent: the
  // mean height of dense uniform samples of its top layer in each pixel. Throws Error(kBadInput)
  // naming the file if it cannot be read, has no triangles, or would need more than 50 M pixels.
  virtual MeshRaster RasterMesh(const std::string& path, double pixel_size_m) const = 0;
};

// The module, loaded on the first call. Throws Error(kInternal) if it cannot be loaded.
const RegistrationModule& Registration();

}  // namespace mesoscan
