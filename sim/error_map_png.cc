#include "sim/error_map_png.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

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
  // Image, then a scale bar below it (at least 320 px wide so the labels fit); the top rows
  // right of a narrow image are white. The bar is drawn by OpenCV on its own small image, the
  // map goes straight into the planar RGB image through viridis as a 256-entry table (OpenCV's
  // applyColorMap, masking and BGR copies over the whole map took ~40% of this function).
  const int bar_h = 48, out_w = std::max(w, 320);
  cv::Mat ramp(1, 256, CV_8UC1);
  for (int i = 0; i < 256; ++i) ramp.at<uint8_t>(0, i) = static_cast<uint8_t>(i);
  cv::Mat viridis;  // 1 x 256 BGR
  cv::applyColorMap(ramp, viridis, cv::COLORMAP_VIRIDIS);
  cv::Mat bar(bar_h, out_w, CV_8UC3, cv::Scalar(255, 255, 255));
  const int bar_w = out_w - 20;
  cv::Mat ramp_big;
  cv::resize(viridis, ramp_big, cv::Size(bar_w, 14), 0, 0, cv::INTER_NEAREST);
  ramp_big.copyTo(bar(cv::Rect(10, 6, bar_w, 14)));
  auto label = [&](const std::string& s, int x) {
    cv::putText(bar, s, cv::Point(x, 40), cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0), 1,
                cv::LINE_AA);
  };
  std::ostringstream hi;
  hi.precision(3);
  hi << max_m * 1e6 << " um";
  label("0", 10);
  label("|Z error|", out_w / 2 - 30);
  label(hi.str(), out_w - 80);
  ImageU8 im(out_w, h + bar_h, 3);
  const cv::Vec3b* lut = viridis.ptr<cv::Vec3b>(0);
  tbb::parallel_for(
      tbb::blocked_range<int>(0, h + bar_h, 64), [&](const tbb::blocked_range<int>& r) {
        for (int y = r.begin(); y < r.end(); ++y) {
          uint8_t* rgb[3] = {&im(0, y, 0), &im(0, y, 1), &im(0, y, 2)};
          if (y >= h) {  // the bar; OpenCV is BGR
            const cv::Vec3b* row = bar.ptr<cv::Vec3b>(y - h);
            for (int x = 0; x < out_w; ++x)
              for (int c = 0; c < 3; ++c) rgb[c][x] = row[x][2 - c];
            continue;
          }
          for (int x = 0; x < w; ++x) {
            const float v = error(x, y);
            cv::Vec3b px(0, 0, 0);  // NaN: black
            if (std::isfinite(v))
              px = lut[static_cast<uint8_t>(std::clamp(std::abs(v) / max_m, 0.0, 1.0) * 255)];
            for (int c = 0; c < 3; ++c) rgb[c][x] = px[2 - c];
          }
          for (int x = w; x < out_w; ++x)
            for (int c = 0; c < 3; ++c) rgb[c][x] = 255;
        }
      });
  // zlib level 1, rows unfiltered: a full-resolution map (2176 x 1482 RGB) is written several
  // times faster than at the default level (0.18 s; libpng's adaptive filters at level 1: 0.40 s,
  // and a 70% larger file: the colour-mapped noise defeats the row predictors).
  WritePng8(path, im, 1, /*filter_rows=*/false);
}

}  // namespace mesoscan
