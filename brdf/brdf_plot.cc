#include "brdf/brdf_plot.h"

#include <algorithm>
#include <cstdio>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "core/parallel.h"

namespace mesoscan {
namespace {

const cv::Scalar kWhite(255, 255, 255), kGrey(110, 110, 110), kLight(200, 200, 200);
// Curve colours (BGR) for the R, G, B channels.
const cv::Scalar kChannel[3] = {cv::Scalar(40, 40, 230), cv::Scalar(40, 170, 40),
                                cv::Scalar(230, 80, 30)};
constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;

std::string Fmt(const char* fmt, double v) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), fmt, v);
  return buf;
}

void Text(cv::Mat& img, const std::string& s, cv::Point p, double scale, const cv::Scalar& c,
          bool centred = false) {
  if (centred) {
    int base = 0;
    const cv::Size sz = cv::getTextSize(s, kFont, scale, 1, &base);
    p.x -= sz.width / 2;
  }
  cv::putText(img, s, p, kFont, scale, c, 1, cv::LINE_AA);
}

// Polar plot of f cos in the plane of incidence: wo on the right (phi = 0), signed wi angle.
void DrawPolar(cv::Mat& img, cv::Rect area, const Brdf& brdf, double theta_o) {
  constexpr int kSteps = 721;
  const Vec3 wo = SphericalDirection(theta_o, 0.0);
  std::vector<Rgb> values(kSteps);
  double vmax = 0;
  for (int i = 0; i < kSteps; ++i) {
    const double t = -kPi / 2 + kPi * i / (kSteps - 1);
    const Vec3 wi = SphericalDirection(std::abs(t), t >= 0 ? 0.0 : kPi);
    values[i] = (brdf.f(wo, wi) * std::max(0.0, wi.z())).max(0.0);
    if (values[i].allFinite()) vmax = std::max(vmax, values[i].maxCoeff());
  }
  const cv::Point c(area.x + area.width / 2, area.y + area.height - 30);
  const int radius = std::min(area.width / 2 - 28, area.height - 60);
  // Logarithmic radius from a tenth of the median (the diffuse level) up to the next power of ten
  // above the peak, so a diffuse base and a sharp highlight are both visible; rings at every
  // decade.
  std::vector<double> positive;
  for (const Rgb& v : values)
    if (v.allFinite() && Luminance(v) > 0) positive.push_back(Luminance(v));
  double median = vmax;
  if (!positive.empty()) {
    std::nth_element(positive.begin(), positive.begin() + positive.size() / 2, positive.end());
    median = positive[positive.size() / 2];
  }
  const double top = vmax > 0 ? std::ceil(std::log10(vmax)) : 0.0;
  const int kDecades =
      median > 0 ? std::clamp(static_cast<int>(top - std::floor(std::log10(0.1 * median))), 2, 6)
                 : 4;
  auto radius_of = [&](double v) {
    if (!(v > 0)) return 0.0;
    return radius * std::clamp((std::log10(v) - (top - kDecades)) / kDecades, 0.0, 1.0);
  };
  // Ring values under the baseline on the right, where no spoke, curve or wo arrow can cover them.
  for (int d = 0; d < kDecades; ++d) {
    const int r = static_cast<int>(std::lround(radius * (d + 1.0) / kDecades));
    cv::ellipse(img, c, cv::Size(r, r), 0, 180, 360, kGrey, 1, cv::LINE_AA);
    cv::line(img, cv::Point(c.x + r, c.y), cv::Point(c.x + r, c.y + 4), kLight, 1);
    // The outermost value is the "90" spoke's place (the range is printed on the left); with
    // narrow rings every other value, so the labels do not run together.
    const int every = radius / kDecades < 30 ? 2 : 1;
    if (d + 1 < kDecades && (d + 1) % every == 0)
      Text(img, Fmt("%g", std::pow(10.0, top - kDecades + d + 1)), cv::Point(c.x + r, c.y + 15),
           0.33, kLight, true);
  }
  Text(img,
       "rings: " + Fmt("%g", std::pow(10.0, top - kDecades + 1)) + " .. " +
           Fmt("%g", std::pow(10.0, top)) + " /sr",
       cv::Point(c.x - radius / 2, c.y + 15), 0.33, kLight, true);
  for (int deg = -90; deg <= 90; deg += 30) {
    const double a = deg * kPi / 180;
    const cv::Point e(c.x + static_cast<int>(radius * std::sin(a)),
                      c.y - static_cast<int>(radius * std::cos(a)));
    cv::line(img, c, e, kGrey, 1, cv::LINE_AA);
    const cv::Point l(c.x + static_cast<int>((radius + 14) * std::sin(a)),
                      c.y - static_cast<int>((radius + 14) * std::cos(a)) + 4);
    Text(img, std::to_string(std::abs(deg)), l, 0.33, kLight, true);
  }
  cv::line(img, cv::Point(c.x - radius - 5, c.y), cv::Point(c.x + radius + 5, c.y), kLight, 1);
  // Incident direction wo as an arrow pointing at the surface.
  const cv::Point wo_tip(c.x + static_cast<int>(radius * std::sin(theta_o)),
                         c.y - static_cast<int>(radius * std::cos(theta_o)));
  cv::arrowedLine(img, wo_tip, c, cv::Scalar(0, 200, 255), 1, cv::LINE_AA, 0, 0.06);
  Text(img, "wo", wo_tip + cv::Point(6, 12), 0.4, cv::Scalar(0, 200, 255));
  // The three channel curves.
  for (int ch = 0; ch < 3; ++ch) {
    std::vector<cv::Point> pts;
    for (int i = 0; i < kSteps; ++i) {
      const double t = -kPi / 2 + kPi * i / (kSteps - 1);
      const double v = std::isfinite(values[i][ch]) ? values[i][ch] : 0.0;
      const double r = radius_of(v);
      pts.emplace_back(c.x + static_cast<int>(std::lround(r * std::sin(t))),
                       c.y - static_cast<int>(std::lround(r * std::cos(t))));
    }
    cv::polylines(img, pts, false, kChannel[ch], 1, cv::LINE_AA);
  }
  Text(img, "theta_o = " + Fmt("%.0f", theta_o * 180 / kPi) + " deg", cv::Point(c.x, area.y + 18),
       0.5, kWhite, true);
  Text(img, "f*cos(theta_i) [1/sr], log radius, plane of incidence", cv::Point(c.x, area.y + 36),
       0.36, kLight, true);
}

