#include "heightfield/error_map_png.h"

#include <algorithm>
#include <cmath>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "core/image_io.h"

namespace mesoscan {

void WriteErrorMapPng(const std::filesystem::path& path, const ImageF& error, double max_m) {
  const int w = error.width(), h = error.height();
  if (max_m <= 0) {
    std::vector<float> a;
    for (float v : error.data())
      if (std::isfinite(v)) a.push_back(std::abs(v));
    if (!a.empty()) {
      std::nth_element(a.begin(), a.begin() + static_cast<size_t>(0.99 * (a.size() - 1)), a.end());
      max_m = a[static_cast<size_t>(0.99 * (a.size() - 1))];
    }
    if (!(max_m > 0)) max_m = 1e-6;
  }
  // Image, then a scale bar below it (at least 320 px wide so the labels fit).
  const int bar_h = 48, out_w = std::max(w, 320);
  cv::Mat grey(h, w, CV_8UC1, cv::Scalar(0)), valid(h, w, CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const float v = error(x, y);
      if (!std::isfinite(v)) continue;
      grey.at<uint8_t>(y, x) =
          static_cast<uint8_t>(std::clamp(std::abs(v) / max_m, 0.0, 1.0) * 255);
      valid.at<uint8_t>(y, x) = 255;
    }
  cv::Mat colour;
  cv::applyColorMap(grey, colour, cv::COLORMAP_VIRIDIS);
  cv::Mat out(h + bar_h, out_w, CV_8UC3, cv::Scalar(255, 255, 255));
  cv::Mat black(h, w, CV_8UC3, cv::Scalar(0, 0, 0));
  colour.copyTo(black, valid);
  black.copyTo(out(cv::Rect(0, 0, w, h)));
  cv::Mat ramp(1, 256, CV_8UC1);
  for (int i = 0; i < 256; ++i) ramp.at<uint8_t>(0, i) = static_cast<uint8_t>(i);
  cv::Mat ramp_c;
  cv::applyColorMap(ramp, ramp_c, cv::COLORMAP_VIRIDIS);
  const int bar_w = out_w - 20;
  cv::Mat ramp_big;
  cv::resize(ramp_c, ramp_big, cv::Size(bar_w, 14), 0, 0, cv::INTER_NEAREST);
  ramp_big.copyTo(out(cv::Rect(10, h + 6, bar_w, 14)));
  auto label = [&](const std::string& s, int x) {
    cv::putText(out, s, cv::Point(x, h + 40), cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0), 1,
                cv::LINE_AA);
  };
  std::ostringstream hi;
  hi.precision(3);
  hi << max_m * 1e6 << " um";
  label("0", 10);
  label("|Z error|", out_w / 2 - 30);
  label(hi.str(), out_w - 80);
  // OpenCV is BGR; the PNG writer takes planar RGB.
  ImageU8 im(out_w, h + bar_h, 3);
  for (int y = 0; y < out.rows; ++y)
    for (int x = 0; x < out.cols; ++x) {
      const cv::Vec3b px = out.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) im(x, y, c) = px[2 - c];
    }
  // zlib level 1, rows unfiltered: a full-resolution map (2176 x 1482 RGB) is written several
  // times faster than at the default level (0.18 s; libpng's adaptive filters at level 1: 0.40 s,
  // and a 70% larger file: the colour-mapped noise defeats the row predictors).
  WritePng8(path, im, 1, /*filter_rows=*/false);
}

}  // namespace mesoscan
