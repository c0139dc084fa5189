#include "heightfield/calibrate_board.h"

#include <cmath>
#include <regex>
#include <sstream>

#include "core/error.h"

namespace mesoscan {

CalibrationBoard CalibrationBoard::Parse(const std::string& text, const std::string& key) {
  static const std::regex re(R"(^checker:(\d+)x(\d+):([0-9]*\.?[0-9]+)$)");
  std::smatch m;
  if (text.rfind("charuco:", 0) == 0)
    MESOSCAN_THROW(ErrorKind::kUsage,
                   key << ": '" << text
                       << "': ChArUco boards are not implemented yet, expected "
                          "checker:COLSxROWS:SQUARE_MM (inner corners, e.g. checker:13x9:10)");
  if (!std::regex_match(text, m, re))
    MESOSCAN_THROW(ErrorKind::kUsage, key << ": '" << text
                                          << "': expected checker:COLSxROWS:SQUARE_MM (inner "
                                             "corners, square side in mm, e.g. checker:13x9:10)");
  CalibrationBoard b;
  const long cols = std::stol(m[1].str().substr(0, 6)), rows = std::stol(m[2].str().substr(0, 6));
  const double square_mm = std::stod(m[3].str());
  if (cols < 2 || rows < 2 || cols > 200 || rows > 200 || !(square_mm > 0) || square_mm > 1e4)
    MESOSCAN_THROW(ErrorKind::kUsage,
                   key << ": '" << text
                       << "': expected 2..200 inner corners per side and a square side > 0 mm");
  b.cols = static_cast<int>(cols);
  b.rows = static_cast<int>(rows);
  b.square_m = square_mm * 1e-3;
  return b;
}

std::string CalibrationBoard::ToString() const {
  std::ostringstream o;
  o << "checker:" << cols << "x" << rows << ":" << square_m * 1e3;
  return o.str();
}

std::vector<Vec3d> CalibrationBoard::Corners() const {
  std::vector<Vec3d> c(num_corners());
  for (int k = 0; k < num_corners(); ++k) c[k] = Corner(k);
  return c;
}

bool CalibrationBoard::Dark(double x, double y) const {
  // Square (a, b) spans corners a-1..a along x (a = 0 is the column of squares left of corner 0).
  const double fx = x / square_m + 0.5 * (cols - 1) + 1.0;
  const double fy = y / square_m + 0.5 * (rows - 1) + 1.0;
  const long a = static_cast<long>(std::floor(fx)), b = static_cast<long>(std::floor(fy));
  return ((a + b) % 2 + 2) % 2 == 0;
}

}  // namespace mesoscan
