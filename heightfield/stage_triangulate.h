#pragma once
// Reconstruction stage 7, triangulate: the camera ray of every kActive pixel intersected with the
// projector plane of its column u (heightfield/triangulate.h, distortion on both devices), into
// the scan's points on the camera grid (scan-outputs.md points.exr), and the predicted depth
// sigma sigma_u |dZ/du| (dZ/du by a forward difference of half a projector pixel). Moves pixels
// to kOk or kNoIntersection.

#include <vector>

#include "core/image.h"
#include "core/scan_folder.h"
#include "heightfield/pixel_buffers.h"
#include "session/session.h"

namespace mesoscan {

struct TriangulateOptions {
  bool keep_dz_du = false;  // fill TriangulatedPoints::dz_du (diagnostics)
  char axis = 'x';  // the decoded projector axis (ReconstructPlan::axis): u is a row for 'y'
};

struct TriangulatedPoints {
  ScanPoints points;           // camera grid: xyz (NaN = none), confidence, projector_u
  std::vector<float> sigma_z;  // ROI grid: predicted depth sigma, m; NaN where unknown
  ImageF dz_du;                // camera grid, m per projector px (keep_dz_du only)
};

TriangulatedPoints TriangulatePoints(const Rig& rig, const RoiGrid& grid,
                                     const CombinedPixels& combined,
                                     const TriangulateOptions& options, PixelStates* state);

}  // namespace mesoscan
