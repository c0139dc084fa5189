// libmesoscan_open3d.so (interface: compare/registration_module.h): Open3D's global and ICP
// registration.

#include "compare/registration_module.h"

#include <open3d/geometry/KDTreeFlann.h>
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/TriangleMesh.h>
#include <open3d/io/TriangleMeshIO.h>
#include <open3d/pipelines/registration/Feature.h>
#include <open3d/pipelines/registration/Registration.h>
#include <open3d/pipelines/registration/RobustKernel.h>
#include <open3d/pipelines/registration/TransformationEstimation.h>
#include <open3d/utility/Logging.h>
#include <open3d/utility/Random.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/parallel.h"
#include "core/robust_stats.h"
#include "core/stage_timer.h"

namespace mesoscan {
namespace {

namespace reg = open3d::pipelines::registration;
using open3d::geometry::PointCloud;

// Point-to-plane residuals of `source` moved by t against `target` (nearest neighbour within
// max_dist; NaN where none).
std::vector<double> PlaneResiduals(const PointCloud& source, const PointCloud& target,
                                   const open3d::geometry::KDTreeFlann& tree, const Mat4d& t,
                                   double max_dist, std::vector<int>* nearest = nullptr) {
  std::vector<double> r(source.points_.size(), std::numeric_limits<double>::quiet_NaN());
  if (nearest) nearest->assign(source.points_.size(), -1);
  const Mat3d R = t.topLeftCorner<3, 3>();
  const Vec3d tr = t.topRightCorner<3, 1>();
  ParallelFor(static_cast<int64_t>(source.points_.size()), [&](int64_t k) {
    const Vec3d p = R * source.points_[k] + tr;
    std::vector<int> ind(1);
    std::vector<double> d2(1);
    if (tree.SearchHybrid(p, max_dist, 1, ind, d2) < 1) return;
    r[k] = target.normals_[ind[0]].dot(p - target.points_[ind[0]]);
    if (nearest) (*nearest)[k] = ind[0];
  });
  return r;
}

double RobustSigma(const std::vector<double>& r) {
  std::vector<double> a;
  a.reserve(r.size());
  for (double v : r)
    if (std::isfinite(v)) a.push_back(v);
  if (a.empty()) return 0.0;
  const double med = Median(a);
  for (double& v : a) v = std::abs(v - med);
  return kMadToSigma * Median(a);
}

std::shared_ptr<PointCloud> MakeCloud(const std::vector<Vec3d>& p, const std::vector<Vec3d>& n) {
  auto c = std::make_shared<PointCloud>();
  c->points_ = p;
  c->normals_ = n;
  return c;
}

// The points of `c` that `on_surface` accepts once moved by t (all of `c` when it is empty or
// accepts fewer than 6).
std::shared_ptr<PointCloud> OnSurface(const std::shared_ptr<PointCloud>& c, const Mat4d& t,
                                      const std::function<bool(const Vec3d&)>& on_surface) {
  if (!on_surface) return c;
  auto out = std::make_shared<PointCloud>();
  const Mat3d R = t.topLeftCorner<3, 3>();
  const Vec3d tr = t.topRightCorner<3, 1>();
  for (size_t k = 0; k < c->points_.size(); ++k)
    if (on_surface(R * c->points_[k] + tr)) {
      out->points_.push_back(c->points_[k]);
      out->normals_.push_back(c->normals_[k]);
    }
  return out->points_.size() >= 6 ? out : c;
}

class Module final : public RegistrationModule {
 public:
  RegistrationOutput Register(const RegistrationInput& in) const override {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    RegistrationOutput out;
    const auto ca = MakeCloud(in.a_points, in.a_normals);
    const auto cb = MakeCloud(in.b_points, in.b_normals);
    const double voxel = in.voxel_m, dmax = in.max_distance_m;

    // Coarse: FPFH features + RANSAC, whatever the re-placement, then point-to-plane ICP at the
    // voxel scale (the voxels average the noise).
    const Stopwatch t_coarse;
    auto da = ca->VoxelDownSample(voxel);
    auto db = cb->VoxelDownSample(voxel);
    da->NormalizeNormals();
    db->NormalizeNormals();
    // Hypotheses: RANSAC on FPFH matches, the identity, and the caller's starts or else
    // rotations about z every 10 degrees about the clouds' centroids (a height field's
    // re-placement is mostly that). Each is refined by point-to-plane ICP at the voxel scale and
    // scored by B's voxels' truncated residual against A: the lowest wins. Without the caller's
    // starts RANSAC runs with two seeds (a near-symmetric object such as a coin leaves single runs
    // unreliable); with them, once on voxels twice as large (the generalist for a re-placement
    // the starts miss, at a quarter of the cost).
    const bool have_starts = !in.starts.empty();
    const double fvoxel = have_starts ? 2 * voxel : voxel;
    const auto fda = have_starts ? da->VoxelDownSample(fvoxel) : da;
    const auto fdb = have_starts ? db->VoxelDownSample(fvoxel) : db;
    const open3d::geometry::KDTreeSearchParamHybrid feature_param(5 * fvoxel, 100);
    const auto fa = reg::ComputeFPFHFeature(*fda, feature_param);
    const auto fb = reg::ComputeFPFHFeature(*fdb, feature_param);
    const reg::CorrespondenceCheckerBasedOnEdgeLength edge_check(0.9);
    const reg::CorrespondenceCheckerBasedOnDistance dist_check(1.5 * fvoxel);
    const open3d::geometry::KDTreeFlann tree_da(*da);
    const double tau = 0.3 * voxel;
    auto score = [&](const Mat4d& t) {
      const std::vector<double> r = PlaneResiduals(*db, *da, tree_da, t, voxel);
      double sum = 0;
      for (double v : r) sum += std::isfinite(v) ? std::min(std::abs(v), tau) : tau;
      return r.empty() ? tau : sum / r.size();
    };
    // Each refinement pairs only B's voxels that land on A's surface (in.a_has_surface).
    auto refine = [&](const Mat4d& t0) {
      const reg::RegistrationResult wide = reg::RegistrationICP(
          *OnSurface(db, t0, in.a_has_surface), *da, 3 * voxel, t0,
          reg::TransformationEstimationPointToPlane(), reg::ICPConvergenceCriteria(1e-6, 1e-6, 30));
      return reg::RegistrationICP(
          *OnSurface(db, wide.transformation_, in.a_has_surface), *da, voxel, wide.transformation_,
          reg::TransformationEstimationPointToPlane(), reg::ICPConvergenceCriteria(1e-6, 1e-6, 30));
    };
    std::vector<Mat4d> starts{Mat4d::Identity()};
    for (int k = 0; k < (have_starts ? 1 : 2); ++k) {
      open3d::utility::random::Seed(in.seed + k);
      const reg::RegistrationResult c = reg::RegistrationRANSACBasedOnFeatureMatching(
          *fdb, *fda, *fb, *fa, /*mutual_filter=*/true, 1.5 * fvoxel,
          reg::TransformationEstimationPointToPoint(false), 3, {edge_check, dist_check},
          reg::RANSACConvergenceCriteria(20000, 0.999));
      if (k == 0) {
        out.coarse_fitness = c.fitness_;
        out.coarse_rmse_m = c.inlier_rmse_;
      }
      starts.push_back(c.transformation_);
    }
    for (const Mat4d& t0 : in.starts) starts.push_back(t0);
    const Vec3d ca_mean = da->GetCenter(), cb_mean = db->GetCenter();
    for (int deg = 0; in.starts.empty() && deg < 360; deg += 10) {
      Mat4d t = Mat4d::Identity();
      t.topLeftCorner<3, 3>() =
          Eigen::AngleAxisd(deg * 3.14159265358979323846 / 180.0, Vec3d::UnitZ()).matrix();
      t.topRightCorner<3, 1>() = ca_mean - t.topLeftCorner<3, 3>() * cb_mean;
      t(2, 3) = 0;
      starts.push_back(t);
    }
    double best_score = std::numeric_limits<double>::infinity();
    reg::RegistrationResult coarse_icp;
    const double max_rad = in.max_rotation_deg * 3.14159265358979323846 / 180.0;
    for (const Mat4d& t0 : starts) {
      const reg::RegistrationResult r = refine(t0);
      if (in.max_rotation_deg < 180 &&
          Eigen::AngleAxisd(Mat3d(r.transformation_.topLeftCorner<3, 3>())).angle() > max_rad)
        continue;
      const double sc = score(r.transformation_);
      if (sc < best_score) {
        best_score = sc;
        coarse_icp = r;
      }
    }
    out.coarse_hypotheses = static_cast<int>(starts.size());
    out.coarse_icp_fitness = coarse_icp.fitness_;
    Mat4d t = coarse_icp.transformation_;
    out.seconds_coarse = t_coarse.Seconds();

    // Fine: robust point-to-plane ICP on every given point, Tukey's k from the residuals' robust
    // scale (a changed area does not inflate it): 6 sigmas, then 4.685 (95% efficiency).
    const Stopwatch t_fine;
    const open3d::geometry::KDTreeFlann tree_a(*ca);
    auto over_a = [&](const Mat4d& tt) { return OnSurface(cb, tt, in.a_has_surface); };
    auto cb_on = over_a(t);
    std::vector<double> res = PlaneResiduals(*cb_on, *ca, tree_a, t, dmax);
    double scale = std::max(RobustSigma(res), 0.05e-6);
    for (const double mult : {6.0, 4.685}) {
      auto kernel = std::make_shared<reg::TukeyLoss>(mult * scale);
      t = reg::RegistrationICP(*cb_on, *ca, dmax, t,
                               reg::TransformationEstimationPointToPlane(kernel),
                               reg::ICPConvergenceCriteria(1e-8, 1e-8, in.fine_iterations))
              .transformation_;
      cb_on = over_a(t);
      res = PlaneResiduals(*cb_on, *ca, tree_a, t, dmax);
      scale = std::max(RobustSigma(res), 0.05e-6);
    }
    out.b_on_a = static_cast<int64_t>(cb_on->points_.size());
    // Reweighting: B's points beyond 3 robust sigmas (a changed area) leave; the rest refit.
    auto cb_in = std::make_shared<PointCloud>();
    for (size_t k = 0; k < res.size(); ++k)
      if (std::isfinite(res[k]) && std::abs(res[k]) <= 3 * scale) {
        cb_in->points_.push_back(cb_on->points_[k]);
        cb_in->normals_.push_back(cb_on->normals_[k]);
      }
    out.b_inliers = static_cast<int64_t>(cb_in->points_.size());
    if (cb_in->points_.size() >= 6) {
      auto kernel = std::make_shared<reg::TukeyLoss>(4.685 * scale);
      t = reg::RegistrationICP(
              *cb_in, *ca, dmax, t, reg::TransformationEstimationPointToPlane(kernel),
              reg::ICPConvergenceCriteria(1e-8, 1e-8, std::max(50, in.fine_iterations)))
              .transformation_;
    }
    std::vector<int> nearest;
    res = PlaneResiduals(*cb_in, *ca, tree_a, t, dmax, &nearest);
    out.robust_sigma_m = RobustSigma(res);
    const Mat3d R = t.topLeftCorner<3, 3>();
    const Vec3d tr = t.topRightCorner<3, 1>();
    for (size_t k = 0; k < res.size(); ++k) {
      if (!std::isfinite(res[k]) || std::abs(res[k]) > 3 * scale) continue;
      const Vec3d p = R * cb_in->points_[k] + tr;
      const Vec3d& n = ca->normals_[nearest[k]];
      Eigen::Matrix<double, 6, 1> j;
      j << p.cross(n), n;
      out.jtj += j * j.transpose();
      out.sum_squares += res[k] * res[k];
      ++out.inliers;
    }
    out.b_to_a = t;
    out.seconds_fine = t_fine.Seconds();
    return out;
  }

