#include "compare/compare.h"

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <memory>
#include <sstream>
#include <vector>

#include "compare/planar_alignment.h"
#include "compare/registration_module.h"
#include "core/error.h"
#include "core/fs.h"
#include "core/image_io.h"
#include "core/module.h"
#include "core/parallel.h"
#include "core/robust_stats.h"
#include "core/stage_timer.h"
#include "maps/colour_map_png.h"

namespace mesoscan {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr double kCoarseVoxels = 20000;

bool InRegion(const HeightField& hf, int i, int j, const CompareOptions& o) {
  const float z = hf.z(i, j);
  if (!std::isfinite(z)) return false;
  if (o.region == CompareOptions::Region::kObject && !(z > o.mount_clearance_m)) return false;
  return true;
}

// The scan's confident points in the region (world metres) with their normals, at most
// max_points of them (an even stride). Returns how many there were before the stride.
size_t MakeCloud(const Scan& s, const CompareOptions& o, bool use_masks, int max_points,
                 std::vector<Vec3d>* points, std::vector<Vec3d>* normals) {
  const HeightField& hf = s.height;
  const ImageF& n = s.normals;
  std::vector<int> idx;
  for (int j = 0; j < hf.height(); ++j)
    for (int i = 0; i < hf.width(); ++i) {
      if (!InRegion(hf, i, j, o)) continue;
      if (!hf.confidence.empty() && !(hf.confidence(i, j) >= o.min_confidence)) continue;
      if (use_masks && !o.mask.empty() && !(o.mask(i, j) != 0)) continue;
      if (use_masks && !o.exclude.empty() && o.exclude(i, j) != 0) continue;
      if (!std::isfinite(n(i, j, 0)) || !std::isfinite(n(i, j, 2))) continue;
      idx.push_back(j * hf.width() + i);
    }
  const size_t stride =
      std::max<size_t>(1, (idx.size() + static_cast<size_t>(max_points) - 1) / max_points);
  for (size_t k = 0; k < idx.size(); k += stride) {
    const int i = idx[k] % hf.width(), j = idx[k] / hf.width();
    points->emplace_back(hf.X(i), hf.Y(j), hf.z(i, j));
    normals->emplace_back(Vec3d(n(i, j, 0), n(i, j, 1), n(i, j, 2)).normalized());
  }
  return idx.size();
}

// The field's object pixels (in the region, confident; A's masks when use_masks): 1, else 0.
ImageU8 ObjectPixels(const HeightField& hf, const CompareOptions& o, bool use_masks) {
  ImageU8 in(hf.width(), hf.height(), 1, 0);
  for (int j = 0; j < hf.height(); ++j)
    for (int i = 0; i < hf.width(); ++i) {
      if (!InRegion(hf, i, j, o)) continue;
      if (!hf.confidence.empty() && !(hf.confidence(i, j) >= o.min_confidence)) continue;
      if (use_masks && !o.mask.empty() && !(o.mask(i, j) != 0)) continue;
      if (use_masks && !o.exclude.empty() && o.exclude(i, j) != 0) continue;
      in(i, j) = 1;
    }
  return in;
}

// The deviation of B from A at one of A's points, for the refinement on the height fields: B's
// height (bilinear) under the point moved by a correction w (rotation vector), tau (applied in A's
// frame) and then a_to_b, minus the point's height, along A's normal; 0 where B has no surface.
struct HeightResidual {
  HeightResidual(const HeightField& b, const Mat4d& a_to_b, const Vec3d& p, double nz)
      : b(b), a_to_b(a_to_b), p(p), nz(nz) {}
  template <typename T>
  bool operator()(const T* const w, const T* const tau, T* r) const {
    const T pa[3] = {T(p.x()), T(p.y()), T(p.z())};
    T pr[3];
    ceres::AngleAxisRotatePoint(w, pa, pr);
    for (int k = 0; k < 3; ++k) pr[k] += tau[k];
    T q[3];
    for (int k = 0; k < 3; ++k)
      q[k] = T(a_to_b(k, 0)) * pr[0] + T(a_to_b(k, 1)) * pr[1] + T(a_to_b(k, 2)) * pr[2] +
             T(a_to_b(k, 3));
    const T fi = (q[0] - T(b.x0)) / T(b.pixel_size), fj = (T(b.y0) - q[1]) / T(b.pixel_size);
    const int i0 = static_cast<int>(std::floor(ceres::internal::AsScalar(fi)));
    const int j0 = static_cast<int>(std::floor(ceres::internal::AsScalar(fj)));
    r[0] = T(0);
    if (i0 < 0 || j0 < 0 || i0 + 1 >= b.width() || j0 + 1 >= b.height()) return true;
    const double z00 = b.z(i0, j0), z10 = b.z(i0 + 1, j0), z01 = b.z(i0, j0 + 1),
                 z11 = b.z(i0 + 1, j0 + 1);
    if (!std::isfinite(z00 + z10 + z01 + z11)) return true;
    const T a = fi - T(i0), c = fj - T(j0);
    const T zb =
        (T(1) - a) * (T(1) - c) * z00 + a * (T(1) - c) * z10 + (T(1) - a) * c * z01 + a * c * z11;
    r[0] = T(nz) * (zb - q[2]);
    return true;
  }
  const HeightField& b;
  const Mat4d& a_to_b;
  Vec3d p;
  double nz;
};

// Refines b_to_a on the height fields themselves: the deviation at A's points (at most
// max_points, an even stride) minimised with Tukey's kernel at 4.685 `scale` (Ceres). Unlike
// the nearest-neighbour pairs of ICP, B is a continuous surface here and only A's points count,
// so B's surface where A has none (holes A did not see, a filled mesh) pulls nothing, and the
// optimum is the one the deviation map measures.
Mat4d RefineOnHeights(const HeightField& ha, const ImageF& na, const ImageU8& a_object,
                      const HeightField& hb, const Mat4d& b_to_a, double scale, int max_points) {
  std::vector<int> idx;
  for (int j = 0; j < ha.height(); ++j)
    for (int i = 0; i < ha.width(); ++i)
      if (a_object(i, j) && std::isfinite(na(i, j, 2))) idx.push_back(j * ha.width() + i);
  const size_t stride =
      std::max<size_t>(1, (idx.size() + static_cast<size_t>(max_points) - 1) / max_points);
  const Mat4d a_to_b = b_to_a.inverse();
  double w[3] = {0, 0, 0}, tau[3] = {0, 0, 0};
  ceres::Problem::Options po;
  po.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(po);
  ceres::TukeyLoss loss(4.685 * scale);
  for (size_t k = 0; k < idx.size(); k += stride) {
    const int i = idx[k] % ha.width(), j = idx[k] / ha.width();
    problem.AddResidualBlock(
        new ceres::AutoDiffCostFunction<HeightResidual, 1, 3, 3>(new HeightResidual(
            hb, a_to_b, Vec3d(ha.X(i), ha.Y(j), ha.z(i, j)), static_cast<double>(na(i, j, 2)))),
        &loss, w, tau);
  }
  if (problem.NumResidualBlocks() < 6) return b_to_a;
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_QR;
  so.max_num_iterations = 30;
  so.num_threads = 2;
  so.logging_type = ceres::SILENT;
  so.function_tolerance = 1e-12;
  so.gradient_tolerance = 1e-16;
  so.parameter_tolerance = 1e-12;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  // a_to_b' = a_to_b * C with C = (R(w), tau); b_to_a' = C^-1 * b_to_a.
  Mat4d c = Mat4d::Identity();
  const Vec3d wv(w[0], w[1], w[2]);
  if (wv.norm() > 0)
    c.topLeftCorner<3, 3>() = Eigen::AngleAxisd(wv.norm(), wv.normalized()).matrix();
  c.topRightCorner<3, 1>() = Vec3d(tau[0], tau[1], tau[2]);
  return c.inverse() * b_to_a;
}

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(q * (v.size() - 1) + 0.5));
  std::nth_element(v.begin(), v.begin() + k, v.end());
  return v[k];
}

}  // namespace

