#include "sim/ground_truth.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "core/budget.h"
#include "core/error.h"
#include "core/image_io.h"
#include "core/numbers.h"
#include "heightfield/lens_shift_fit.h"

namespace mesoscan {

Json GroundTruthErrors::ToJson() const {
  return {{"depth_error", "Z(reconstructed) - Z(gt_points.exr) at the same camera pixel, metres"},
          {"pixels_gt", pixels_gt},
          {"pixels_both", pixels_both},
          {"coverage", coverage},
          {"rms_m", rms_m},
          {"mean_m", mean_m},
          {"median_abs_m", median_abs_m},
          {"p99_abs_m", p99_abs_m},
          {"max_abs_m", max_abs_m},
          {"gross", gross},
          {"gross_fraction", gross_fraction},
          {"gross_threshold_m", gross_threshold_m},
          {"inlier_scale_m", inlier_scale_m},
          {"footprint_known", footprint_known},
          {"mixed_relief_m", mixed_relief_m},
          {"pixels_mixed", pixels_mixed},
          {"mixed_kept", mixed_kept},
          {"gross_mixed", gross_mixed},
          {"coverage_single", coverage_single}};
}

ImageF LensShiftDepthCrlbMap(const Session& session, const ReconstructDiagnostics& d,
                             const ImageF& error, const std::function<double(double)>& sigma) {
  if (d.ls_amplitude.empty() || session.frames.empty()) return {};
  const double steps_per_px =
      session.rig.lens_shifter ? session.rig.lens_shifter->steps_per_px : 1.0;
  std::vector<double> x;
  for (const Frame& f : session.frames)
    if (f.pattern.type == PatternType::kStripes) x.push_back(f.shift_steps / steps_per_px);
  if (x.empty()) return {};
  const double centre = std::accumulate(x.begin(), x.end(), 0.0) / x.size();
  for (double& v : x) v -= centre;
  ImageF out(d.u.width(), d.u.height(), 1, std::numeric_limits<float>::quiet_NaN());
  for (int y = 0; y < d.u.height(); ++y)
    for (int xx = 0; xx < d.u.width(); ++xx) {
      if (!std::isfinite(error(xx, y)) || !std::isfinite(d.dz_du(xx, y))) continue;
      const double var_phi = LensShiftPhaseCrlb(sigma(d.ls_offset(xx, y)), d.ls_amplitude(xx, y), x,
                                                d.ls_frequency(xx, y),
                                                /*fit_frequency=*/false);
      out(xx, y) = static_cast<float>(std::sqrt(var_phi) / kPi * std::abs(d.dz_du(xx, y)));
    }
  return out;
}

double LensShiftDepthCrlbRms(const Session& session, const ReconstructDiagnostics& d,
                             const ImageF& error, const std::function<double(double)>& sigma) {
  const ImageF floor = LensShiftDepthCrlbMap(session, d, error, sigma);
  double s2 = 0;
  int64_t n = 0;
  for (float v : floor.data())
    if (std::isfinite(v)) {
      s2 += static_cast<double>(v) * v;
      ++n;
    }
  return n ? std::sqrt(s2 / n) : 0.0;
}

namespace {

// The channels the evaluation reads, in this order (the footprint pair may be absent).
const std::vector<std::string> kReadChannels = {"Z", "lit_fraction", "relief"};

}  // namespace

GroundTruthPoints ReadGroundTruthPoints(const Session& session) {
  if (!session.ground_truth)
    MESOSCAN_BAD_INPUT(session.root.string() << "/session.json: ground_truth: not present");
  GroundTruthPoints gt;
  gt.path = session.root / session.ground_truth->points;
  // An OpenEXR gt_points (what the simulator writes): only Z and the footprint channels, straight
  // into planes (full resolution: 37 MB and 0.25 CPU-s, against 124 MB and 0.39 CPU-s for all
  // five channels interleaved through OIIO and then de-interleaved).
  if (ReadExrPlanes(gt.path, kReadChannels, {"X", "Y", "Z"}, &gt.image, &gt.info)) return gt;
  // Any other format OIIO reads: one read, used in place (no header read first, no copy).
  gt.image = ReadImage(gt.path, &gt.info);
  const auto& names = gt.info.channel_names;
  for (const char* c : {"X", "Y", "Z"})
    if (std::find(names.begin(), names.end(), c) == names.end())
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(gt.path), "missing channel '" << c << "'");
  return gt;
}

GroundTruthErrors EvaluateAgainstGroundTruth(const Session& session, const ScanPoints& points,
                                             const PixelRect& roi, double gross_threshold_m) {
  return EvaluateAgainstGroundTruth(ReadGroundTruthPoints(session), points, roi, gross_threshold_m);
}

