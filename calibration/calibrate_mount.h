#pragma once
// The mount plane from a session of the empty mount, and the scan of a flat
// target with a rig held in memory that it and the lens-shifter calibration
// (calibration/calibrate_shifter.h) share.
//
// `mesoscan calibrate ... --mount SESSION`: a session of a board lying on the mount defines the
// world by that board (calibration/calibrate.h); a session of the empty mount (no board: sines
// and/or lens-shift frames on the bare mount) is decoded and triangulated with the calibrated
// camera and projector by the reconstruction's own pipeline (heightfield/reconstruct.h
// ReconstructPoints, stages 0-8), a plane is fitted robustly to the points, and the world becomes:
// z = 0 on that plane, +z towards the rig (docs/formats.md "Conventions"); x along
// the camera's x axis projected onto the plane, y = z cross x, the origin where the camera's
// optical axis meets the plane (a camera looking straight down gives the paper rig's world).

#include <cstdint>
#include <string>
#include <vector>

#include "core/json.h"
#include "core/scan_folder.h"
#include "core/transform.h"
#include "heightfield/pixel_buffers.h"
#include "session/session.h"

namespace mesoscan {

// A flat target scanned with a rig in memory.
struct FlatTargetScan {
  RoiGrid grid;                     // the camera grid (whole image)
  ImageF xyz;                       // camera grid, rig-world metres; NaN where no point
  std::vector<float> ls_frequency;  // per pixel: the lens-shift profile's own fitted frequency
                                    // (cycles per nominal projector px); empty without lens shift
  double ls_period_px = 2;          // the stripes' period (projector px)
  int lens_shift_frames = 0;
  // Camera grid: the triangulation's predicted depth sigma of each point (m, from the lens-shift
  // residuals), NaN where no point.
  std::vector<float> sigma_z;
  int64_t points = 0;  // pixels with a point
  double seconds = 0;
};

// Runs the reconstruction pipeline (heightfield/reconstruct.h ReconstructPoints: plan to mixed
// pixels) on `session` with `rig` instead of the session's own rig (whose device
// sizes must match; its lens_shifter is used for the shift positions). With lens-shift frames,
// the 4-parameter profile fit runs on every pixel (the per-pixel frequency is kept) instead of
// the smoothed frequency map. Throws Error(kBadInput) naming the session if its sizes differ or
// its frames cannot decode.
FlatTargetScan ScanFlatTarget(const Session& session, const Rig& rig);

struct MountPlaneOptions {
  // Points farther than this many robust sigmas (1.4826 MAD) from the plane are rejected, > 1.
  double reject_sigmas = 4.0;
  int rounds = 4;
  // At least this many points must remain (else bad input: not a flat, lit mount).
  int64_t min_points = 1000;
  size_t max_samples = 400000;  // points used for the fit (a regular subsample)
};

struct MountPlane {
  std::string session;
  Vec3d normal = Vec3d::UnitZ();  // unit, in the rig's world used for the scan, towards the rig
  double offset = 0;              // plane: normal . x = offset
  int64_t points = 0, inliers = 0;
  double rms_m = 0;             // RMS distance of the inliers from the plane
  double robust_sigma_m = 0;    // 1.4826 MAD of the distances
  double normal_sigma_rad = 0;  // 1-sigma of the normal's direction (least-squares covariance)
  double offset_sigma_m = 0;    // 1-sigma of the plane at the points' centroid
  // The noise's share (FlatTargetScan::sigma_z over the inliers): RMS of the predicted sigmas,
  // and RMS of distance / predicted sigma (1 for points as good as the noise allows along the
  // ray; the plane's normal is within a few degrees of it); 0 without sigmas.
  double predicted_rms_m = 0;
  double rms_over_predicted = 0;
  double seconds = 0;
  Json ToJson() const;
};

// Fits the plane to the points of a flat-target scan (robust least squares).
MountPlane FitMountPlane(const FlatTargetScan& scan, const Rig& rig,
                         const MountPlaneOptions& options);

// The warning line when the mount's points scatter about the plane by more than `factor` times
// the noise the reconstruction predicts for them (RMS of distance / predicted sigma: the rig bends
// a flat surface), else "".
std::string MountFlatnessWarning(const MountPlane& plane, double factor = 3.0);

// world_from_camera for the plane (z = 0 on it, +z towards the camera; x along the camera's x
// projected onto the plane; origin on the camera's optical axis). `plane` is in the world of
// `rig`; the result is in the same units, as a new world_from_device for the camera.
Rigid3d MountWorldFromCamera(const MountPlane& plane, const Rig& rig);

// The rig with its world moved onto the plane (both devices keep their relative pose).
Rig RigOnMount(const Rig& rig, const MountPlane& plane);

// True if `session` holds sine frames along both projector axes at shift 0 (a board view can be
// detected in it); an empty-mount session need not.
bool HasBoardPatterns(const Session& session);

}  // namespace mesoscan
