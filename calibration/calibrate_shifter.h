#pragma once
// The lens shifter's steps_per_px and its variation over the image from the
// lens-shift frames of a flat target (the empty mount, or a board lying on it) scanned with the
// calibrated rig (calibration/calibrate_mount.h ScanFlatTarget).
//
// At a camera pixel the lens-shift profile oscillates with the fitted frequency f (cycles per
// nominal projector px, the positions being shift_steps / nominal steps_per_px), so the shifter
// moves the image there by one projector pixel every
//     s(pixel) = nominal_steps_per_px / (period_px * f)            steps
// (period_px = 2 for the one-pixel stripes). Over the image, s varies with the optics; the model
// is the simulator's (sim/README.md) and the paper's quadratic gain:
//     1 / s = g(un, vn) / S,   g = 1 + gx un + gy vn + gr (un^2 + vn^2),
//     un = (u - cx) / (W / 2),  vn = (v - cy) / (H / 2),
// (u, v) the projector pixel of the point (from the calibrated rig), (cx, cy) the projector's
// principal point. S, the steps per projector pixel at the principal point, is the rig's
// `lens_shifter.steps_per_px`; the gains (the variation) go to report.json and a PNG map, not
// to the rig: reconstruction fits the frequency of every scan over the image anyway
// (heightfield/stage_lens_shift.h), and the session format has one scalar.

#include <filesystem>
#include <string>
#include <vector>

#include "calibration/calibrate_mount.h"
#include "core/image.h"
#include "core/json.h"
#include "session/session.h"

namespace mesoscan {

struct ShifterCalibrationOptions {
  double reject_sigmas = 4.0;  // per-pixel values beyond this many robust sigmas are dropped
  int rounds = 4;
  int64_t min_pixels = 1000;  // fewer fitted profiles: bad input
  size_t max_samples = 400000;
};

struct ShifterCalibration {
  std::string session;
  LensShifter nominal;             // what the session's rig said
  LensShifter calibrated;          // steps_per_px = S; axis and range as the session's
  double steps_per_px_sigma = 0;   // 1-sigma of S (least squares, scaled by the residual)
  double median_steps_per_px = 0;  // median of s over the fitted pixels (no model)
  double gain_x = 0, gain_y = 0, gain_r = 0;  // g's coefficients
  double gain_sigma[3] = {0, 0, 0};
  double pixel_sigma_rel = 0;   // robust scatter of one pixel's 1/s around the model, relative
  double model_rms_rel = 0;     // RMS of the inliers' relative residual
  double s_min = 0, s_max = 0;  // s of the model over the projector pixels the camera saw
  int64_t pixels = 0, inliers = 0;
  ImageF steps_map;  // camera grid: per-pixel s (NaN where not fitted)
  ImageF model_map;  // camera grid: the model's s at each pixel with a point
  double seconds = 0;

  // The model's steps per projector px at projector pixel (u, v) of a projector (cx, cy, W, H).
  double ModelSteps(double u, double v, double cx, double cy, double w, double h) const;
  Json ToJson() const;
  std::string BriefReport() const;
};

// Throws Error(kBadInput) if the scan has no lens-shift frames, the session's rig no
// lens_shifter, or fewer than min_pixels profiles were fitted.
ShifterCalibration CalibrateShifter(const Session& session, const FlatTargetScan& scan,
                                    const Rig& rig, const ShifterCalibrationOptions& options);

// lens_shifter_steps.png: the per-pixel steps per projector px over the camera image (colour
// map, range and S in the label).
void WriteShifterMapPng(const ShifterCalibration& cal, const std::filesystem::path& path);

}  // namespace mesoscan
