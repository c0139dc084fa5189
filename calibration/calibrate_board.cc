#include "calibration/calibrate_board.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <opencv2/aruco/charuco.hpp>
#include <regex>
#include <sstream>
#include <utility>

#include "core/error.h"

namespace mesoscan {

namespace {

// OpenCV's predefined ArUco dictionaries by name (cv::aruco::PREDEFINED_DICTIONARY_NAME).
const std::vector<std::pair<std::string, int>>& Dictionaries() {
  static const std::vector<std::pair<std::string, int>> d = {
      {"DICT_4X4_50", cv::aruco::DICT_4X4_50},
      {"DICT_4X4_100", cv::aruco::DICT_4X4_100},
      {"DICT_4X4_250", cv::aruco::DICT_4X4_250},
      {"DICT_4X4_1000", cv::aruco::DICT_4X4_1000},
      {"DICT_5X5_50", cv::aruco::DICT_5X5_50},
      {"DICT_5X5_100", cv::aruco::DICT_5X5_100},
      {"DICT_5X5_250", cv::aruco::DICT_5X5_250},
      {"DICT_5X5_1000", cv::aruco::DICT_5X5_1000},
      {"DICT_6X6_50", cv::aruco::DICT_6X6_50},
      {"DICT_6X6_100", cv::aruco::DICT_6X6_100},
      {"DICT_6X6_250", cv::aruco::DICT_6X6_250},
      {"DICT_6X6_1000", cv::aruco::DICT_6X6_1000},
      {"DICT_7X7_50", cv::aruco::DICT_7X7_50},
      {"DICT_7X7_100", cv::aruco::DICT_7X7_100},
      {"DICT_7X7_250", cv::aruco::DICT_7X7_250},
      {"DICT_7X7_1000", cv::aruco::DICT_7X7_1000},
      {"DICT_ARUCO_ORIGINAL", cv::aruco::DICT_ARUCO_ORIGINAL},
      {"DICT_APRILTAG_16H5", cv::aruco::DICT_APRILTAG_16h5},
      {"DICT_APRILTAG_25H9", cv::aruco::DICT_APRILTAG_25h9},
      {"DICT_APRILTAG_36H10", cv::aruco::DICT_APRILTAG_36h10},
      {"DICT_APRILTAG_36H11", cv::aruco::DICT_APRILTAG_36h11}};
  return d;
}

}  // namespace

CalibrationBoard CalibrationBoard::Parse(const std::string& text, const std::string& key) {
  static const std::regex re(R"(^checker:(\d+)x(\d+):([0-9]*\.?[0-9]+)$)");
  static const std::regex re_charuco(
      R"(^charuco:(\d+)x(\d+):([0-9]*\.?[0-9]+):([0-9]*\.?[0-9]+):([A-Za-z0-9_]+)$)");
  std::smatch m;
  CalibrationBoard b;
  if (text.rfind("charuco:", 0) == 0) {
    if (!std::regex_match(text, m, re_charuco))
      MESOSCAN_BAD_OPTION(key,
                          "'" << text
                              << "': expected charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT (squares, "
                                 "e.g. charuco:8x6:12:9:DICT_5X5_100)");
    const long sx = std::stol(m[1].str().substr(0, 6)), sy = std::stol(m[2].str().substr(0, 6));
    const double square_mm = std::stod(m[3].str()), marker_mm = std::stod(m[4].str());
    if (sx < 3 || sy < 3 || sx > 201 || sy > 201 || !(square_mm > 0) || square_mm > 1e4)
      MESOSCAN_BAD_OPTION(
          key, "'" << text << "': expected 3..201 squares per side and a square side > 0 mm");
    if (!(marker_mm > 0) || !(marker_mm < square_mm))
      MESOSCAN_BAD_OPTION(key, "'" << text
                                   << "': expected a marker side > 0 and smaller than "
                                      "the square side");
    std::string dict = m[5].str();
    std::transform(dict.begin(), dict.end(), dict.begin(),
                   [](unsigned char c) { return static_cast<char>(std::toupper(c)); });
    if (dict.rfind("DICT_", 0) != 0) dict = "DICT_" + dict;
    const auto& list = Dictionaries();
    auto it =
        std::find_if(list.begin(), list.end(), [&](const auto& e) { return e.first == dict; });
    if (it == list.end()) {
      std::ostringstream names;
      for (size_t i = 0; i < list.size(); ++i) names << (i ? ", " : "") << list[i].first;
      MESOSCAN_BAD_OPTION(key, "'" << text << "': unknown ArUco dictionary '" << m[5].str()
                                   << "', expected one of " << names.str());
    }
    const int markers = static_cast<int>((sx * sy) / 2);
    const int available = cv::aruco::getPredefinedDictionary(it->second)->bytesList.rows;
    if (markers > available)
      MESOSCAN_BAD_OPTION(key, "'" << text << "': a " << sx << "x" << sy << " ChArUco board needs "
                                   << markers << " markers, " << it->first << " has " << available);
    b.cols = static_cast<int>(sx - 1);
    b.rows = static_cast<int>(sy - 1);
    b.square_m = square_mm * 1e-3;
    b.marker_m = marker_mm * 1e-3;
    b.dictionary = it->second;
    b.dictionary_name = it->first;
    return b;
  }
  if (!std::regex_match(text, m, re))
    MESOSCAN_BAD_OPTION(key, "'" << text
                                 << "': expected checker:COLSxROWS:SQUARE_MM (inner "
                                    "corners, square side in mm, e.g. checker:13x9:10) "
                                    "or charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT");
  const long cols = std::stol(m[1].str().substr(0, 6)), rows = std::stol(m[2].str().substr(0, 6));
  const double square_mm = std::stod(m[3].str());
  if (cols < 2 || rows < 2 || cols > 200 || rows > 200 || !(square_mm > 0) || square_mm > 1e4)
    MESOSCAN_BAD_OPTION(
        key, "'" << text << "': expected 2..200 inner corners per side and a square side > 0 mm");
  b.cols = static_cast<int>(cols);
  b.rows = static_cast<int>(rows);
  b.square_m = square_mm * 1e-3;
  return b;
}

std::string CalibrationBoard::ToString() const {
  std::ostringstream o;
  if (charuco())
    o << "charuco:" << squares_x() << "x" << squares_y() << ":" << square_m * 1e3 << ":"
      << marker_m * 1e3 << ":" << dictionary_name;
  else
    o << "checker:" << cols << "x" << rows << ":" << square_m * 1e3;
  return o.str();
}

std::vector<uint8_t> CalibrationBoard::CharucoImage(int px_per_square, int* width,
                                                    int* height) const {
  const auto dict = cv::aruco::getPredefinedDictionary(
      static_cast<cv::aruco::PREDEFINED_DICTIONARY_NAME>(dictionary));
  const auto b = cv::aruco::CharucoBoard::create(
      squares_x(), squares_y(), static_cast<float>(square_m), static_cast<float>(marker_m), dict);
  *width = squares_x() * px_per_square;
  *height = squares_y() * px_per_square;
  cv::Mat img;
  b->draw(cv::Size(*width, *height), img, 0, 1);
  std::vector<uint8_t> out(static_cast<size_t>(*width) * *height);
  for (int y = 0; y < *height; ++y)
    for (int x = 0; x < *width; ++x)
      out[static_cast<size_t>(y) * *width + x] = img.at<uint8_t>(y, x);
  return out;
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