// Hemisphere seen from above (orthographic): RGB of f cos, exposure set by the panel's 99th
// percentile of the largest channel (so colours do not clip), sRGB-encoded.
void DrawHemisphere(cv::Mat& img, cv::Rect area, const Brdf& brdf, double theta_o) {
  const int radius = std::min(area.width, area.height - 40) / 2 - 18;
  const cv::Point c(area.x + area.width / 2, area.y + 24 + radius);
  const Vec3 wo = SphericalDirection(theta_o, 0.0);
  const int n = 2 * radius + 1;
  std::vector<Rgb> vals(static_cast<size_t>(n) * n, Rgb::Constant(-1));
  ParallelForRows(n, [&](int y0, int y1) {
    for (int py = y0; py < y1; ++py)
      for (int px = 0; px < n; ++px) {
        const double x = (px - radius) / static_cast<double>(radius);
        const double y = (radius - py) / static_cast<double>(radius);
        const double r2 = x * x + y * y;
        if (r2 > 1) continue;
        const Vec3 wi(x, y, std::sqrt(std::max(0.0, 1 - r2)));
        Rgb v = brdf.f(wo, wi) * wi.z();
        if (!v.allFinite()) v = Rgb::Zero();
        vals[static_cast<size_t>(py) * n + px] = v.max(0.0);
      }
  });
  std::vector<double> lum;
  for (const Rgb& v : vals)
    if (v[0] >= 0) lum.push_back(v.maxCoeff());
  double exposure = 1;
  if (!lum.empty()) {
    const size_t k = std::min(lum.size() - 1, static_cast<size_t>(0.99 * lum.size()));
    std::nth_element(lum.begin(), lum.begin() + k, lum.end());
    exposure = lum[k] > 0 ? 1.0 / lum[k] : 1.0;
  }
  auto encode = [](double v) {
    v = std::clamp(v, 0.0, 1.0);
    v = v <= 0.0031308 ? 12.92 * v : 1.055 * std::pow(v, 1 / 2.4) - 0.055;
    return static_cast<uint8_t>(std::lround(255 * v));
  };
  for (int py = 0; py < n; ++py)
    for (int px = 0; px < n; ++px) {
      const Rgb& v = vals[static_cast<size_t>(py) * n + px];
      if (v[0] < 0) continue;
      const cv::Point p(c.x - radius + px, c.y - radius + py);
      img.at<cv::Vec3b>(p) =
          cv::Vec3b(encode(v[2] * exposure), encode(v[1] * exposure), encode(v[0] * exposure));
    }
  cv::circle(img, c, radius, kGrey, 1, cv::LINE_AA);
  // Mirror direction of wo (where a highlight is expected) and the direction of wo itself.
  const cv::Point mirror(c.x - static_cast<int>(radius * std::sin(theta_o)), c.y);
  const cv::Point wo_p(c.x + static_cast<int>(radius * std::sin(theta_o)), c.y);
  cv::drawMarker(img, wo_p, cv::Scalar(0, 200, 255), cv::MARKER_CROSS, 10, 1);
  // Dark halo so the mirror marker stays visible on a saturated highlight.
  cv::circle(img, mirror, 6, cv::Scalar(0, 0, 0), 3, cv::LINE_AA);
  cv::circle(img, mirror, 6, kWhite, 1, cv::LINE_AA);
  Text(img, "hemisphere from above: + = wo side, o = mirror", cv::Point(c.x, area.y + 14), 0.36,
       kLight, true);
  // Colour bar: the grey ramp of the encoding, 0 to the white level, with three ticks.
  const int bar_w = 2 * radius, bar_x = c.x - radius, bar_y = c.y + radius + 8;
  for (int x = 0; x < bar_w; ++x) {
    const uint8_t g = encode(static_cast<double>(x) / (bar_w - 1));
    cv::line(img, cv::Point(bar_x + x, bar_y), cv::Point(bar_x + x, bar_y + 7),
             cv::Scalar(g, g, g));
  }
  cv::rectangle(img, cv::Rect(bar_x - 1, bar_y - 1, bar_w + 2, 10), kGrey, 1);
  for (int k = 0; k <= 2; ++k) {
    const int x = bar_x + k * (bar_w - 1) / 2;
    cv::line(img, cv::Point(x, bar_y + 8), cv::Point(x, bar_y + 11), kLight, 1);
    Text(img, Fmt("%.3g", 0.5 * k / exposure), cv::Point(x, bar_y + 22), 0.33, kLight, true);
  }
  Text(img, "f*cos [1/sr] per channel, linear; white = 99th percentile", cv::Point(c.x, bar_y + 36),
       0.33, kLight, true);
}

}  // namespace

