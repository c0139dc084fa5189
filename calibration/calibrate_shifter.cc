#include "calibration/calibrate_shifter.h"

#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "core/error.h"
#include "core/image_io.h"
#include "core/robust_stats.h"

namespace mesoscan {
namespace {

constexpr float kNaNf = std::numeric_limits<float>::quiet_NaN();

Json ShifterJson(const LensShifter& s) {
  return {{"axis", std::string(1, s.axis)},
          {"steps_per_px", s.steps_per_px},
          {"range_steps", {s.range_steps[0], s.range_steps[1]}}};
}

}  // namespace

double ShifterCalibration::ModelSteps(double u, double v, double cx, double cy, double w,
                                      double h) const {
  const double un = (u - cx) / (w / 2), vn = (v - cy) / (h / 2);
  const double g = 1 + gain_x * un + gain_y * vn + gain_r * (un * un + vn * vn);
  return calibrated.steps_per_px / g;
}

ShifterCalibration CalibrateShifter(const Session& session, const FlatTargetScan& scan,
                                    const Rig& rig, const ShifterCalibrationOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  const std::string where = session.root.string() + "/session.json";
  if (!session.rig.lens_shifter)
    MESOSCAN_BAD_INPUT(where << ": rig: no lens_shifter, expected one to calibrate");
  if (scan.ls_frequency.empty())
    MESOSCAN_BAD_INPUT(where << ": frames: no lens-shift frames (>= 4 stripes of period 2 along "
                                "x), expected them to calibrate the lens shifter");
  ShifterCalibration cal;
  cal.session = session.root.string();
  cal.nominal = *session.rig.lens_shifter;
  cal.calibrated = cal.nominal;
  const double nominal = cal.nominal.steps_per_px, period = scan.ls_period_px;
  const int W = rig.camera.width, H = rig.camera.height;
  const PinholeCamera& prj = rig.projector;
  const double cx = prj.K(0, 2), cy = prj.K(1, 2), hw = prj.width / 2.0, hh = prj.height / 2.0;
  cal.steps_map = ImageF(W, H, 1, kNaNf);
  cal.model_map = ImageF(W, H, 1, kNaNf);

  // Per pixel: y = period * f = nominal / s (1 at the nominal value), and the projector (un, vn).
  struct Sample {
    size_t pixel;
    double y, un, vn;
  };
  std::vector<Sample> all;
  for (size_t i = 0; i < static_cast<size_t>(W) * H; ++i) {
    const float f = scan.ls_frequency[i];
    const float z = scan.xyz.channel(2)[i];
    if (!std::isfinite(f) || !(f > 0) || !std::isfinite(z)) continue;
    const Vec3d x(scan.xyz.channel(0)[i], scan.xyz.channel(1)[i], z);
    Vec2d uv;
    if (!prj.Project(x, &uv)) continue;
    all.push_back({i, period * f, (uv.x() - cx) / hw, (uv.y() - cy) / hh});
    cal.steps_map.channel(0)[i] = static_cast<float>(nominal / (period * f));
  }
  cal.pixels = static_cast<int64_t>(all.size());
  if (cal.pixels < options.min_pixels)
    MESOSCAN_BAD_INPUT(where << ": " << cal.pixels
                             << " lens-shift profiles fitted on points, expected at least "
                             << options.min_pixels << " (is the target lit and in focus?)");
  {
    std::vector<double> s;
    s.reserve(all.size());
    for (const auto& a : all) s.push_back(nominal / a.y);
    cal.median_steps_per_px = Median(std::move(s));
  }
  const size_t stride = std::max<size_t>(1, all.size() / options.max_samples);
  std::vector<const Sample*> fit;
  for (size_t k = 0; k < all.size(); k += stride) fit.push_back(&all[k]);
  auto terms = [](const Sample& s) {
    return Eigen::Vector4d(1.0, s.un, s.vn, s.un * s.un + s.vn * s.vn);
  };
  std::vector<uint8_t> use(fit.size(), 1);
  std::vector<double> res(fit.size());
  Eigen::Vector4d a = Eigen::Vector4d::Zero();
  Eigen::Matrix4d ata = Eigen::Matrix4d::Identity();
  double sigma = 0;
  for (int round = 0; round < std::max(1, options.rounds); ++round) {
    ata.setZero();
    Eigen::Vector4d atb = Eigen::Vector4d::Zero();
    for (size_t k = 0; k < fit.size(); ++k) {
      if (!use[k]) continue;
      const Eigen::Vector4d t = terms(*fit[k]);
      ata += t * t.transpose();
      atb += t * fit[k]->y;
    }
    a = ata.ldlt().solve(atb);
    if (!a.allFinite() || !(a(0) > 0))
      MESOSCAN_BAD_INPUT(where << ": the lens-shift frequencies do not determine the shifter's "
                                  "gain over the image (degenerate coverage)");
    for (size_t k = 0; k < fit.size(); ++k) res[k] = fit[k]->y - terms(*fit[k]).dot(a);
    std::vector<double> ab(res.size());
    for (size_t k = 0; k < res.size(); ++k) ab[k] = std::abs(res[k]);
    sigma = kMadToSigma * Median(ab);
    for (size_t k = 0; k < fit.size(); ++k)
      use[k] = std::abs(res[k]) <= options.reject_sigmas * sigma + 1e-15;
  }
  double s2 = 0;
  int64_t n = 0;
  for (size_t k = 0; k < fit.size(); ++k)
    if (use[k]) {
      s2 += res[k] * res[k];
      ++n;
    }
  const double rms = n ? std::sqrt(s2 / n) : 0;
  cal.inliers = n * static_cast<int64_t>(stride);
  cal.pixel_sigma_rel = sigma / a(0);
  cal.model_rms_rel = rms / a(0);
  cal.calibrated.steps_per_px = nominal / a(0);
  cal.gain_x = a(1) / a(0);
  cal.gain_y = a(2) / a(0);
  cal.gain_r = a(3) / a(0);
  // Covariance of a: rms^2 (A^T A)^-1 on the subsample (its pixels are independent fits).
  const Eigen::Matrix4d cov = rms * rms * ata.inverse();
  cal.steps_per_px_sigma = nominal / (a(0) * a(0)) * std::sqrt(std::max(0.0, cov(0, 0)));
  for (int q = 0; q < 3; ++q)
    cal.gain_sigma[q] = std::sqrt(std::max(0.0, cov(q + 1, q + 1))) / a(0);
  cal.s_min = std::numeric_limits<double>::infinity();
  cal.s_max = -cal.s_min;
  for (const auto& s : all) {
    const double g =
        1 + cal.gain_x * s.un + cal.gain_y * s.vn + cal.gain_r * (s.un * s.un + s.vn * s.vn);
    const double m = cal.calibrated.steps_per_px / g;
    cal.model_map.channel(0)[s.pixel] = static_cast<float>(m);
    cal.s_min = std::min(cal.s_min, m);
    cal.s_max = std::max(cal.s_max, m);
  }
  cal.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return cal;
}

Json ShifterCalibration::ToJson() const {
  return {{"session", session},
          {"nominal", ShifterJson(nominal)},
          {"calibrated", ShifterJson(calibrated)},
          {"steps_per_px_sigma", steps_per_px_sigma},
          {"median_steps_per_px", median_steps_per_px},
          {"model",
           "steps per projector px s(u, v) = steps_per_px / g, g = 1 + gain_x un + gain_y vn + "
           "gain_r (un^2 + vn^2), un = (u - cx) / (W/2), vn = (v - cy) / (H/2) on the projector"},
          {"gain_x", gain_x},
          {"gain_y", gain_y},
          {"gain_r", gain_r},
          {"gain_sigma", {gain_sigma[0], gain_sigma[1], gain_sigma[2]}},
          {"steps_per_px_over_view", {s_min, s_max}},
          {"pixel_scatter_rel", pixel_sigma_rel},
          {"model_rms_rel", model_rms_rel},
          {"pixels", pixels},
          {"inliers", inliers},
          {"seconds", seconds}};
}

std::string ShifterCalibration::BriefReport() const {
  std::ostringstream o;
  o << std::setprecision(6) << "lens shifter: " << calibrated.steps_per_px << " +- "
    << std::setprecision(2) << steps_per_px_sigma << " steps/px at the projector centre (rig said "
    << std::setprecision(6) << nominal.steps_per_px << "), " << std::setprecision(5) << s_min
    << " .. " << s_max << " over the view (gain x " << std::setprecision(3) << gain_x << ", y "
    << gain_y << ", r " << gain_r << "), " << pixels << " pixels";
  return o.str();
}

void WriteShifterMapPng(const ShifterCalibration& cal, const std::filesystem::path& path) {
  const ImageF& m = cal.steps_map;
  if (m.pixels() == 0) return;
  std::vector<float> v;
  for (size_t i = 0; i < m.pixels(); i += 7)
    if (std::isfinite(m.channel(0)[i])) v.push_back(m.channel(0)[i]);
  if (v.empty()) return;
  std::sort(v.begin(), v.end());
  const double lo = v[v.size() / 100], hi = std::max<double>(v[v.size() * 99 / 100], lo + 1e-6);
  const int W = m.width(), H = m.height();
  cv::Mat grey(H, W, CV_8U), valid(H, W, CV_8U);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const float s = m.channel(0)[static_cast<size_t>(y) * W + x];
      valid.at<uint8_t>(y, x) = std::isfinite(s) ? 255 : 0;
      grey.at<uint8_t>(y, x) =
          std::isfinite(s)
              ? static_cast<uint8_t>(std::clamp((s - lo) / (hi - lo) * 255.0, 0.0, 255.0))
              : 0;
    }
  cv::Mat colour;
  cv::applyColorMap(grey, colour, cv::COLORMAP_VIRIDIS);
  colour.setTo(cv::Scalar(0, 0, 0), valid == 0);
  const double scale = std::min(1.0, 1200.0 / std::max(W, H));
  if (scale < 1.0) cv::resize(colour, colour, cv::Size(), scale, scale, cv::INTER_AREA);
  // Scale bar and label below.
  const int cw = colour.cols, bar = 18, text = 40;
  cv::Mat canvas(colour.rows + bar + text, std::max(cw, 480), CV_8UC3, cv::Scalar(255, 255, 255));
  colour.copyTo(canvas(cv::Rect(0, 0, cw, colour.rows)));
  for (int x = 0; x < canvas.cols; ++x) {
    cv::Mat one(1, 1, CV_8U, cv::Scalar(static_cast<int>(255.0 * x / (canvas.cols - 1))));
    cv::Mat c;
    cv::applyColorMap(one, c, cv::COLORMAP_VIRIDIS);
    canvas(cv::Rect(x, colour.rows + 2, 1, bar - 4)).setTo(c.at<cv::Vec3b>(0, 0));
  }
  std::ostringstream label;
  label << std::setprecision(5) << "steps per projector px: " << lo << " (left) .. " << hi
        << " (right); S = " << cal.calibrated.steps_per_px << " at the projector centre";
  cv::putText(canvas, label.str(), cv::Point(6, colour.rows + bar + 26), cv::FONT_HERSHEY_SIMPLEX,
              0.45, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  ImageU8 out(canvas.cols, canvas.rows, 3);
  for (int y = 0; y < canvas.rows; ++y)
    for (int x = 0; x < canvas.cols; ++x) {
      const cv::Vec3b px = canvas.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c)
        out.channel(c)[static_cast<size_t>(y) * canvas.cols + x] = px[2 - c];
    }
  WritePng8(path, out);
}

}  // namespace mesoscan