MESOSCAN_DECLARE_MODULE(open3d);

const RegistrationModule& Registration() {
  return *static_cast<const RegistrationModule*>(MESOSCAN_MODULE(open3d));
}

void CompareOptions::Check() const {
  if (!(mount_clearance_m >= 0 && std::isfinite(mount_clearance_m)))
    MESOSCAN_BAD_OPTION("CompareOptions.mount_clearance_m", "expected a finite value >= 0 (m)");
  if (!(min_confidence >= 0 && min_confidence < 1))
    MESOSCAN_BAD_OPTION("CompareOptions.min_confidence", "expected a value in [0, 1)");
  if (!(k_sigma > 0 && std::isfinite(k_sigma)))
    MESOSCAN_BAD_OPTION("CompareOptions.k_sigma", "expected a finite value > 0");
  if (window < 1 || window % 2 == 0 || window > 51)
    MESOSCAN_BAD_OPTION("CompareOptions.window", "expected an odd number of pixels in 1..51");
  if (!(coarse_voxel_m >= 0 && coarse_voxel_m < 0.1))
    MESOSCAN_BAD_OPTION("CompareOptions.coarse_voxel_m", "expected 0 (auto) or (0, 0.1) m");
  if (max_icp_points < 1000)
    MESOSCAN_BAD_OPTION("CompareOptions.max_icp_points", "expected >= 1000");
}

