#include "maps/colour_map_png.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <vector>

#include "core/image_io.h"

namespace mesoscan {
namespace {

// 256 BGR entries of the style's colour scale.
cv::Mat ColourTable(ColourMapStyle::Kind kind) {
  cv::Mat table(1, 256, CV_8UC3);
  if (kind == ColourMapStyle::Kind::kSequential) {
    cv::Mat ramp(1, 256, CV_8UC1);
    for (int i = 0; i < 256; ++i) ramp.at<uint8_t>(0, i) = static_cast<uint8_t>(i);
    cv::applyColorMap(ramp, table, cv::COLORMAP_VIRIDIS);
    return table;
  }
  // ColorBrewer RdBu (11 classes), from blue (negative) to red (positive), RGB.
  static constexpr std::array<std::array<int, 3>, 11> kRdBu = {{{5, 48, 97},
                                                                {33, 102, 172},
                                                                {67, 147, 195},
                                                                {146, 197, 222},
                                                                {209, 229, 240},
                                                                {247, 247, 247},
                                                                {253, 219, 199},
                                                                {244, 165, 130},
                                                                {214, 96, 77},
                                                                {178, 24, 43},
                                                                {103, 0, 31}}};
  for (int i = 0; i < 256; ++i) {
    const double t = i / 255.0 * 10.0;
    const int k = std::min(9, static_cast<int>(t));
    const double f = t - k;
    cv::Vec3b& px = table.at<cv::Vec3b>(0, i);
    for (int c = 0; c < 3; ++c)
      px[2 - c] =
          static_cast<uint8_t>(std::lround((1 - f) * kRdBu[k][c] + f * kRdBu[k + 1][c]));  // BGR
  }
  return table;
}

// "<sign><v * label_scale> <unit>" (streamed: GCC 12's -Wrestrict misfires on string +).
std::string Label(double v, const ColourMapStyle& s, const char* sign = "") {
  std::ostringstream os;
  os.precision(3);
  os << sign << v * s.label_scale << " " << s.unit;
  return os.str();
}

}  // namespace

void WriteColourMapPng(const std::filesystem::path& path, const ImageF& values,
                       const ColourMapStyle& style) {
  const int w = values.width(), h = values.height();
  const bool diverging = style.kind == ColourMapStyle::Kind::kDiverging;
  double hi = style.hi;
  if (!(hi > 0)) {
    std::vector<float> a;
    for (float v : values.data())
      if (std::isfinite(v)) a.push_back(std::abs(v));
    if (!a.empty()) {
      std::nth_element(a.begin(), a.begin() + static_cast<size_t>(0.99 * (a.size() - 1)), a.end());
      hi = a[static_cast<size_t>(0.99 * (a.size() - 1))];
    }
    if (!(hi > 0)) hi = 1e-6;
  }
  // Map, then the legend below it (at least 320 px wide so the labels fit). The legend is drawn
  // by OpenCV on its own small image; the map goes straight into the planar RGB image through a
  // 256-entry table (OpenCV's applyColorMap, masking and BGR copies over the whole map took ~40%
  // of the time).
  const bool scale_bar = style.pixel_size_m > 0;
  const int bar_h = scale_bar || diverging ? 70 : 48, out_w = std::max(w, 320);
  const cv::Mat lut_mat = ColourTable(style.kind);
  cv::Mat bar(bar_h, out_w, CV_8UC3, cv::Scalar(255, 255, 255));
  const int bar_w = out_w - 20;
  cv::Mat ramp_big;
  cv::resize(lut_mat, ramp_big, cv::Size(bar_w, 14), 0, 0, cv::INTER_NEAREST);
  ramp_big.copyTo(bar(cv::Rect(10, 6, bar_w, 14)));
  auto label = [&](const std::string& s, int x, int y = 40) {
    cv::putText(bar, s, cv::Point(x, y), cv::FONT_HERSHEY_SIMPLEX, 0.4, cv::Scalar(0, 0, 0), 1,
                cv::LINE_AA);
  };
  if (diverging) {
    label(Label(hi, style, "-"), 10);
    label("0", out_w / 2 - 3);
    label(Label(hi, style, "+"), out_w - 80);
    // The title right-aligned on the row below (the scale bar's, on its left).
    int baseline = 0;
    const cv::Size size = cv::getTextSize(style.title, cv::FONT_HERSHEY_SIMPLEX, 0.4, 1, &baseline);
    label(style.title, out_w - 10 - size.width, 60);
  } else {
    label("0", 10);
    label(style.title, out_w / 2 - 30);
    label(Label(hi, style), out_w - 80);
  }
  if (scale_bar) {
    // The longest round length (1, 2, 5 x 10^k m) that fits in a quarter of the map.
    const double max_len = 0.25 * std::max(w, 1) * style.pixel_size_m;
    double len = std::pow(10.0, std::floor(std::log10(max_len)));
    if (5 * len <= max_len)
      len *= 5;
    else if (2 * len <= max_len)
      len *= 2;
    const int px = std::max(1, static_cast<int>(std::lround(len / style.pixel_size_m)));
    cv::rectangle(bar, cv::Rect(10, 52, px, 5), cv::Scalar(0, 0, 0), cv::FILLED);
    std::ostringstream os;
    os << (len >= 1e-3 ? len * 1e3 : len * 1e6) << (len >= 1e-3 ? " mm" : " um");
    label(os.str(), 16 + px, 60);
  }
  ImageU8 im(out_w, h + bar_h, 3);
  const cv::Vec3b* lut = lut_mat.ptr<cv::Vec3b>(0);
  tbb::parallel_for(tbb::blocked_range<int>(0, h + bar_h, 64),
                    [&](const tbb::blocked_range<int>& r) {
                      for (int y = r.begin(); y < r.end(); ++y) {
                        uint8_t* rgb[3] = {&im(0, y, 0), &im(0, y, 1), &im(0, y, 2)};
                        if (y >= h) {  // the legend; OpenCV is BGR
                          const cv::Vec3b* row = bar.ptr<cv::Vec3b>(y - h);
                          for (int x = 0; x < out_w; ++x)
                            for (int c = 0; c < 3; ++c) rgb[c][x] = row[x][2 - c];
                          continue;
                        }
                        for (int x = 0; x < w; ++x) {
                          const float v = values(x, y);
                          cv::Vec3b px(0, 0, 0);  // NaN: black
                          if (std::isfinite(v)) {
                            const double t = diverging ? 0.5 + 0.5 * v / hi : std::abs(v) / hi;
                            px = lut[static_cast<uint8_t>(std::clamp(t, 0.0, 1.0) * 255)];
                          }
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