GroundTruthErrors EvaluateAgainstGroundTruth(const GroundTruthPoints& gt_points,
                                             const ScanPoints& points, const PixelRect& roi_in,
                                             double gross_threshold_m) {
  const auto& path = gt_points.path;
  const ImageF& gt = gt_points.image;
  const auto& names = gt_points.info.channel_names;
  auto channel = [&](const char* c) {
    const auto it = std::find(names.begin(), names.end(), c);
    return it == names.end() ? -1 : static_cast<int>(it - names.begin());
  };
  if (channel("Z") < 0) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "missing channel 'Z'");
  const int cz = channel("Z"), c_lit = channel("lit_fraction"), c_relief = channel("relief");
  const bool footprint = c_lit >= 0 && c_relief >= 0;
  const int w = points.xyz.width(), h = points.xyz.height();
  if (gt.width() != w || gt.height() != h)
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "size " << gt.width() << "x" << gt.height()
                                                         << ", expected the camera's " << w << "x"
                                                         << h);
  PixelRect roi = roi_in;
  if (roi.w <= 0 || roi.h <= 0) roi = {0, 0, w, h};
  GroundTruthErrors e;
  e.error = ImageF(w, h, 1, std::numeric_limits<float>::quiet_NaN());
  std::vector<double> a;  // |error| of every pixel with both (no second copy: 25 MB at 3 Mpx)
  double s = 0, s2 = 0;
  for (int y = std::max(0, roi.y); y < std::min(h, roi.y + roi.h); ++y)
    for (int x = std::max(0, roi.x); x < std::min(w, roi.x + roi.w); ++x) {
      const float zg = gt(x, y, cz);
      if (!std::isfinite(zg)) continue;
      ++e.pixels_gt;
      const float z = points.xyz(x, y, 2);
      if (!std::isfinite(z)) continue;
      const double d = static_cast<double>(z) - zg;
      e.error(x, y) = static_cast<float>(d);
      s += d;
      s2 += d * d;
      a.push_back(std::abs(d));
    }
  e.pixels_both = static_cast<int64_t>(a.size());
  e.coverage = e.pixels_gt ? static_cast<double>(e.pixels_both) / e.pixels_gt : 0.0;
  if (a.empty()) return e;
  e.mean_m = s / a.size();
  e.rms_m = std::sqrt(s2 / a.size());
  // Order statistics by selection (the same values as a full sort, in linear time).
  const size_t i_med = a.size() / 2,
               i_p99 = std::min(a.size() - 1, static_cast<size_t>(0.99 * a.size()));
  std::nth_element(a.begin(), a.begin() + i_p99, a.end());
  e.p99_abs_m = a[i_p99];
  e.max_abs_m = *std::max_element(a.begin() + i_p99, a.end());
  std::nth_element(a.begin(), a.begin() + i_med, a.begin() + i_p99);
  e.median_abs_m = a[i_med];
  {
    double in2 = 0;
    size_t n = 0;
    for (double v : a)
      if (v < 5 * e.median_abs_m) {
        in2 += v * v;
        ++n;
      }
    e.inlier_scale_m = 10 * std::sqrt(in2 / std::max<size_t>(1, n));
  }
  if (gross_threshold_m <= 0) gross_threshold_m = kGrossErrorM;
  e.gross_threshold_m = gross_threshold_m;
  for (double v : a) e.gross += v > gross_threshold_m;
  e.gross_fraction = static_cast<double>(e.gross) / a.size();

  e.footprint_known = footprint;
  e.mixed_relief_m = footprint ? e.inlier_scale_m / 10 : 0.0;
  int64_t single = 0, single_both = 0;
  for (int y = std::max(0, roi.y); y < std::min(h, roi.y + roi.h); ++y)
    for (int x = std::max(0, roi.x); x < std::min(w, roi.x + roi.w); ++x) {
      if (!std::isfinite(gt(x, y, cz))) continue;
      const bool kept = std::isfinite(e.error(x, y));
      const bool mixed =
          footprint && (gt(x, y, c_lit) < 1.0f || gt(x, y, c_relief) > e.mixed_relief_m);
      if (!mixed) {
        ++single;
        single_both += kept;
        continue;
      }
      ++e.pixels_mixed;
      e.mixed_kept += kept;
      e.gross_mixed += kept && std::abs(e.error(x, y)) > gross_threshold_m;
    }
  e.coverage_single = single ? static_cast<double>(single_both) / single : 0.0;
  return e;
}
}  // namespace mesoscan
