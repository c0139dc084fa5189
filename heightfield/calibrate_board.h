#pragma once
// The calibration target: a printed checkerboard (inner corners COLS x ROWS, square size), as
// `mesoscan calibrate --board` and `simulate --object board:...` name it.

#include <string>
#include <vector>

#include "core/transform.h"

namespace mesoscan {

struct CalibrationBoard {
  int cols = 0, rows = 0;  // inner corners along the board's x and y, >= 2 each
  double square_m = 0.0;   // side of a square, metres, > 0

  // "checker:COLSxROWS:SQUARE_MM", e.g. "checker:13x9:10" (either orientation of the board).
  // Throws Error(kUsage) naming `key` (e.g. "--board") on anything else; "charuco:..." is refused
  // with a line saying that only checkerboards are implemented.
  static CalibrationBoard Parse(const std::string& text, const std::string& key);
  std::string ToString() const;  // "checker:13x9:10"

  int num_corners() const { return cols * rows; }
  // Corner k (k = j * cols + i, i along x) in the board frame: the board's centre at the origin,
  // x along the columns, y along the rows, z = 0 on the board, +z out of the printed face.
  Vec3d Corner(int k) const {
    return Vec3d((k % cols - 0.5 * (cols - 1)) * square_m, (k / cols - 0.5 * (rows - 1)) * square_m,
                 0.0);
  }
  std::vector<Vec3d> Corners() const;
  // True where the board frame's (x, y) lies on a dark square (the squares of the checker
  // extend one square beyond the inner corners; the square at corner 0's outer diagonal is dark).
  bool Dark(double x, double y) const;
  // Half extents of the checker area (squares), metres.
  double HalfWidth() const { return 0.5 * (cols + 1) * square_m; }
  double HalfHeight() const { return 0.5 * (rows + 1) * square_m; }
};

}  // namespace mesoscan
