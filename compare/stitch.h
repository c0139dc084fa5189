#pragma once
// Stitching overlapping scans of an object larger than one field (docs/stitch.md): each pair of
// overlapping scans registered on its overlap (compare/registration_module.h: FPFH + RANSAC,
// robust point-to-plane ICP), the poses then solved together (a pose graph, Ceres, each edge
// weighted by its point-to-plane information), and the scans blended into one height field on
// a common grid (weights = confidence times a ramp falling to zero at each scan's border: no
// seams), with normals, confidence and albedo.

#include <filesystem>
#include <string>
#include <vector>

#include "core/json.h"
#include "core/scan_folder.h"
#include "core/transform.h"

namespace mesoscan {

struct StitchOptions {
  // Nominal placement of each scan in the mosaic (metres, x, y): scan k's world point p lies
  // near mosaic point p + offset_k (the object was moved by -offset_k under the field). Empty:
  // all zero. Registration corrects re-placements of a few mm and degrees about it.
  std::vector<Vec2d> offsets_m;
  // Border ramp: a scan's weight rises from 0 at its grid's border to 1 over this fraction of
  // its smaller side (smoothstep), in (0, 0.5].
  double feather = 0.12;
  // Points with a confidence below this do not register, in [0, 1).
  double min_confidence = 0.5;
  // Pairs are registered where their nominal footprints overlap by at least this fraction of
  // the smaller scan's area.
  double min_overlap = 0.15;
  // A pair's registration (the relative re-placement of its two scans: up to twice one scan's)
  // is kept only if its correction of the nominal placement is within these (a wrong match of a
  // repetitive relief is refused, not averaged in), and its inlier RMS within 3x the median of
  // the pairs'. The registration searches within them.
  double max_correction_deg = 10.0;
  double max_correction_fraction = 0.4;  // displacement, of the smaller side of the pair's B
  // false: the plain mosaic (scans placed at their nominal offsets, no registration).
  bool register_scans = true;
  int max_icp_points = 60000;  // per scan and pair (evenly subsampled), >= 1000
  void Check() const;
};

struct StitchResult {
  Scan scan;                            // height (Z, confidence), normals; report
  ImageF albedo;                        // on the height grid (1 channel), empty if no scan had one
  std::vector<Mat4d> mosaic_from_scan;  // per input: its world to the mosaic's
  std::string BriefReport() const;
};

// Stitches `scans` (names: their folders, for messages and the report). Throws Error(kBadInput)
// naming a scan that has too few confident points or overlaps no other one, Error(kUsage) for
// bad options.
StitchResult StitchScans(const std::vector<Scan>& scans, const std::vector<std::string>& names,
                         const StitchOptions& options);

// The scan folder (height.exr and normal.exr tiled 64 x 64 with MIP levels, points.exr on the
// grid, albedo.exr when there is an albedo, report.json) into `dir` (which must exist).
void WriteStitchedScan(const std::filesystem::path& dir, const StitchResult& result);

}  // namespace mesoscan