std::optional<double> PredictedSigma(const Scan& scan) {
  const Json& r = scan.report;
  if (r.is_object() && r.contains("summary") && r["summary"].is_object() &&
      r["summary"].contains("predicted_depth_rms_m") &&
      r["summary"]["predicted_depth_rms_m"].is_number()) {
    const double s = r["summary"]["predicted_depth_rms_m"].get<double>();
    if (s > 0 && std::isfinite(s)) return s;
  }
  return std::nullopt;
}

Scan ScanFromMesh(const std::filesystem::path& path, double pixel_size_m) {
  MESOSCAN_CHECK(pixel_size_m > 0);
  if (!std::filesystem::is_regular_file(path))
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "no such file");
  const MeshRaster r = Registration().RasterMesh(path.string(), pixel_size_m);
  Scan s;
  HeightField& hf = s.height;
  hf.x0 = r.x0;
  hf.y0 = r.y0;
  hf.pixel_size = r.pixel_size;
  hf.z = ImageF(r.width, r.height, 1);
  std::copy(r.z.begin(), r.z.end(), hf.z.data().begin());
  hf.confidence = ImageF(r.width, r.height, 1, 0.0f);
  for (size_t k = 0; k < r.z.size(); ++k)
    if (std::isfinite(r.z[k])) hf.confidence.data()[k] = 1.0f;
  s.normals = hf.Normals();
  s.points.xyz = ImageF(2, 2, 3, kNaN);
  s.points.confidence = ImageF(2, 2, 1, 0.0f);
  s.points.projector_u = ImageF(2, 2, 1, kNaN);
  s.report["mesh"] = {{"file", path.string()}, {"triangles", r.triangles}};
  return s;
}

std::string CompareResult::BriefReport() const {
  std::ostringstream os;
  os << std::fixed << std::setprecision(2);
  const Json& d = report.at("deviation");
  os << "compared " << d.at("pixels").get<int64_t>() << " pixels: deviation RMS "
     << report.at("deviation_rms_um").get<double>() << " um";
  if (report.value("predicted_sigma_um", Json(nullptr)).is_number())
    os << " (predicted sigma " << report.at("predicted_sigma_um").get<double>() << " um), changed "
       << std::setprecision(4) << 100.0 * report.at("changed_fraction").get<double>() << " %"
       << std::setprecision(2);
  else
    os << " (no predicted noise: no change test)";
  os << "; registration RMS " << report.at("registration").at("inlier_rms_um").get<double>()
     << " um in " << report.at("timings_s").at("total").get<double>() << " s";
  return os.str();
}

