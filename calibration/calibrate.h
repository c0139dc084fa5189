#pragma once
// Calibration of a projector-camera rig from sessions of a printed checkerboard or ChArUco board
// (spec "Calibration sessions"; `mesoscan calibrate`).
//
// Per view (one session = one board pose): the board's texture is the white frame or the mean of
// a full phase set; corners by OpenCV's findChessboardCornersSB (or, for ChArUco, the ArUco
// markers and interpolateCornersCharuco) refined with cornerSubPix; the sine frames' gains
// estimated jointly with the pixels' phases; the
// projector (u, v) of every camera pixel in a window around each corner is decoded from the sine
// frames of both axes (heightfield/phase_shift.h), or, for a session with Gray-code frames (a
// Gray code alone, OpenCV structured_light style, or a sine period it orders), by the
// reconstruction's codecs (calibration/calibrate_codecs.h: integer codes whose corners come
// sub-pixel only through the local fit), and each corner is taken into the projector by
// a local homography fitted robustly (LMEDS) over that window (Moreno & Taubin, "Simple, accurate,
// and robust projector-camera calibration", 3DIMPVT 2012, Sec. 3). Camera and projector are
// initialised by OpenCV (calibrateCamera, stereoCalibrate: also the plain baseline the report
// shows) and then refined together with every board pose in one Ceres bundle adjustment using
// PinholeCamera::ProjectWithParams (core/camera.h), the model reconstruction uses.

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "calibration/calibrate_board.h"
#include "calibration/calibrate_bundle.h"
#include "calibration/calibrate_coverage.h"
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

// The devices' models (`calibrate --model`): chosen per device by leave-one-view-out
// cross-validation from the ladder none, k1, k1 k2, k1 k2 p1 p2, k1 k2 p1 p2 k3 with the
// principal point free or at the centre and fx = fy or not (kAuto), or that distortion model for
// both devices (principal point free, fx and fy).
enum class CalibrationModel { kAuto, kNone, kK1, kK1K2, kFull };

struct CalibrateOptions {
  CalibrationBoard board;
  CalibrationModel model = CalibrationModel::kAuto;
  // Distortion coefficients held at 0: any of "k2", "k3", "tangential" (p1, p2); with kAuto the
  // ladder leaves them out.
  bool fix_k2 = false, fix_k3 = false, fix_tangential = false;
  // Both principal points held at the image centre ((W - 1) / 2, (H - 1) / 2).
  bool fix_principal_point = false;
  // OpenCV's calibration (k1 k2) validated on the same held-out views, for the report.
  bool validate_opencv = true;
  // Warnings: coverage of a device's field below this fraction (or an outer third of it
  // uncovered), (0, 1]; a held-out view reprojected at more than this many times the corners'
  // noise, > 1; a held-out board's scale error beyond this (percent), > 0; an intrinsic whose
  // leave-one-view-out jackknife exceeds its least-squares sigma this many times, > 1.
  double poor_coverage = 0.5;
  double held_out_warning_ratio = 3.0;
  double scale_warning_pct = 0.1;
  double scatter_warning_ratio = 3.0;
  // Moreno & Taubin's local homography: camera pixels within +-this many px of a corner, >= 3.
  int homography_half_window_px = 20;
  // A corner's homography needs at least this fraction of its window decoded, (0, 1].
  double min_window_fraction = 0.25;
  // Decoding: pixels with a sine modulation below this (frame units in [0, 1]) are not used.
  double min_modulation = 0.01;
  // Coded sessions (Gray code): pixels whose codec confidence is below this are not used, [0, 1]
  // (a Gray-code pixel with every bit read at its minimum signal-to-noise has 0.5, one on a
  // code edge between two neighbouring columns half of that).
  double min_code_confidence = 0.25;
  // Noise sigma of one frame sample (frame units) assumed when weighing periods, > 0.
  double frame_sigma = 0.01;
  CalibrationGainMethod gain_method = CalibrationGainMethod::kJoint;
  // A view whose reprojection RMS exceeds this many times the median view's is named as an
  // outlier in the report (and a warning); it is kept. > 1.
  double outlier_view_factor = 3.0;
  // A corner whose residual under the most flexible model exceeds this many robust sigmas of its
  // device is left out (a misread fringe order, a smudge), > 3.
  double outlier_corner_sigmas = 6.0;
  // cornerSubPix after findChessboardCornersSB (the SB corners alone are less precise on noisy,
  // low-contrast boards).
  bool refine_corners = true;
  int min_views = 3;  // fewer usable views: bad input (exit 3)
  void Check() const;
  // "k3,tangential" -> the fix flags; throws Error(kUsage) at "CalibrateOptions.fix".
  void ParseFix(const std::string& list);
  // "auto", "none", "k1", "k1k2", "full"; throws Error(kUsage) at "CalibrateOptions.model".
  void ParseModel(const std::string& text);
};

// One board pose as seen by the camera and the projector.
struct CalibrationView {
  std::string name;           // the session folder
  bool found = false;         // the board was found
  std::string problem;        // why not, or why the view was dropped (one line)
  std::string codec;          // what decoded the projector: "sine", "graycode", "sine+graycode"
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
  std::array<int, 2> corners_rejected{};  // camera, projector (CalibrateOptions)
  double rms_camera_px = 0, rms_projector_px = 0, rms_stereo_px = 0;  // over all used corners
  std::string world;                          // "mount board <session>" or "first board <session>"
  std::string ceres_brief;                    // Ceres' Summary::BriefReport()
  DeviceModel camera_model, projector_model;  // as chosen (or given)
  Json candidates;                            // every model tried: held-out figures, whether chosen
  // 1-sigma of every fitted parameter: the larger of the least-squares sigma and the scatter of
  // the leave-one-view-out fits (both kept, with the jackknife).
  Json uncertainties;
  std::vector<HeldOutView> held_out;         // each view left out of the chosen models' fit
  std::vector<HeldOutView> opencv_held_out;  // the same with OpenCV's calibration (baseline)
  Json validation;                           // held-out figures per view, summaries, OpenCV's
  Json opencv;                               // OpenCV's calibration on the same corners
  CalibratedRegion camera_region, projector_region;  // the corners' hulls
  std::vector<DeviceCoverage> coverage;              // camera, projector
  std::vector<std::string> warnings;                 // one line each (see CalibrateOptions)
  double seconds = 0;
  Json ToJson() const;
  std::string BriefReport() const;
  // Lines for the terminal: the models and each candidate's held-out error, the held-out
  // validation beside OpenCV's, coverage.
  std::vector<std::string> ReportLines() const;
  // What a rig file carries besides the rig ("calibration": models, regions, held-out summary).
  Json RigFileJson() const;
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
// session (every sine frame of both axes, or the codecs of a session with Gray-code frames). NaN
// where a pixel does not decode (low modulation, inconsistent periods, an ambiguous edge column).
// Exposed for tests.
struct ProjectorCoordinates {
  std::vector<float> u, v;  // per requested pixel
  int eight_bit_frames = 0;
};
ProjectorCoordinates DecodeProjectorCoordinates(const Session& session,
                                                const std::vector<uint32_t>& pixels,
                                                const CalibrateOptions& options);

}  // namespace mesoscan
