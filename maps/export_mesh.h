#pragma once
// Triangle mesh of a height field for the GLB export: an error-bounded, crack-free
// right-triangulated irregular network (RTIN: the 4-8 / longest-edge bisection hierarchy of
// Evans, Kirkpatrick & Townsend, "Right-triangulated irregular networks", Algorithmica 30,
// 2001; the bottom-up error propagation of mapbox/martini) over the regular height grid.
//
// No triangle crosses a hole: every triangle whose region holds an unknown (NaN) sample is
// subdivided down to the grid, where triangles with an unknown corner are dropped. With a
// budget large enough (and no tolerance) the mesh is the full grid mesh (two triangles per grid
// cell, every covered sample a vertex); otherwise the split threshold is the smallest that meets
// the budget, and the true maximum height error over every covered sample is measured and
// reported.

#include <cstdint>
#include <vector>

#include "core/height_field.h"

namespace mesoscan {

struct GridMeshOptions {
  // Upper bound on the number of triangles, > 0. Holes force full subdivision along their
  // edges; if that alone exceeds the budget, the mesh keeps those triangles and
  // GridMesh::budget_met is false.
  int64_t max_triangles = 1'000'000;
  // Triangles whose RTIN error is at or below this are never split (metres, >= 0). 0: only the
  // budget limits the mesh.
  double tolerance_m = 0.0;
  void Check() const;
};

struct GridMesh {
  // Grid sample of each vertex: pixel index j * width + i of the height field.
  std::vector<int32_t> vertex_pixel;
  // Three vertex indices per triangle, counter-clockwise seen from +z (world), i.e. with the
  // outward normal pointing up.
  std::vector<uint32_t> indices;
  double threshold_m = 0.0;         // the RTIN split threshold used (metres)
  double max_height_error_m = 0.0;  // measured max |z_sample - mesh| over covered samples
  int64_t lossless_triangles = 0;   // triangles of the lossless mesh (threshold 0)
  int64_t valid_samples = 0;        // finite samples in the height field
  int64_t uncovered_samples = 0;    // finite samples in no triangle (isolated by holes)
  bool budget_met = true;

  int64_t triangles() const { return static_cast<int64_t>(indices.size() / 3); }
  int64_t vertices() const { return static_cast<int64_t>(vertex_pixel.size()); }
};

GridMesh TriangulateHeightField(const HeightField& hf, const GridMeshOptions& options);

}  // namespace mesoscan
