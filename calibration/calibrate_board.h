#pragma once
// The calibration target: a printed checkerboard (inner corners COLS x ROWS, square size) or a
// ChArUco board (OpenCV's aruco module: a checker of COLS x ROWS squares with ArUco markers in
// its light squares, every corner identified, so that boards partly out of view work), as
// `mesoscan calibrate --board` and `simulate --object board:...` name it.

#include <string>
#include <vector>

#include "core/transform.h"

namespace mesoscan {

struct CalibrationBoard {
  int cols = 0, rows = 0;  // inner corners along the board's x and y, >= 2 each
  double square_m = 0.0;   // side of a square, metres, > 0
  // ChArUco only: marker side (metres, < square_m) and OpenCV's predefined dictionary
  // (cv::aruco::PREDEFINED_DICTIONARY_NAME), -1 for a plain checkerboard.
  double marker_m = 0.0;
  int dictionary = -1;
  std::string dictionary_name;  // e.g. "DICT_5X5_100"
  bool charuco() const { return dictionary >= 0; }

  // "checker:COLSxROWS:SQUARE_MM", e.g. "checker:13x9:10" (inner corners, either orientation of
  // the board), or "charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT", e.g.
  // "charuco:8x6:12:9:DICT_5X5_100" (squares, as OpenCV's CharucoBoard and board generators count
  // them: (COLS-1) x (ROWS-1) inner corners; DICT with or without the "DICT_" prefix, any case).
  // Throws Error(kUsage) at the options field `key` (e.g. "CalibrateOptions.board") on anything
  // else.
  static CalibrationBoard Parse(const std::string& text, const std::string& key);
  std::string ToString() const;  // "checker:13x9:10", "charuco:8x6:12:9:DICT_5X5_100"

  int num_corners() const { return cols * rows; }
  int squares_x() const { return cols + 1; }
  int squares_y() const { return rows + 1; }
  // Corner k (k = j * cols + i, i along x) in the board frame: the board's centre at the origin,
  // x along the columns, y along the rows, z = 0 on the board, +z out of the printed face.
  // ChArUco: k is OpenCV's corner id (row j from the top of the printed board, whose image has
  // y down: our y, with +z out of the face, points up the print).
  Vec3d Corner(int k) const {
    const double y = (k / cols - 0.5 * (rows - 1)) * square_m;
    return Vec3d((k % cols - 0.5 * (cols - 1)) * square_m, charuco() ? -y : y, 0.0);
  }
  std::vector<Vec3d> Corners() const;
  // True where the board frame's (x, y) lies on a dark square (the squares of the checker
  // extend one square beyond the inner corners; the square at corner 0's outer diagonal is dark).
  bool Dark(double x, double y) const;
  // Half extents of the checker area (squares), metres.
  double HalfWidth() const { return 0.5 * (cols + 1) * square_m; }
  double HalfHeight() const { return 0.5 * (rows + 1) * square_m; }
  // ChArUco: the printed board as OpenCV draws it (8-bit grey, 255 paper, 0 ink), exactly
  // squares_x() x squares_y() squares of `px_per_square` pixels, row 0 at the top (board +y).
  std::vector<uint8_t> CharucoImage(int px_per_square, int* width, int* height) const;
};

}  // namespace mesoscan
