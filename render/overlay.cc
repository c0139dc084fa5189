#include "render/overlay.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <opencv2/imgproc.hpp>

#include "core/error.h"

namespace mesoscan {
namespace {

// Planar ImageU8 <-> interleaved cv::Mat (RGB order kept: the colours drawn are grey).
cv::Mat ToMat(const ImageU8& im) {
  cv::Mat m(im.height(), im.width(), CV_8UC3);
  for (int y = 0; y < im.height(); ++y)
    for (int x = 0; x < im.width(); ++x)
      for (int c = 0; c < 3; ++c) m.at<cv::Vec3b>(y, x)[c] = im(x, y, c);
  return m;
}

void FromMat(const cv::Mat& m, ImageU8* im) {
  for (int y = 0; y < im->height(); ++y)
    for (int x = 0; x < im->width(); ++x)
      for (int c = 0; c < 3; ++c) (*im)(x, y, c) = m.at<cv::Vec3b>(y, x)[c];
}

// Draws `text` centred in [x0, x0 + width) on the baseline row `baseline`, shrunk to fit.
void PutCentred(cv::Mat* m, const std::string& text, int x0, int width, int baseline, double scale,
                const cv::Scalar& colour, int thickness) {
  int base = 0;
  cv::Size sz = cv::getTextSize(text, cv::FONT_HERSHEY_SIMPLEX, scale, thickness, &base);
  if (sz.width > width - 4) {
    scale *= (width - 4.0) / sz.width;
    sz = cv::getTextSize(text, cv::FONT_HERSHEY_SIMPLEX, scale, thickness, &base);
  }
  cv::putText(*m, text, cv::Point(x0 + (width - sz.width) / 2, baseline), cv::FONT_HERSHEY_SIMPLEX,
              scale, colour, thickness, cv::LINE_AA);
}

}  // namespace

int LabelStripHeight(int image_height) { return std::clamp(image_height / 12, 14, 40); }

ImageU8 LabelledSideBySide(const ImageU8& left, const ImageU8& right, const std::string& left_label,
                           const std::string& right_label) {
  MESOSCAN_CHECK(left.height() == right.height() && left.channels() == 3 && right.channels() == 3);
  const int gap = 4, h = left.height(), strip = LabelStripHeight(h);
  ImageU8 both(left.width() + gap + right.width(), strip + h, 3, 255);
  for (int c = 0; c < 3; ++c)
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < left.width(); ++x) both(x, strip + y, c) = left(x, y, c);
      for (int x = 0; x < right.width(); ++x)
        both(left.width() + gap + x, strip + y, c) = right(x, y, c);
    }
  cv::Mat m = ToMat(both);
  const double scale = strip / 30.0;
  const int baseline = strip - std::max(2, strip / 4);
  PutCentred(&m, left_label, 0, left.width(), baseline, scale, cv::Scalar(0, 0, 0), 1);
  PutCentred(&m, right_label, left.width() + gap, right.width(), baseline, scale,
             cv::Scalar(0, 0, 0), 1);
  FromMat(m, &both);
  return both;
}

std::string LengthLabel(double metres) {
  char buf[32];
  if (metres >= 1)
    std::snprintf(buf, sizeof(buf), "%g m", metres);
  else if (metres >= 1e-2 - 1e-12)
    std::snprintf(buf, sizeof(buf), "%g cm", metres * 1e2);
  else if (metres >= 1e-3 - 1e-12)
    std::snprintf(buf, sizeof(buf), "%g mm", metres * 1e3);
  else
    std::snprintf(buf, sizeof(buf), "%g um", metres * 1e6);
  return buf;
}

double DrawScaleBar(ImageU8* image, double pixels_per_metre) {
  MESOSCAN_CHECK(image->channels() == 3);
  if (!(pixels_per_metre > 0) || !std::isfinite(pixels_per_metre)) return 0;
  const int w = image->width(), h = image->height();
  // The round length nearest a fifth of the width.
  const double want = 0.2 * w / pixels_per_metre;
  const double decade = std::pow(10.0, std::floor(std::log10(want)));
  double best = decade;
  for (const double k : {1.0, 2.0, 5.0, 10.0})
    if (std::abs(std::log(k * decade / want)) < std::abs(std::log(best / want))) best = k * decade;
  const int len = static_cast<int>(std::lround(best * pixels_per_metre));
  const int margin = std::max(4, h / 30), thick = std::max(2, h / 80);
  if (len < 8 || len > w - 2 * margin) return 0;
  cv::Mat m = ToMat(*image);
  const int y1 = h - margin, y0 = y1 - thick;
  cv::rectangle(m, cv::Point(margin - 1, y0 - 1), cv::Point(margin + len, y1),
                cv::Scalar(20, 20, 20), cv::FILLED);
  cv::rectangle(m, cv::Point(margin, y0), cv::Point(margin + len - 1, y1 - 1),
                cv::Scalar(255, 255, 255), cv::FILLED);
  const double scale = std::clamp(h / 400.0, 0.3, 1.0);
  const std::string text = LengthLabel(best);
  const cv::Point at(margin, y0 - std::max(3, thick));
  cv::putText(m, text, at, cv::FONT_HERSHEY_SIMPLEX, scale, cv::Scalar(20, 20, 20), 3, cv::LINE_AA);
  cv::putText(m, text, at, cv::FONT_HERSHEY_SIMPLEX, scale, cv::Scalar(255, 255, 255), 1,
              cv::LINE_AA);
  FromMat(m, image);
  return best;
}

}  // namespace mesoscan
