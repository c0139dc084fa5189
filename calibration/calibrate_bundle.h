#pragma once
// The bundle adjustment behind `mesoscan calibrate` (calibration/calibrate.h): camera, projector,
// their relative pose and every board pose from the board corners seen by both devices; the
// camera models it can fit (a ladder of distortion terms, the principal point free or at the
// image centre, fx = fy or not); leave-one-view-out validation (the rig fitted without a view,
// that view's corners reprojected and its board triangulated as a scan would: camera ray against
// the projector column) and the choice of each device's model by it; the plain OpenCV calibration
// (Moreno & Taubin 2012: calibrateCamera per device, stereoCalibrate) on the same corners, for
// the baseline figures.

#include <array>
#include <string>
#include <vector>

#include "calibration/calibrate_board.h"
#include "core/camera.h"
#include "core/json.h"
#include "core/transform.h"

namespace mesoscan {

struct CalibrationView;

// A pose as the adjustment stores it (angle-axis, rad, then translation, m) as a transform.
Rigid3d PoseFromArray(const double* a);

// Which parameters of one device the adjustment fits; the others are held (distortion terms at
// 0, the principal point at the image centre ((W - 1) / 2, (H - 1) / 2), fy at fx).
struct DeviceModel {
  // Distortion terms (bits): k1, k2, the tangential pair p1 p2, k3 (OpenCV's order k1 k2 p1 p2 k3).
  enum Term : unsigned { kK1 = 1, kK2 = 2, kTangential = 4, kK3 = 8 };
  unsigned terms = kK1 | kK2 | kTangential | kK3;
  bool free_principal_point = true;
  bool equal_focal = false;         // fx = fy (square pixels)
  int FreeParameters() const;       // intrinsics and distortion terms fitted
  std::string ToString() const;     // "k1 k2, principal point free, fx = fy"
  std::string TermsString() const;  // "none", "k1", "k1 k2", "k1 k2 p1 p2", "k1 k2 p1 p2 k3"
  Json ToJson() const;
  bool operator==(const DeviceModel& o) const {
    return terms == o.terms && free_principal_point == o.free_principal_point &&
           equal_focal == o.equal_focal;
  }
};

// One device's parameters: intrinsics {fx, fy, cx, cy} (px), distortion {k1, k2, p1, p2, k3}.
struct DeviceParams {
  std::array<double, 4> intr{};
  std::array<double, 5> dist{};
  int width = 0, height = 0;
  // The model's held values: terms outside it set to 0, the principal point to the centre if
  // not free, fy to fx if equal.
  void Apply(const DeviceModel& model);
  PinholeCamera Camera() const;  // world_from_device = identity
};

// Everything the adjustment solves for. Poses are angle-axis (rad) then translation (m).
struct BundleParams {
  DeviceParams cam, prj;
  std::array<double, 6> prj_from_cam{};
  std::vector<std::array<double, 6>> cam_from_board;  // per view of the adjustment
  Rigid3d PrjFromCam() const;
  // Camera at the world origin (world = camera frame), projector at prj_from_cam.
  PinholeCamera CameraInCameraFrame() const;
  PinholeCamera ProjectorInCameraFrame() const;
};

struct BundleSolveOptions {
  int max_iterations = 200;
  double tolerance = 1e-14;  // Ceres' function, gradient and parameter tolerances
  // Levenberg-Marquardt's initial trust region: large for a start near the solution (the first
  // steps are then Gauss-Newton's), Ceres' default 1e4 otherwise.
  double initial_trust_region = 1e4;
  int threads = 1;
};

struct BundleSolveSummary {
  bool usable = false;
  double cost = 0;  // 1/2 sum of squared residuals (px^2)
  int residuals = 0, parameters = 0;
  std::string brief;  // Ceres' BriefReport()
};

// Solves for `p` (its values are the start) over `views` but `skip` (-1: none), with the
// devices' models applied first. p->cam_from_board has one pose per view (the skipped one is
// left as it was).
BundleSolveSummary SolveBundle(const std::vector<const CalibrationView*>& views, int skip,
                               const CalibrationBoard& board, const DeviceModel& cam_model,
                               const DeviceModel& prj_model, const BundleSolveOptions& options,
                               BundleParams* p);

// The 1-sigma of every fitted parameter from the linearised least squares at `p` (all views),
// scaled by the residual variance per device (the corners' measured noise), parameter columns
// scaled before the inversion so that ill-conditioned but determined directions are kept.
// Keys: camera / projector {fx, fy, cx, cy, distortion {k1 ...}}, prj_from_cam {rx_rad ...},
// residual_sigma_px {camera, projector}; a held parameter has no entry. Empty on failure.
Json BundleCovariance(const std::vector<const CalibrationView*>& views,
                      const CalibrationBoard& board, const DeviceModel& cam_model,
                      const DeviceModel& prj_model, const BundleParams& p);

// A view left out of the calibration, checked against the rig fitted without it.
struct HeldOutView {
  std::string name;
  // Its board pose fitted with the rig held (both devices' corners), then its corners
  // reprojected: RMS (px) per device and the sum of squared residuals over the noise sigmas.
  double rms_camera_px = 0, rms_projector_px = 0;
  int camera_corners = 0, projector_corners = 0;
  double chi2 = 0;
  // Its corners triangulated as a scan would (camera ray against the projector column u,
  // heightfield/triangulate.h), against the board's known geometry: adjacent-corner distance
  // error (RMS and mean, um), RMS distance from their best plane (um), scale of the best
  // similarity onto the board (scale - 1, percent) and RMS residual after it (um).
  int triangulated = 0;
  double adjacent_rms_um = 0, adjacent_mean_um = 0, flatness_rms_um = 0, scale_error_pct = 0,
         shape_rms_um = 0;
  Json ToJson() const;
};

// Evaluates view `v` with the rig of `p` (its board poses are not used: the view's pose starts
// from solvePnP on its camera corners). sigma_*: the corners' noise per device, px.
HeldOutView EvaluateHeldOut(const CalibrationView& v, const CalibrationBoard& board,
                            const BundleParams& p, double sigma_camera_px,
                            double sigma_projector_px);

// Leave one view out for one pair of models: the fit on all views (started from `start`) and one
// fit per view without it (started from the all-view fit), each held-out view evaluated.
struct CrossValidation {
  DeviceModel cam, prj;
  BundleParams all;
  BundleSolveSummary all_summary;
  std::vector<BundleParams> folds;  // per view: the rig fitted without it
  std::vector<HeldOutView> held_out;
  double chi2 = 0;  // sum over the held-out views
  double Chi2PerResidual() const;
};
CrossValidation CrossValidate(const std::vector<const CalibrationView*>& views,
                              const CalibrationBoard& board, const DeviceModel& cam_model,
                              const DeviceModel& prj_model, const BundleParams& start,
                              double sigma_camera_px, double sigma_projector_px);

// The plain baseline: OpenCV's calibrateCamera for each device (`cv_flags`, e.g.
// cv::CALIB_FIX_K3 | cv::CALIB_ZERO_TANGENT_DIST) and stereoCalibrate with CALIB_FIX_INTRINSIC,
// on the views but `skip`. Throws Error(kBadInput) if OpenCV fails.
BundleParams OpenCvCalibration(const std::vector<const CalibrationView*>& views, int skip,
                               const CalibrationBoard& board, int camera_width, int camera_height,
                               int projector_width, int projector_height, int cv_flags,
                               double* rms_camera = nullptr, double* rms_projector = nullptr,
                               double* rms_stereo = nullptr);

// Leave one view out with OpenCV's calibration (as CrossValidate).
std::vector<HeldOutView> OpenCvCrossValidate(const std::vector<const CalibrationView*>& views,
                                             const CalibrationBoard& board, int camera_width,
                                             int camera_height, int projector_width,
                                             int projector_height, int cv_flags,
                                             double sigma_camera_px, double sigma_projector_px,
                                             std::vector<BundleParams>* folds = nullptr);

// Aggregates of held-out views: RMS over views of each figure's per-view value, max |scale|.
struct HeldOutSummary {
  double rms_camera_px = 0, rms_projector_px = 0, adjacent_rms_um = 0, flatness_rms_um = 0,
         max_abs_scale_error_pct = 0, mean_abs_scale_error_pct = 0;
  int views = 0;
  Json ToJson() const;
};
HeldOutSummary SummariseHeldOut(const std::vector<HeldOutView>& views);

}  // namespace mesoscan
