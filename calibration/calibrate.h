#pragma once
// Calibration of a projector-camera rig from sessions of a printed checkerboard or ChArUco board
// (spec "Calibration sessions"; `mesoscan calibrate`).
//
// Per view (one session = one board pose): the board's texture is the white frame or the mean of
// a full phase set; corners by OpenCV's findChessboardCornersSB (or, for ChArUco, the ArUco
// markers and interpolateCornersCharuco) refined with cornerSubPix; the sine frames' gains
// estimated jointly with the pixels' phases; the
// projector (u, v) of every camera pixel in a window around each corner is decoded from the sine
// frames of both axes (heightfield/phase_shift.h), and each corner is taken into the projector by
// a local homography fitted robustly (LMEDS) over that window (Moreno & Taubin, "Simple, accurate,
// and robust projector-camera calibration", 3DIMPVT 2012, Sec. 3). Camera and projector are
// initialised by OpenCV (calibrateCamera, stereoCalibrate: also the plain baseline the report
// shows) and then refined together with every board pose in one Ceres bundle adjustment using
// PinholeCamera::ProjectWithParams (core/camera.h), the model reconstruction uses.

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "calibration/calibrate_board.h"
#include "core/json.h"
#include "core/transform.h"
#include "session/session.h"

namespace mesoscan {

// How the per-frame gains (lamp, shutter) of the sine frames are estimated before decoding: not
// at all, alternating least squares with the offset shared by all sets (frames.h), each set's
// frame means over the view (frame_corrections.h FrameMeanGains), or the joint least squares of
// gains and per-pixel coefficients with the shared offset (default; see the .cc). Measured on
// the virtual rig (tests/calibrate_sim_test's 13 views, 3 phases, 0.5% jitter), projector corner
// error RMS and relative pose error: none 0.047 px, 0.037 mm / 0.039 deg; alternating 0.036 px,
// 0.043 mm / 0.023 deg; frame means 35 px (the one-period sets' stripes do not average out over
// a view: their gains are off by percent and the unwrapping fails); joint 0.0180 px, 0.0054 mm /
// 0.0066 deg. Without jitter (same poses, other noise): alternating 0.0178 px, 0.0088 mm /
// 0.0080 deg; joint 0.0183 px, 0.0202 mm / 0.0067 deg (the estimated gains' own noise moves a
// view's projector corners together a little; the pose error at 12 views is ~0.01-0.02 mm).
enum class CalibrationGainMethod { kNone, kAlternating, kFrameMeans, kJoint };

struct CalibrateOptions {
  CalibrationBoard board;
  // Distortion coefficients held at 0: any of "k2", "k3", "tangential" (p1, p2).
  bool fix_k2 = false, fix_k3 = false, fix_tangential = false;
  // Moreno & Taubin's local homography: camera pixels within +-this many px of a corner, >= 3.
  int homography_half_window_px = 20;
  // A corner's homography needs at least this fraction of its window decoded, (0, 1].
  double min_window_fraction = 0.25;
  // Decoding: pixels with a sine modulation below this (frame units in [0, 1]) are not used.
  double min_modulation = 0.01;
  // Noise sigma of one frame sample (frame units) assumed when weighing periods, > 0.
  double frame_sigma = 0.01;
  CalibrationGainMethod gain_method = CalibrationGainMethod::kJoint;
  // A view whose reprojection RMS exceeds this many times the median view's is named as an
  // outlier in the report (and a warning); it is kept. > 1.
  double outlier_view_factor = 3.0;
  // cornerSubPix after findChessboardCornersSB (the SB corners alone are less precise on noisy,
  // low-contrast boards).
  bool refine_corners = true;
  int min_views = 3;  // fewer usable views: bad input (exit 3)
  void Check() const;
  // "k3,tangential" -> the fix flags; throws Error(kUsage) naming --fix.
  void ParseFix(const std::string& list);
};

// One board pose as seen by the camera and the projector.
struct CalibrationView {
  std::string name;           // the session folder
  bool found = false;         // the board was found
  std::string problem;        // why not, or why the view was dropped (one line)
  int width = 0, height = 0;  // camera image size
  int projector_width = 0, projector_height = 0;
  // Every board corner, board order (k = j*cols+i); NaN where not seen (a ChArUco board partly
  // out of view).
  std::vector<Vec2d> camera_px;
  std::vector<Vec2d> projector_px;     // per corner; NaN where not decoded
  std::vector<int> projector_inliers;  // per corner: LMEDS inliers of its homography
  // Filled by Calibrate():
  Rigid3d cam_from_board;
  std::vector<Vec2d> camera_residual_px, projector_residual_px;  // observed - predicted
  double rms_camera_px = 0, rms_projector_px = 0;
  bool outlier = false;
  double decode_seconds = 0;
};

// Finds the board and decodes the projector coordinates of its corners in one calibration
// session. A view without a board is returned with found = false and `problem` set (not an
// error); unreadable frames or undecodable patterns throw Error(kBadInput) naming the session.
CalibrationView DetectView(const Session& session, const CalibrateOptions& options);

struct CalibrationResult {
  Rig rig;                             // the calibrated rig (world as chosen, see Calibrate)
  std::vector<CalibrationView> views;  // all views, including those skipped
  int views_used = 0;
  double rms_camera_px = 0, rms_projector_px = 0, rms_stereo_px = 0;  // over all used corners
  std::string world;        // "mount board <session>" or "first board <session>"
  std::string ceres_brief;  // Ceres' Summary::BriefReport()
  Json uncertainties;       // 1-sigma of every parameter (Ceres covariance)
  Json opencv;              // OpenCV's calibration on the same corners (baseline)
  double seconds = 0;
  Json ToJson() const;
  std::string BriefReport() const;
};

// Calibrates from views (DetectView). `size_rig`: the device sizes (and lens_shifter, copied to
// the result). `mount_view` (a view of a board lying on the mount, optional, also used in the
// adjustment): world z = 0 on its board, +z towards the rig; without it the first used view's
// board defines the world. Throws Error(kBadInput) with one line if fewer than min_views views
// have a board, or if the views are degenerate (all at one pose).
CalibrationResult Calibrate(std::vector<CalibrationView> views, const Rig& size_rig,
                            const std::optional<CalibrationView>& mount_view,
                            const CalibrateOptions& options);

// report.json, residuals_camera.png, residuals_projector.png, coverage_camera.png,
// coverage_projector.png into `dir` (created).
void WriteCalibrationReport(const CalibrationResult& result, const std::filesystem::path& dir,
                            const Json& extra);

// The projector coordinates (u, v) decoded at camera pixels `pixels` (index y * width + x) of a
// session (every sine frame of both axes). NaN where a pixel does not decode (low modulation,
// inconsistent periods, an ambiguous edge column). Exposed for tests.
struct ProjectorCoordinates {
  std::vector<float> u, v;  // per requested pixel
  int eight_bit_frames = 0;
};
ProjectorCoordinates DecodeProjectorCoordinates(const Session& session,
                                                const std::vector<uint32_t>& pixels,
                                                const CalibrateOptions& options);

}  // namespace mesoscan