CompareResult CompareScans(const Scan& a, const Scan& b, const CompareOptions& o,
                           const std::string& a_name, const std::string& b_name) {
  o.Check();
  const Stopwatch total;
  const HeightField& ha = a.height;
  const HeightField& hb = b.height;
  for (const ImageF* m : {&o.mask, &o.exclude})
    if (!m->empty() && (m->width() != ha.width() || m->height() != ha.height()))
      MESOSCAN_BAD_OPTION(m == &o.mask ? "CompareOptions.mask" : "CompareOptions.exclude",
                          "expected a mask of A's " << ha.width() << "x" << ha.height()
                                                    << " height grid, got " << m->width() << "x"
                                                    << m->height());
  Scan an = a, bn = b;  // normals computed from the height where the folder had none
  if (an.normals.empty()) an.normals = ha.Normals();
  if (bn.normals.empty()) bn.normals = hb.Normals();

  // ---- clouds ----
  RegistrationInput in;
  const size_t a_count =
      MakeCloud(an, o, /*use_masks=*/true, 4 * o.max_icp_points, &in.a_points, &in.a_normals);
  MakeCloud(bn, o, /*use_masks=*/false, o.max_icp_points, &in.b_points, &in.b_normals);
  constexpr size_t kMinPoints = 500;
  if (in.a_points.size() < kMinPoints)
    MESOSCAN_BAD_INPUT_AT(
        ErrorSite::File(std::filesystem::path(a_name) / "height.exr"),
        "only " << in.a_points.size()
                << " confident points in the compared region, expected >= " << kMinPoints);
  if (in.b_points.size() < kMinPoints)
    MESOSCAN_BAD_INPUT_AT(
        ErrorSite::File(std::filesystem::path(b_name) / "height.exr"),
        "only " << in.b_points.size()
                << " confident points in the compared region, expected >= " << kMinPoints);
  const double px = std::max(ha.pixel_size, hb.pixel_size);
  // Auto voxel: 4 pixels, larger for a large field (at most ~20000 voxels of A's points: the
  // features and RANSAC cost grows with their count, the coarse alignment needs no more).
  const double voxel =
      o.coarse_voxel_m > 0
          ? o.coarse_voxel_m
          : std::max(4 * px, std::sqrt(static_cast<double>(a_count) * px * px / kCoarseVoxels));
  Json timings;

  // ---- coarse placement from the height images (OpenCV), then registration (Open3D) ----
  const Stopwatch t_planar;
  const ImageU8 a_object = ObjectPixels(ha, o, /*use_masks=*/true);
  const std::vector<PlanarCandidate> planar =
      PlanarAlignment(ha, a_object, hb, ObjectPixels(hb, o, /*use_masks=*/false));
  for (const PlanarCandidate& c : planar) in.starts.push_back(c.b_to_a);
  timings["planar"] = t_planar.Seconds();
  in.voxel_m = voxel;
  in.max_distance_m = 2 * px;
  in.seed = o.seed;
  // B a mesh (ScanFromMesh): its coverage differs from A's (a mesh is often filled where A has
  // holes, its outline differs), so only B's points over A's surface pair, and the transform is
  // then refined on the deviation itself (RefineOnHeights). A surface under a point: the four
  // pixels around it are A's confident object pixels.
  const bool b_is_mesh = b.report.contains("mesh");
  if (b_is_mesh)
    in.a_has_surface = [&ha, &a_object](const Vec3d& q) {
      const int i = static_cast<int>(std::floor(ha.I(q.x())));
      const int j = static_cast<int>(std::floor(ha.J(q.y())));
      if (i < 0 || j < 0 || i + 1 >= ha.width() || j + 1 >= ha.height()) return false;
      return a_object(i, j) && a_object(i + 1, j) && a_object(i, j + 1) && a_object(i + 1, j + 1);
    };
  const RegistrationOutput reg = Registration().Register(in);
  timings["coarse"] = reg.seconds_coarse;
  timings["fine"] = reg.seconds_fine;
  if (reg.coarse_icp_fitness < 0.3)
    MESOSCAN_BAD_INPUT(
        a_name << ", " << b_name << ": the coarse alignment found no consistent transform (overlap "
               << reg.coarse_icp_fitness << " of B's points); are they scans of the same object?");
  const Stopwatch t_heights;
  const Mat4d t = b_is_mesh
                      ? RefineOnHeights(ha, an.normals, a_object, hb, reg.b_to_a,
                                        std::max(reg.robust_sigma_m, 0.2e-6), o.max_icp_points)
                      : reg.b_to_a;
  if (b_is_mesh) timings["heights"] = t_heights.Seconds();
  Eigen::Matrix<double, 6, 6> cov = Eigen::Matrix<double, 6, 6>::Zero();
  if (reg.inliers > 6) cov = (reg.sum_squares / (reg.inliers - 6)) * reg.jtj.inverse();

  // ---- deviation on A's grid ----
  Stopwatch t_dev;
  CompareResult out;
  out.b_to_a = t;
  out.covariance = cov;
  out.grid = ha;
  out.grid.z = ImageF();
  out.grid.confidence = ImageF();
  const int w = ha.width(), h = ha.height();
  out.deviation = ImageF(w, h, 1, kNaN);
  out.sigma = ImageF(w, h, 1, kNaN);
  out.changed = ImageF(w, h, 1, kNaN);
  const std::optional<double> sig_a = PredictedSigma(a), sig_b = PredictedSigma(b);
  const bool have_sigma = sig_a && sig_b;
  const Mat4d a_to_b = t.inverse();
  const Mat3d Rab = a_to_b.topLeftCorner<3, 3>();
  const Vec3d tab = a_to_b.topRightCorner<3, 1>();
  ParallelForRows(h, [&](int j0, int j1) {
    for (int j = j0; j < j1; ++j)
      for (int i = 0; i < w; ++i) {
        if (!InRegion(ha, i, j, o)) continue;
        if (!o.mask.empty() && !(o.mask(i, j) != 0)) continue;
        if (!o.exclude.empty() && o.exclude(i, j) != 0) continue;
        const Vec3d na(an.normals(i, j, 0), an.normals(i, j, 1), an.normals(i, j, 2));
        if (!na.allFinite()) continue;
        const Vec3d q = Rab * Vec3d(ha.X(i), ha.Y(j), ha.z(i, j)) + tab;
        const double zb = hb.Sample(q.x(), q.y());
        if (!std::isfinite(zb)) continue;
        if (o.region == CompareOptions::Region::kObject && !(zb > o.mount_clearance_m)) continue;
        // Distance along A's normal (in B's frame) from A's point to B's surface, taken as the
        // plane through B's point above q with that normal.
        const Vec3d nb = Rab * na;
        out.deviation(i, j) = static_cast<float>(nb.z() * (zb - q.z()));
        if (have_sigma)
          out.sigma(i, j) = static_cast<float>(std::abs(nb.z()) * std::hypot(*sig_a, *sig_b));
      }
  });
  // The change test on window means (the per-pixel test would flag 0.27% of pure noise at 3
  // sigma); the window mean's sigma assumes independent pixels.
  const int r = o.window / 2;
  int64_t compared = 0, changed = 0;
  std::vector<double> devs;
  if (have_sigma) {
    std::vector<int64_t> changed_rows(h, 0);
    ParallelForRows(h, [&](int j0, int j1) {
      for (int j = j0; j < j1; ++j)
        for (int i = 0; i < w; ++i) {
          if (!std::isfinite(out.deviation(i, j))) continue;
          double sum = 0, var = 0;
          int n = 0;
          for (int y = std::max(0, j - r); y <= std::min(h - 1, j + r); ++y)
            for (int x = std::max(0, i - r); x <= std::min(w - 1, i + r); ++x) {
              const float d = out.deviation(x, y);
              if (!std::isfinite(d)) continue;
              sum += d;
              var += static_cast<double>(out.sigma(x, y)) * out.sigma(x, y);
              ++n;
            }
          const double mean = sum / n, sm = std::sqrt(var) / n;
          const bool c = std::abs(mean) > o.k_sigma * sm;
          out.changed(i, j) = c ? 1.0f : 0.0f;
          changed_rows[j] += c;
        }
    });
    for (int64_t c : changed_rows) changed += c;
  }
  for (float d : out.deviation.data())
    if (std::isfinite(d)) devs.push_back(d);
  compared = static_cast<int64_t>(devs.size());
  if (compared == 0)
    MESOSCAN_BAD_INPUT(a_name << ", " << b_name << ": no pixel of A's grid has a point of B "
                              << "after registration: nothing to compare");
  double ss = 0;
  for (double d : devs) ss += d * d;
  const double rms = std::sqrt(ss / compared);

  // Repeatability: over non-overlapping window blocks of unchanged pixels, the RMS of the block
  // means against the RMS their predicted sigmas give.
  double block_ss = 0, block_pred = 0, unchanged_ss = 0, unchanged_pred = 0;
  int64_t blocks = 0, unchanged = 0;
  if (have_sigma) {
    for (int j = 0; j < h; ++j)
      for (int i = 0; i < w; ++i)
        if (out.changed(i, j) == 0.0f) {
          unchanged_ss += static_cast<double>(out.deviation(i, j)) * out.deviation(i, j);
          unchanged_pred += static_cast<double>(out.sigma(i, j)) * out.sigma(i, j);
          ++unchanged;
        }
    const int bw = o.window;
    for (int j = 0; j + bw <= h; j += bw)
      for (int i = 0; i + bw <= w; i += bw) {
        double sum = 0, var = 0;
        bool ok = true;
        for (int y = j; y < j + bw && ok; ++y)
          for (int x = i; x < i + bw && ok; ++x) {
            ok = out.changed(x, y) == 0.0f;
            sum += out.deviation(x, y);
            var += static_cast<double>(out.sigma(x, y)) * out.sigma(x, y);
          }
        if (!ok) continue;
        const double n = bw * bw;
        block_ss += (sum / n) * (sum / n);
        block_pred += var / (n * n);
        ++blocks;
      }
  }
  timings["deviation"] = t_dev.Seconds();
  timings["total"] = total.Seconds();

  // ---- report ----
  Json& rep = out.report;
  rep["format"] = "mesoscan-compare/1";
  rep["b_to_a"] = MatrixToJson(t);
  rep["b_to_a_units"] = "metres; row-major 4x4 taking B's world coordinates to A's";
  {
    const Eigen::AngleAxisd aa(Mat3d(t.topLeftCorner<3, 3>()));
    rep["b_to_a_rotation_deg"] = aa.angle() * 180.0 / 3.14159265358979323846;
    rep["b_to_a_translation_mm"] = {t(0, 3) * 1e3, t(1, 3) * 1e3, t(2, 3) * 1e3};
  }
  Json unc;
  unc["rotation_sigma_urad"] = {std::sqrt(cov(0, 0)) * 1e6, std::sqrt(cov(1, 1)) * 1e6,
                                std::sqrt(cov(2, 2)) * 1e6};
  unc["translation_sigma_um"] = {std::sqrt(cov(3, 3)) * 1e6, std::sqrt(cov(4, 4)) * 1e6,
                                 std::sqrt(cov(5, 5)) * 1e6};
  {
    // RMS over A's registered points of the displacement's sigma (omega x p + tau).
    double acc = 0;
    for (const Vec3d& p : in.a_points) {
      Eigen::Matrix<double, 3, 6> jp;
      jp << 0, p.z(), -p.y(), 1, 0, 0, -p.z(), 0, p.x(), 0, 1, 0, p.y(), -p.x(), 0, 0, 0, 1;
      acc += (jp * cov * jp.transpose()).trace();
    }
    unc["displacement_sigma_rms_um"] = std::sqrt(acc / in.a_points.size()) * 1e6;
  }
  unc["covariance"] = MatrixToJson(cov);
  unc["covariance_order"] = "rx, ry, rz (rad), tx, ty, tz (m), a correction applied after b_to_a";
  unc["note"] = "from the point-to-plane fit, residuals taken as independent";
  rep["b_to_a_uncertainty"] = unc;
  Json regj;
  regj["coarse_fitness"] = reg.coarse_fitness;
  regj["coarse_rmse_um"] = reg.coarse_rmse_m * 1e6;
  regj["coarse_refined_fitness"] = reg.coarse_icp_fitness;
  regj["coarse_hypotheses"] = reg.coarse_hypotheses;
  regj["coarse_voxel_m"] = voxel;
  regj["points_a"] = in.a_points.size();
  regj["points_b"] = in.b_points.size();
  regj["points_b_on_a"] = reg.b_on_a;
  regj["points_b_inliers"] = reg.b_inliers;
  regj["inlier_rms_um"] = reg.inliers ? std::sqrt(reg.sum_squares / reg.inliers) * 1e6 : 0.0;
  regj["robust_sigma_um"] = reg.robust_sigma_m * 1e6;
  regj["planar_candidates"] = Json::array();
  for (const PlanarCandidate& c : planar)
    regj["planar_candidates"].push_back(
        {{"rotation_z_deg", c.angle_deg}, {"response", c.response}});
  regj["method"] =
      "starts from phase correlation of the height images' relief over rotations about z "
      "(OpenCV) and from FPFH + RANSAC (Open3D), each refined by point-to-plane ICP and scored; "
      "then point-to-plane ICP with Tukey's kernel, points beyond 3 robust sigmas excluded and "
      "refit";
  if (b_is_mesh)
    regj["mesh_steps"] =
        "B a mesh: only B's points over A's surface pair (coarse and fine), then the deviation at "
        "A's points minimised on the height fields (Ceres, Tukey's kernel)";
  rep["registration"] = regj;
  rep["deviation_rms_um"] = rms * 1e6;
  Json dev;
  dev["pixels"] = compared;
  dev["sign"] = "positive: B above A (material added); along A's normal";
  for (const auto& [name, q] : std::vector<std::pair<std::string, double>>{
           {"p01", 0.01}, {"p05", 0.05}, {"p50", 0.5}, {"p95", 0.95}, {"p99", 0.99}})
    dev["percentiles_um"][name] = Percentile(devs, q) * 1e6;
  {
    std::vector<double> ad(devs);
    for (double& v : ad) v = std::abs(v);
    dev["abs_p50_um"] = Percentile(ad, 0.5) * 1e6;
    dev["abs_p95_um"] = Percentile(ad, 0.95) * 1e6;
    // A histogram of the signed deviation: 61 bins over +-p99 of |d|.
    const double hi = std::max(Percentile(ad, 0.99), 1e-9);
    std::vector<int64_t> bins(61, 0);
    for (double v : devs) {
      const int k = static_cast<int>(std::floor((v / hi + 1) * 30.5));
      ++bins[std::clamp(k, 0, 60)];
    }
    dev["histogram"] = {{"lo_um", -hi * 1e6}, {"hi_um", hi * 1e6}, {"counts", bins}};
  }
  rep["deviation"] = dev;
  if (have_sigma) {
    const double pred = std::hypot(*sig_a, *sig_b);
    rep["predicted_sigma_um"] = pred * 1e6;
    rep["predicted_sigma_a_um"] = *sig_a * 1e6;
    rep["predicted_sigma_b_um"] = *sig_b * 1e6;
    rep["changed_fraction"] = static_cast<double>(changed) / compared;
    rep["changed_area_mm2"] = changed * ha.pixel_size * ha.pixel_size * 1e6;
    rep["change_test"] = {{"k_sigma", o.k_sigma},
                          {"window_px", o.window},
                          {"rule",
                           "|mean deviation over the window| > k_sigma * its predicted sigma "
                           "(the pixels' predicted sigmas taken as independent)"}};
    Json rp;
    rp["deviation_rms_um"] = unchanged ? std::sqrt(unchanged_ss / unchanged) * 1e6 : 0.0;
    rp["predicted_rms_um"] = unchanged ? std::sqrt(unchanged_pred / unchanged) * 1e6 : 0.0;
    rp["block_mean_rms_um"] = blocks ? std::sqrt(block_ss / blocks) * 1e6 : 0.0;
    rp["predicted_block_mean_rms_um"] = blocks ? std::sqrt(block_pred / blocks) * 1e6 : 0.0;
    rp["ratio"] = blocks && block_pred > 0 ? std::sqrt(block_ss / block_pred) : 0.0;
    rp["blocks"] = blocks;
    rp["note"] =
        "over the unchanged pixels: the deviation's RMS per pixel, and of its means over "
        "non-overlapping window blocks against what the scans' predicted sigmas give (ratio 1: "
        "the scans agree as their noise predicts)";
    rep["repeatability"] = rp;
  } else {
    rep["predicted_sigma_um"] = nullptr;
    rep["changed_fraction"] = nullptr;
    rep["warnings"].push_back(
        "a scan carries no predicted noise (report.json summary.predicted_depth_rms_m): no "
        "change test and no repeatability ratio");
  }
  rep["grid"] = {
      {"width", w}, {"height", h}, {"x0", ha.x0}, {"y0", ha.y0}, {"pixel_size", ha.pixel_size}};
  rep["options"] = {{"region", o.region == CompareOptions::Region::kObject ? "object" : "all"},
                    {"mount_clearance_m", o.mount_clearance_m},
                    {"mask", !o.mask.empty()},
                    {"exclude", !o.exclude.empty()},
                    {"min_confidence", o.min_confidence},
                    {"k_sigma", o.k_sigma},
                    {"window", o.window},
                    {"seed", o.seed}};
  rep["timings_s"] = timings;
  if (have_sigma && static_cast<double>(changed) / compared > 0.1)
    rep["warnings"].push_back(
        "more than 10% of the compared area changed beyond k sigma: unless the object changed "
        "that much, the registration failed (a near-symmetric object, too little relief); look "
        "at deviation.png");
  if (reg.coarse_icp_fitness < 0.5 || reg.b_inliers < 0.5 * in.b_points.size())
    rep["warnings"].push_back(
        "less than half of B's points registered onto A: check that the scans overlap");
  return out;
}

void WriteComparison(const std::filesystem::path& dir, const CompareResult& r) {
  std::map<std::string, double> attrs = {
      {kAttrX0, r.grid.x0}, {kAttrY0, r.grid.y0}, {kAttrPixelSize, r.grid.pixel_size}};
  WriteExrPlanes(dir / "deviation.exr",
                 {{"Z", &r.deviation}, {"sigma", &r.sigma}, {"changed", &r.changed}}, attrs);
  ColourMapStyle style;
  style.kind = ColourMapStyle::Kind::kDiverging;
  style.title = "deviation of B from A";
  style.pixel_size_m = r.grid.pixel_size;
  const Json& rep = r.report;
  if (rep.contains("predicted_sigma_um") && rep["predicted_sigma_um"].is_number())
    style.hi = std::max(4 * rep["predicted_sigma_um"].get<double>(),
                        std::abs(rep["deviation"]["percentiles_um"]["p01"].get<double>())) *
               1e-6;
  WriteColourMapPng(dir / "deviation.png", r.deviation, style);
  WriteJsonFile(dir / "report.json", r.report);
}

}  // namespace mesoscan