  MeshRaster RasterMesh(const std::string& path, double pixel) const override {
    open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
    open3d::geometry::TriangleMesh mesh;
    if (!open3d::io::ReadTriangleMesh(path, mesh))
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "cannot be read as a triangle mesh");
    if (mesh.triangles_.empty() || mesh.vertices_.empty())
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "holds no triangles");
    std::string ext = std::filesystem::path(path).extension().string();
    for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    if (ext == ".glb" || ext == ".gltf")  // glTF's +Y up: (X, Y, Z) is the world (X, -Z, Y)
      for (Eigen::Vector3d& v : mesh.vertices_) v = Vec3d(v.x(), -v.z(), v.y());
    for (const Eigen::Vector3d& v : mesh.vertices_)
      if (!v.allFinite()) MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "has a non-finite vertex");
    const Eigen::Vector3d lo = mesh.GetMinBound(), hi = mesh.GetMaxBound();
    MeshRaster r;
    r.pixel_size = pixel;
    const double w = std::floor((hi.x() - lo.x()) / pixel) + 1,
                 h = std::floor((hi.y() - lo.y()) / pixel) + 1;
    if (w * h > 50e6)
      MESOSCAN_BAD_INPUT_AT(ErrorSite::File(path), "spans " << (hi.x() - lo.x()) << " x "
                                                            << (hi.y() - lo.y())
                                                            << " m: more than 50 M pixels of "
                                                            << pixel << " m (is it in metres?)");
    r.width = static_cast<int>(w);
    r.height = static_cast<int>(h);
    r.x0 = lo.x();
    r.y0 = hi.y();
    r.triangles = static_cast<int64_t>(mesh.triangles_.size());
    // Dense uniform samples of the surface (about 8 per pixel; Open3D's ray caster is not
    // usable in every build), averaged per pixel over its top layer: the samples within 2
    // pixels below the pixel's highest (a closed mesh's underside stays out).
    const double area = mesh.GetSurfaceArea();
    const size_t n = static_cast<size_t>(std::clamp(8 * area / (pixel * pixel), 1e4, 3e7));
    const auto cloud = mesh.SamplePointsUniformly(n);
    const size_t cells = static_cast<size_t>(r.width) * r.height;
    std::vector<float> top(cells, -std::numeric_limits<float>::infinity());
    std::vector<double> sum(cells, 0.0);
    std::vector<int> count(cells, 0);
    auto cell = [&](const Eigen::Vector3d& p) -> int64_t {
      const int i = static_cast<int>(std::lround((p.x() - r.x0) / pixel));
      const int j = static_cast<int>(std::lround((r.y0 - p.y()) / pixel));
      if (i < 0 || j < 0 || i >= r.width || j >= r.height) return -1;
      return static_cast<int64_t>(j) * r.width + i;
    };
    for (const Eigen::Vector3d& p : cloud->points_) {
      const int64_t k = cell(p);
      if (k >= 0) top[k] = std::max(top[k], static_cast<float>(p.z()));
    }
    for (const Eigen::Vector3d& p : cloud->points_) {
      const int64_t k = cell(p);
      if (k >= 0 && p.z() >= top[k] - 2 * pixel) {
        sum[k] += p.z();
        ++count[k];
      }
    }
    r.z.assign(cells, std::numeric_limits<float>::quiet_NaN());
    for (size_t k = 0; k < cells; ++k)
      if (count[k] > 0) r.z[k] = static_cast<float>(sum[k] / count[k]);
    return r;
  }
};

}  // namespace
}  // namespace mesoscan

extern "C" __attribute__((visibility("default"))) const void* mesoscan_module_open3d() {
  static const mesoscan::Module module;
  return static_cast<const mesoscan::RegistrationModule*>(&module);
}
