#pragma once
// The virtual rig looking at a calibration board: a printed checkerboard or ChArUco board
// (heightfield/ calibrate_board.h) at any pose in front of the rig, rendered analytically
// (ray-plane intersection, no Embree: the board is one plane), with sine patterns and/or Gray
// codes (each bit and its inverse, OpenCV structured_light style) along both projector axes,
// distortion on both devices (the rig's), sensor noise as sim/README.md, frames as
// 16-bit PNG or 8-bit PNG/BMP/TIFF. Writes a calibration session (spec "Calibration sessions": the
// rig holds only device sizes); the true rig and the board pose are kept under the session's
// "simulation" key for tests.

#include <array>
#include <filesystem>
#include <string>
#include <vector>

#include "calibration/calibrate_board.h"
#include "sim/virtual_rig.h"

namespace mesoscan {

struct BoardSimOptions {
  CalibrationBoard board;
  // World pose of the board: rotation vector (rx, ry, rz) in degrees, then translation
  // (tx, ty, tz) in mm. All zero: the board lies on the mount (z = 0), centred at the world
  // origin, its x along world x and its printed face up (+z, towards the rig).
  std::array<double, 6> pose{};
  // Albedo of the dark squares and of the paper (light squares and the margin). A printed
  // low-contrast board (grey squares on white): dark 0.45, light 0.8.
  double dark_albedo = 0.06, light_albedo = 0.85;
  double margin_squares = 1.0;      // paper beyond the checker, squares
  double background_albedo = 0.25;  // beyond the paper (the mount, far away)
  // Sine periods along projector y (the x periods are SimulateOptions::ps_periods_px).
  std::vector<double> ps_periods_y_px;
  // Gray code along projector y (the x code is SimulateOptions::graycode_*, inverse frames as
  // SimulateOptions::graycode_inverse): 0 bits = none; block_px * 2^bits covers the height.
  int graycode_y_bits = 0;
  double graycode_y_block_px = 1.0;
  // "png16" (default), "png8", "bmp" (8-bit), "tif8".
  std::string frame_format = "png16";
  void Check() const;
};

// "board:checker:13x9:10" -> the board; "" if `object` does not start with "board:".
bool IsBoardObject(const std::string& object);

// "rx,ry,rz,tx,ty,tz" (degrees, mm) -> pose; throws Error(kUsage) at the options field `option`.
std::array<double, 6> ParseBoardPose(const std::string& text,
                                     const std::string& option = "BoardSimOptions.pose");
// world_from_board of a pose.
Rigid3d BoardPoseToRigid(const std::array<double, 6>& pose);

// Simulates the board session into out_dir (atomically). Uses from `options`: rig, crop,
// ps_periods_px and graycode_* (axis x), ps_phases, white, black, supersample, fill_factor,
// blur_sigma_px, defocus_px_per_m, focus_height_m, projector_gamma, exposure, ambient, noise
// parameters, seed.
SimulateSummary SimulateBoard(const SimulateOptions& options, const BoardSimOptions& board,
                              const std::filesystem::path& out_dir);

// Writes {"rig": ...} in the session format (the file `simulate --rig` and sessions use).
void WriteRigFile(const std::filesystem::path& path, const Rig& rig);

// A rig of the held-back real captures' shape (another scanner): camera 1688 x 1352 with radial
// distortion, projector 1824 x 1140 at 15 degrees, 0.42 m away. For tests and bench_calibrate.
Rig RealShapeRig();

}  // namespace mesoscan