void BrdfPlotOptions::Check() const {
  if (theta_o_deg.empty()) MESOSCAN_BAD_INPUT("plot: theta_o_deg is empty");
  for (double t : theta_o_deg)
    if (!(t >= 0 && t <= 89)) MESOSCAN_BAD_INPUT("plot: theta_o " << t << " outside [0, 89] deg");
  if (panel_px < 200) MESOSCAN_BAD_INPUT("plot: panel_px " << panel_px << " < 200");
  // Budget before allocation: the image is columns * panel_px by ~2.7 * panel_px RGB.
  constexpr int kMaxPanel = 4096, kMaxColumns = 32;
  if (panel_px > kMaxPanel)
    MESOSCAN_BAD_INPUT("plot: panel_px " << panel_px << " exceeds the limit of " << kMaxPanel);
  if (theta_o_deg.size() > kMaxColumns)
    MESOSCAN_BAD_INPUT("plot: " << theta_o_deg.size() << " theta_o columns exceed the limit of "
                                << kMaxColumns);
}

ImageU8 PlotBrdf(const Brdf& brdf, const BrdfPlotOptions& options) {
  options.Check();
  const int cols = static_cast<int>(options.theta_o_deg.size());
  const int w = options.panel_px, title_h = 34, polar_h = w * 2 / 3, hemi_h = w;
  cv::Mat img(title_h + polar_h + hemi_h + 24, cols * w, CV_8UC3, cv::Scalar(24, 24, 24));
  Text(img, options.title, cv::Point(10, 23), 0.6, kWhite);
  for (int i = 0; i < cols; ++i) {
    const double theta_o = options.theta_o_deg[i] * kPi / 180;
    DrawPolar(img, cv::Rect(i * w, title_h, w, polar_h), brdf, theta_o);
    DrawHemisphere(img, cv::Rect(i * w, title_h + polar_h, w, hemi_h), brdf, theta_o);
  }
  // Legend for the curve colours.
  const int ly = img.rows - 8;
  const char* names[3] = {"R", "G", "B"};
  for (int ch = 0; ch < 3; ++ch) {
    const int x = 10 + ch * 60;
    cv::line(img, cv::Point(x, ly - 4), cv::Point(x + 24, ly - 4), kChannel[ch], 2);
    Text(img, names[ch], cv::Point(x + 28, ly), 0.4, kWhite);
  }
  ImageU8 out(img.cols, img.rows, 3);
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x) {
      const cv::Vec3b p = img.at<cv::Vec3b>(y, x);
      out(x, y, 0) = p[2];
      out(x, y, 1) = p[1];
      out(x, y, 2) = p[0];
    }
  return out;
}

}  // namespace mesoscan
