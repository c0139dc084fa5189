#include "calibration/calibrate_bundle.h"

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <sstream>

#include "calibration/calibrate.h"
#include "core/error.h"
#include "core/parallel.h"
#include "heightfield/triangulate.h"

namespace mesoscan {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// {fx, fy, cx, cy} with fy = fx when the model says so (fy's own slot is then held).
template <typename T>
void Intrinsics(const T* intr, bool equal_focal, T* out) {
  out[0] = intr[0];
  out[1] = equal_focal ? intr[0] : intr[1];
  out[2] = intr[2];
  out[3] = intr[3];
}

// Reprojection residual of one board corner in the camera, or in the projector through
// prj_from_cam. Parameters: intrinsics {fx, fy, cx, cy}, distortion[5], cam_from_board
// (angle-axis, t), and for the projector prj_from_cam (angle-axis, t).
struct CornerResidual {
  CornerResidual(const Vec3d& x, const Vec2d& obs, bool equal_focal)
      : x_(x), obs_(obs), equal_focal_(equal_focal) {}
  template <typename T>
  void BoardToCamera(const T* board_pose, T* p) const {
    const T xb[3] = {T(x_.x()), T(x_.y()), T(x_.z())};
    ceres::AngleAxisRotatePoint(board_pose, xb, p);
    for (int i = 0; i < 3; ++i) p[i] += board_pose[3 + i];
  }
  template <typename T>
  bool Finish(const T* intr, const T* dist, const T* p, T* res) const {
    T k[4], uv[2];
    Intrinsics(intr, equal_focal_, k);
    if (!PinholeCamera::ProjectWithParams(k, dist, p, uv)) return false;
    res[0] = uv[0] - T(obs_.x());
    res[1] = uv[1] - T(obs_.y());
    return true;
  }
  Vec3d x_;
  Vec2d obs_;
  bool equal_focal_;
};

struct CameraCost : CornerResidual {
  using CornerResidual::CornerResidual;
  template <typename T>
  bool operator()(const T* intr, const T* dist, const T* pose, T* res) const {
    T p[3];
    BoardToCamera(pose, p);
    return Finish(intr, dist, p, res);
  }
};

struct ProjectorCost : CornerResidual {
  using CornerResidual::CornerResidual;
  template <typename T>
  bool operator()(const T* intr, const T* dist, const T* pose, const T* prj, T* res) const {
    T p[3], q[3];
    BoardToCamera(pose, p);
    ceres::AngleAxisRotatePoint(prj, p, q);
    for (int i = 0; i < 3; ++i) q[i] += prj[3 + i];
    return Finish(intr, dist, q, res);
  }
};

std::vector<int> HeldIntrinsics(const DeviceModel& m) {
  std::vector<int> held;
  if (m.equal_focal) held.push_back(1);
  if (!m.free_principal_point) held.insert(held.end(), {2, 3});
  return held;
}

std::vector<int> HeldDistortion(const DeviceModel& m) {
  std::vector<int> held;
  if (!(m.terms & DeviceModel::kK1)) held.push_back(0);
  if (!(m.terms & DeviceModel::kK2)) held.push_back(1);
  if (!(m.terms & DeviceModel::kTangential)) held.insert(held.end(), {2, 3});
  if (!(m.terms & DeviceModel::kK3)) held.push_back(4);
  return held;
}

void Hold(ceres::Problem* problem, double* block, int size, const std::vector<int>& held) {
  if (held.empty()) return;
  if (static_cast<int>(held.size()) == size)
    problem->SetParameterBlockConstant(block);
  else
    problem->SetManifold(block, new ceres::SubsetManifold(size, held));
}

// Adds every corner residual of views (but `skip`) to `problem`; returns per residual block
// whether it is the projector's.
std::vector<uint8_t> AddResiduals(const std::vector<const CalibrationView*>& views, int skip,
                                  const CalibrationBoard& board, bool cam_equal, bool prj_equal,
                                  BundleParams* p, ceres::Problem* problem) {
  std::vector<uint8_t> is_projector;
  for (size_t i = 0; i < views.size(); ++i) {
    if (static_cast<int>(i) == skip) continue;
    const CalibrationView& v = *views[i];
    for (int k = 0; k < board.num_corners(); ++k) {
      if (!v.camera_px[k].allFinite()) continue;
      const Vec3d x = board.Corner(k);
      problem->AddResidualBlock(new ceres::AutoDiffCostFunction<CameraCost, 2, 4, 5, 6>(
                                    new CameraCost(x, v.camera_px[k], cam_equal)),
                                nullptr, p->cam.intr.data(), p->cam.dist.data(),
                                p->cam_from_board[i].data());
      is_projector.push_back(0);
      if (!v.projector_px[k].allFinite()) continue;
      problem->AddResidualBlock(new ceres::AutoDiffCostFunction<ProjectorCost, 2, 4, 5, 6, 6>(
                                    new ProjectorCost(x, v.projector_px[k], prj_equal)),
                                nullptr, p->prj.intr.data(), p->prj.dist.data(),
                                p->cam_from_board[i].data(), p->prj_from_cam.data());
      is_projector.push_back(1);
    }
  }
  return is_projector;
}

double Rms(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x * x;
  return v.empty() ? 0.0 : std::sqrt(s / v.size());
}

}  // namespace

Rigid3d PoseFromArray(const double* a) {
  Rigid3d t;
  double r[9];
  ceres::AngleAxisToRotationMatrix(a, r);  // column-major
  for (int c = 0; c < 3; ++c)
    for (int rr = 0; rr < 3; ++rr) t.rotation(rr, c) = r[c * 3 + rr];
  t.translation = Vec3d(a[3], a[4], a[5]);
  return t;
}

int DeviceModel::FreeParameters() const {
  int n = equal_focal ? 1 : 2;
  if (free_principal_point) n += 2;
  n += !!(terms & kK1) + !!(terms & kK2) + 2 * !!(terms & kTangential) + !!(terms & kK3);
  return n;
}

std::string DeviceModel::TermsString() const {
  std::string s;
  auto add = [&](const char* t) {
    if (!s.empty()) s += ' ';
    s += t;
  };
  if (terms & kK1) add("k1");
  if (terms & kK2) add("k2");
  if (terms & kTangential) add("p1 p2");
  if (terms & kK3) add("k3");
  return s.empty() ? "none" : s;
}

std::string DeviceModel::ToString() const {
  std::string s = "distortion " + TermsString();
  s += free_principal_point ? ", principal point free" : ", principal point at the centre";
  s += equal_focal ? ", fx = fy" : ", fx and fy";
  return s;
}

Json DeviceModel::ToJson() const {
  return {{"distortion", TermsString()},
          {"principal_point", free_principal_point ? "free" : "centre"},
          {"equal_focal", equal_focal},
          {"free_parameters", FreeParameters()}};
}

void DeviceParams::Apply(const DeviceModel& model) {
  for (int i : HeldDistortion(model)) dist[i] = 0.0;
  if (!model.free_principal_point) {
    intr[2] = 0.5 * (width - 1);
    intr[3] = 0.5 * (height - 1);
  }
  if (model.equal_focal) {
    const double f = 0.5 * (intr[0] + intr[1]);
    intr[0] = intr[1] = f;
  }
}

PinholeCamera DeviceParams::Camera() const {
  PinholeCamera c;
  c.width = width;
  c.height = height;
  c.K << intr[0], 0, intr[2], 0, intr[1], intr[3], 0, 0, 1;
  for (int i = 0; i < 5; ++i) c.distortion[i] = dist[i];
  return c;
}

Rigid3d BundleParams::PrjFromCam() const { return PoseFromArray(prj_from_cam.data()); }

PinholeCamera BundleParams::CameraInCameraFrame() const { return cam.Camera(); }

PinholeCamera BundleParams::ProjectorInCameraFrame() const {
  PinholeCamera c = prj.Camera();
  c.world_from_device = PrjFromCam().Inverse();
  return c;
}

BundleSolveSummary SolveBundle(const std::vector<const CalibrationView*>& views, int skip,
                               const CalibrationBoard& board, const DeviceModel& cam_model,
                               const DeviceModel& prj_model, const BundleSolveOptions& options,
                               BundleParams* p) {
  MESOSCAN_CHECK_EQ(p->cam_from_board.size(), views.size());
  p->cam.Apply(cam_model);
  p->prj.Apply(prj_model);
  ceres::Problem problem;
  const std::vector<uint8_t> blocks =
      AddResiduals(views, skip, board, cam_model.equal_focal, prj_model.equal_focal, p, &problem);
  BundleSolveSummary out;
  out.residuals = 2 * static_cast<int>(blocks.size());
  if (blocks.empty()) return out;
  Hold(&problem, p->cam.intr.data(), 4, HeldIntrinsics(cam_model));
  Hold(&problem, p->cam.dist.data(), 5, HeldDistortion(cam_model));
  Hold(&problem, p->prj.intr.data(), 4, HeldIntrinsics(prj_model));
  Hold(&problem, p->prj.dist.data(), 5, HeldDistortion(prj_model));
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_SCHUR;
  so.max_num_iterations = options.max_iterations;
  so.function_tolerance = options.tolerance;
  so.gradient_tolerance = options.tolerance;
  so.parameter_tolerance = options.tolerance;
  so.num_threads = options.threads;
  so.initial_trust_region_radius = options.initial_trust_region;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  if (cam_model.equal_focal) p->cam.intr[1] = p->cam.intr[0];
  if (prj_model.equal_focal) p->prj.intr[1] = p->prj.intr[0];
  out.usable = summary.IsSolutionUsable();
  out.cost = summary.final_cost;
  const int used_views = static_cast<int>(views.size()) - (skip >= 0 ? 1 : 0);
  out.parameters = cam_model.FreeParameters() + prj_model.FreeParameters() + 6 + 6 * used_views;
  out.brief = summary.BriefReport();
  return out;
}

Json BundleCovariance(const std::vector<const CalibrationView*>& views,
                      const CalibrationBoard& board, const DeviceModel& cam_model,
                      const DeviceModel& prj_model, const BundleParams& p_in) {
  // Every parameter free in the problem (no manifolds: the Jacobian's columns are the ambient
  // coordinates); the model's held parameters are then dropped and fy merged into fx.
  BundleParams p = p_in;
  ceres::Problem problem;
  const std::vector<uint8_t> is_projector =
      AddResiduals(views, -1, board, false, false, &p, &problem);
  std::vector<double*> blocks = {p.cam.intr.data(), p.cam.dist.data(), p.prj.intr.data(),
                                 p.prj.dist.data(), p.prj_from_cam.data()};
  for (auto& b : p.cam_from_board) blocks.push_back(b.data());
  // A view whose board pose has no residual (none) is not in the problem.
  std::vector<double*> present;
  for (double* b : blocks)
    if (problem.HasParameterBlock(b)) present.push_back(b);
  if (present.size() < 5) return Json();
  ceres::Problem::EvaluateOptions eo;
  eo.parameter_blocks = present;
  std::vector<double> res;
  ceres::CRSMatrix crs;
  double cost = 0;
  if (!problem.Evaluate(eo, &cost, &res, nullptr, &crs)) return Json();
  const int rows = crs.num_rows, cols = crs.num_cols;
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(rows, cols);
  for (int r = 0; r < rows; ++r)
    for (int n = crs.rows[r]; n < crs.rows[r + 1]; ++n) J(r, crs.cols[n]) = crs.values[n];
  // The free parameters as combinations of the ambient columns: (column, name); fy's column is
  // added to fx's when fx = fy.
  struct Free {
    std::vector<int> cols;
    std::string device, name;
  };
  std::vector<Free> free;
  const std::vector<std::string> in = {"fx", "fy", "cx", "cy"};
  const std::vector<std::string> dn = {"k1", "k2", "p1", "p2", "k3"};
  for (int d = 0; d < 2; ++d) {
    const DeviceModel& m = d ? prj_model : cam_model;
    const int base = d ? 9 : 0;
    const std::string dev = d ? "projector" : "camera";
    if (m.equal_focal)
      free.push_back({{base + 0, base + 1}, dev, "f"});
    else
      free.insert(free.end(), {{{base + 0}, dev, "fx"}, {{base + 1}, dev, "fy"}});
    if (m.free_principal_point)
      free.insert(free.end(), {{{base + 2}, dev, "cx"}, {{base + 3}, dev, "cy"}});
    const std::vector<int> held = HeldDistortion(m);
    for (int i = 0; i < 5; ++i)
      if (std::find(held.begin(), held.end(), i) == held.end())
        free.push_back({{base + 4 + i}, dev, dn[i]});
  }
  const std::vector<std::string> pn = {"rx_rad", "ry_rad", "rz_rad", "tx_m", "ty_m", "tz_m"};
  for (int i = 0; i < 6; ++i) free.push_back({{18 + i}, "prj_from_cam", pn[i]});
  const int n_named = static_cast<int>(free.size());
  for (int c = 24; c < cols; ++c) free.push_back({{c}, "", ""});  // board poses
  const int n = static_cast<int>(free.size());
  // Rows whitened by each device's noise: its residual variance with the degrees of freedom
  // shared in proportion (sigma^2 = SSR_device / (n_device (1 - p / n_rows))).
  double ss[2] = {0, 0};
  int cnt[2] = {0, 0};
  for (size_t b = 0; b < is_projector.size(); ++b)
    for (int k = 0; k < 2; ++k) {
      ss[is_projector[b]] += res[2 * b + k] * res[2 * b + k];
      ++cnt[is_projector[b]];
    }
  const double dof_factor = std::max(0.1, 1.0 - static_cast<double>(n) / rows);
  double sigma[2];
  for (int d = 0; d < 2; ++d) sigma[d] = cnt[d] ? std::sqrt(ss[d] / (cnt[d] * dof_factor)) : 1.0;
  Eigen::MatrixXd Jf(rows, n);
  for (int c = 0; c < n; ++c) {
    Eigen::VectorXd col = Eigen::VectorXd::Zero(rows);
    for (int a : free[c].cols) col += J.col(a);
    Jf.col(c) = col;
  }
  for (size_t b = 0; b < is_projector.size(); ++b)
    Jf.middleRows(2 * b, 2) /= sigma[is_projector[b]];
  // Column scaling (Jacobi): the Hessian's spectrum spans many decades in raw units (metres,
  // radians, pixels, r^6 coefficients); scaled, only true degeneracies remain small.
  Eigen::VectorXd scale(n);
  for (int c = 0; c < n; ++c) {
    const double norm = Jf.col(c).norm();
    scale[c] = norm > 0 ? 1.0 / norm : 0.0;
  }
  const Eigen::MatrixXd Js = Jf * scale.asDiagonal();
  const Eigen::MatrixXd H = Js.transpose() * Js;
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(H);
  const Eigen::VectorXd lambda = es.eigenvalues();
  Json out;
  if (!(lambda.minCoeff() > 1e-12 * lambda.maxCoeff()) || scale.minCoeff() <= 0) {
    out["error"] = "the covariance could not be computed (rank-deficient problem)";
    return out;
  }
  const Eigen::MatrixXd cov_s =
      es.eigenvectors() * lambda.cwiseInverse().asDiagonal() * es.eigenvectors().transpose();
  for (int c = 0; c < n_named; ++c) {
    const double sd = std::sqrt(std::max(0.0, cov_s(c, c))) * scale[c];
    const Free& f = free[c];
    const bool is_dist = std::find(dn.begin(), dn.end(), f.name) != dn.end();
    if (f.name == "f") {
      out[f.device]["fx"] = sd;
      out[f.device]["fy"] = sd;
    } else if (is_dist) {
      out[f.device]["distortion"][f.name] = sd;
    } else {
      out[f.device][f.name] = sd;
    }
  }
  out["residual_sigma_px"] = {{"camera", sigma[0]}, {"projector", sigma[1]}};
  out["condition"] = lambda.maxCoeff() / lambda.minCoeff();
  return out;
}

Json HeldOutView::ToJson() const {
  return {{"session", name},
          {"rms_camera_px", rms_camera_px},
          {"rms_projector_px", rms_projector_px},
          {"camera_corners", camera_corners},
          {"projector_corners", projector_corners},
          {"chi2", chi2},
          {"triangulated", triangulated},
          {"adjacent_distance_rms_um", adjacent_rms_um},
          {"adjacent_distance_mean_um", adjacent_mean_um},
          {"flatness_rms_um", flatness_rms_um},
          {"scale_error_pct", scale_error_pct},
          {"shape_rms_um", shape_rms_um}};
}

HeldOutView EvaluateHeldOut(const CalibrationView& v, const CalibrationBoard& board,
                            const BundleParams& p_in, double sigma_camera_px,
                            double sigma_projector_px) {
  HeldOutView h;
  h.name = v.name;
  const int nc = board.num_corners();
  BundleParams p = p_in;
  // 1. The board pose: solvePnP on the camera corners, refined with both devices (rig held).
  std::array<double, 6> pose{};
  {
    std::vector<cv::Point3d> obj;
    std::vector<cv::Point2d> img;
    for (int k = 0; k < nc; ++k)
      if (v.camera_px[k].allFinite()) {
        const Vec3d x = board.Corner(k);
        obj.emplace_back(x.x(), x.y(), x.z());
        img.emplace_back(v.camera_px[k].x(), v.camera_px[k].y());
      }
    if (obj.size() < 4) return h;
    const cv::Mat K = (cv::Mat_<double>(3, 3) << p.cam.intr[0], 0, p.cam.intr[2], 0, p.cam.intr[1],
                       p.cam.intr[3], 0, 0, 1);
    const cv::Mat d(1, 5, CV_64F, p.cam.dist.data());
    cv::Mat rvec, tvec;
    try {
      if (!cv::solvePnP(obj, img, K, d, rvec, tvec)) return h;
    } catch (const cv::Exception&) {
      return h;
    }
    for (int i = 0; i < 3; ++i) {
      pose[i] = rvec.at<double>(i);
      pose[3 + i] = tvec.at<double>(i);
    }
  }
  p.cam_from_board.assign(1, pose);
  {
    ceres::Problem problem;
    const std::vector<const CalibrationView*> one = {&v};
    AddResiduals(one, -1, board, false, false, &p, &problem);
    for (double* b : {p.cam.intr.data(), p.cam.dist.data(), p.prj.intr.data(), p.prj.dist.data(),
                      p.prj_from_cam.data()})
      if (problem.HasParameterBlock(b)) problem.SetParameterBlockConstant(b);
    ceres::Solver::Options so;
    so.linear_solver_type = ceres::DENSE_QR;
    so.max_num_iterations = 50;
    so.num_threads = 1;
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
  }
  // 2. Reprojection.
  const PinholeCamera cam = p.CameraInCameraFrame(), prj = p.prj.Camera();
  const Rigid3d cam_from_board = PoseFromArray(p.cam_from_board[0].data());
  const Rigid3d prj_from_cam = p.PrjFromCam();
  double sc = 0, sp = 0;
  for (int k = 0; k < nc; ++k) {
    const Vec3d pc = cam_from_board * board.Corner(k);
    Vec2d uv;
    if (v.camera_px[k].allFinite() && cam.ProjectDevice(pc.data(), uv.data())) {
      sc += (v.camera_px[k] - uv).squaredNorm();
      ++h.camera_corners;
    }
    const Vec3d pp = prj_from_cam * pc;
    if (v.projector_px[k].allFinite() && prj.ProjectDevice(pp.data(), uv.data())) {
      sp += (v.projector_px[k] - uv).squaredNorm();
      ++h.projector_corners;
    }
  }
  h.rms_camera_px = h.camera_corners ? std::sqrt(sc / h.camera_corners) : 0;
  h.rms_projector_px = h.projector_corners ? std::sqrt(sp / h.projector_corners) : 0;
  h.chi2 =
      sc / (sigma_camera_px * sigma_camera_px) + sp / (sigma_projector_px * sigma_projector_px);
  // 3. The board triangulated as a scan would.
  const Triangulator tri(cam, p.ProjectorInCameraFrame(), 'x');
  std::vector<Vec3d> X(nc, Vec3d(kNaN, kNaN, kNaN));
  std::vector<Vec3d> src, dst;
  for (int k = 0; k < nc; ++k) {
    if (!v.camera_px[k].allFinite() || !v.projector_px[k].allFinite()) continue;
    const auto x = tri.Triangulate(v.camera_px[k].x(), v.camera_px[k].y(), v.projector_px[k].x());
    if (!x) continue;
    X[k] = *x;
    src.push_back(board.Corner(k));
    dst.push_back(*x);
  }
  h.triangulated = static_cast<int>(dst.size());
  if (h.triangulated < 4) return h;
  std::vector<double> adj;
  for (int j = 0; j < board.rows; ++j)
    for (int i = 0; i < board.cols; ++i) {
      const int k = j * board.cols + i;
      if (!X[k].allFinite()) continue;
      if (i + 1 < board.cols && X[k + 1].allFinite())
        adj.push_back((X[k + 1] - X[k]).norm() - board.square_m);
      if (j + 1 < board.rows && X[k + board.cols].allFinite())
        adj.push_back((X[k + board.cols] - X[k]).norm() - board.square_m);
    }
  h.adjacent_rms_um = Rms(adj) * 1e6;
  double mean = 0;
  for (double a : adj) mean += a;
  h.adjacent_mean_um = adj.empty() ? 0.0 : mean / adj.size() * 1e6;
  Eigen::Matrix3Xd S(3, src.size()), D(3, dst.size());
  for (size_t i = 0; i < src.size(); ++i) {
    S.col(i) = src[i];
    D.col(i) = dst[i];
  }
  const Vec3d c = D.rowwise().mean();
  const Eigen::Matrix3Xd Dc = D.colwise() - c;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(Dc * Dc.transpose());
  const Vec3d normal = es.eigenvectors().col(0);
  h.flatness_rms_um = std::sqrt((normal.transpose() * Dc).squaredNorm() / src.size()) * 1e6;
  const Eigen::Matrix4d T = Eigen::umeyama(S, D, true);
  const double s = T.block<3, 1>(0, 0).norm();
  h.scale_error_pct = (s - 1.0) * 100.0;
  const Eigen::Matrix3Xd fit = (T.topLeftCorner<3, 3>() * S).colwise() + T.block<3, 1>(0, 3);
  h.shape_rms_um = std::sqrt((fit - D).squaredNorm() / src.size()) * 1e6;
  return h;
}

double CrossValidation::Chi2PerResidual() const {
  int n = 0;
  for (const auto& h : held_out) n += 2 * (h.camera_corners + h.projector_corners);
  return n ? chi2 / n : 0.0;
}

CrossValidation CrossValidate(const std::vector<const CalibrationView*>& views,
                              const CalibrationBoard& board, const DeviceModel& cam_model,
                              const DeviceModel& prj_model, const BundleParams& start,
                              double sigma_camera_px, double sigma_projector_px) {
  CrossValidation cv;
  cv.cam = cam_model;
  cv.prj = prj_model;
  cv.all = start;
  BundleSolveOptions all_options;
  all_options.threads = 2;
  all_options.initial_trust_region = 1e12;
  cv.all_summary = SolveBundle(views, -1, board, cam_model, prj_model, all_options, &cv.all);
  const int n = static_cast<int>(views.size());
  cv.folds.assign(n, cv.all);
  cv.held_out.resize(n);
  ParallelFor(n, [&](int64_t i) {
    // From the all-view solution a few iterations suffice: the held-out figures do not move at
    // the 1e-9 relative change in cost where this stops.
    BundleSolveOptions o;
    o.tolerance = 1e-9;
    o.max_iterations = 50;
    o.initial_trust_region = 1e12;
    SolveBundle(views, static_cast<int>(i), board, cam_model, prj_model, o, &cv.folds[i]);
    cv.held_out[i] =
        EvaluateHeldOut(*views[i], board, cv.folds[i], sigma_camera_px, sigma_projector_px);
  });
  for (const auto& h : cv.held_out) cv.chi2 += h.chi2;
  return cv;
}

BundleParams OpenCvCalibration(const std::vector<const CalibrationView*>& views, int skip,
                               const CalibrationBoard& board, int camera_width, int camera_height,
                               int projector_width, int projector_height, int cv_flags,
                               double* rms_camera, double* rms_projector, double* rms_stereo) {
  const int nc = board.num_corners();
  std::vector<std::vector<cv::Point3f>> obj_cam, obj_both;
  std::vector<std::vector<cv::Point2f>> img_cam, img_cam_both, img_prj;
  std::vector<int> index;  // view of each entry
  for (size_t i = 0; i < views.size(); ++i) {
    if (static_cast<int>(i) == skip) continue;
    const CalibrationView* v = views[i];
    std::vector<cv::Point3f> oc, ob;
    std::vector<cv::Point2f> ic, icb, ip;
    for (int k = 0; k < nc; ++k) {
      if (!v->camera_px[k].allFinite()) continue;
      const Vec3d x = board.Corner(k);
      const cv::Point3f xp(static_cast<float>(x.x()), static_cast<float>(x.y()), 0.f);
      oc.push_back(xp);
      ic.emplace_back(static_cast<float>(v->camera_px[k].x()),
                      static_cast<float>(v->camera_px[k].y()));
      if (v->projector_px[k].allFinite()) {
        ob.push_back(xp);
        icb.push_back(ic.back());
        ip.emplace_back(static_cast<float>(v->projector_px[k].x()),
                        static_cast<float>(v->projector_px[k].y()));
      }
    }
    obj_cam.push_back(oc);
    img_cam.push_back(ic);
    obj_both.push_back(ob);
    img_cam_both.push_back(icb);
    img_prj.push_back(ip);
    index.push_back(static_cast<int>(i));
  }
  const cv::Size cam_size(camera_width, camera_height), prj_size(projector_width, projector_height);
  cv::Mat kc, dc, kp, dp, r_pc, t_pc, e, f;
  std::vector<cv::Mat> rv_c, tv_c, rv_p, tv_p;
  double a = 0, b = 0, c = 0;
  try {
    a = cv::calibrateCamera(obj_cam, img_cam, cam_size, kc, dc, rv_c, tv_c, cv_flags);
    b = cv::calibrateCamera(obj_both, img_prj, prj_size, kp, dp, rv_p, tv_p, cv_flags);
    c = cv::stereoCalibrate(obj_both, img_cam_both, img_prj, kc, dc, kp, dp, cam_size, r_pc, t_pc,
                            e, f, cv::CALIB_FIX_INTRINSIC);
  } catch (const cv::Exception& ex) {
    MESOSCAN_BAD_INPUT("calibrate: OpenCV's calibration failed on these "
                       << obj_cam.size() << " views (" << ex.err
                       << "); are the views at different tilts?");
  }
  if (!std::isfinite(a) || !std::isfinite(b) || !std::isfinite(c))
    MESOSCAN_BAD_INPUT("calibrate: OpenCV's calibration did not converge (degenerate views?)");
  if (rms_camera) *rms_camera = a;
  if (rms_projector) *rms_projector = b;
  if (rms_stereo) *rms_stereo = c;
  BundleParams p;
  p.cam.width = camera_width;
  p.cam.height = camera_height;
  p.prj.width = projector_width;
  p.prj.height = projector_height;
  auto fill = [](const cv::Mat& k, const cv::Mat& d, DeviceParams* dp) {
    dp->intr = {k.at<double>(0, 0), k.at<double>(1, 1), k.at<double>(0, 2), k.at<double>(1, 2)};
    dp->dist.fill(0.0);
    for (int i = 0; i < 5 && i < static_cast<int>(d.total()); ++i) dp->dist[i] = d.at<double>(i);
  };
  fill(kc, dc, &p.cam);
  fill(kp, dp, &p.prj);
  cv::Mat rvec;
  cv::Rodrigues(r_pc, rvec);
  for (int i = 0; i < 3; ++i) {
    p.prj_from_cam[i] = rvec.at<double>(i);
    p.prj_from_cam[3 + i] = t_pc.at<double>(i);
  }
  p.cam_from_board.assign(views.size(), {});
  for (size_t n = 0; n < index.size(); ++n)
    for (int i = 0; i < 3; ++i) {
      p.cam_from_board[index[n]][i] = rv_c[n].at<double>(i);
      p.cam_from_board[index[n]][3 + i] = tv_c[n].at<double>(i);
    }
  return p;
}

std::vector<HeldOutView> OpenCvCrossValidate(const std::vector<const CalibrationView*>& views,
                                             const CalibrationBoard& board, int camera_width,
                                             int camera_height, int projector_width,
                                             int projector_height, int cv_flags,
                                             double sigma_camera_px, double sigma_projector_px,
                                             std::vector<BundleParams>* folds) {
  const int n = static_cast<int>(views.size());
  std::vector<HeldOutView> out(n);
  std::vector<BundleParams> params(n);
  ParallelFor(n, [&](int64_t i) {
    params[i] = OpenCvCalibration(views, static_cast<int>(i), board, camera_width, camera_height,
                                  projector_width, projector_height, cv_flags);
    out[i] = EvaluateHeldOut(*views[i], board, params[i], sigma_camera_px, sigma_projector_px);
  });
  if (folds) *folds = std::move(params);
  return out;
}

Json HeldOutSummary::ToJson() const {
  return {{"views", views},
          {"rms_camera_px", rms_camera_px},
          {"rms_projector_px", rms_projector_px},
          {"adjacent_distance_rms_um", adjacent_rms_um},
          {"flatness_rms_um", flatness_rms_um},
          {"max_abs_scale_error_pct", max_abs_scale_error_pct},
          {"mean_abs_scale_error_pct", mean_abs_scale_error_pct}};
}

HeldOutSummary SummariseHeldOut(const std::vector<HeldOutView>& views) {
  HeldOutSummary s;
  double c = 0, p = 0, a = 0, fl = 0;
  for (const auto& h : views) {
    if (h.triangulated < 4) continue;
    ++s.views;
    c += h.rms_camera_px * h.rms_camera_px;
    p += h.rms_projector_px * h.rms_projector_px;
    a += h.adjacent_rms_um * h.adjacent_rms_um;
    fl += h.flatness_rms_um * h.flatness_rms_um;
    s.max_abs_scale_error_pct = std::max(s.max_abs_scale_error_pct, std::abs(h.scale_error_pct));
    s.mean_abs_scale_error_pct += std::abs(h.scale_error_pct);
  }
  if (s.views) {
    s.rms_camera_px = std::sqrt(c / s.views);
    s.rms_projector_px = std::sqrt(p / s.views);
    s.adjacent_rms_um = std::sqrt(a / s.views);
    s.flatness_rms_um = std::sqrt(fl / s.views);
    s.mean_abs_scale_error_pct /= s.views;
  }
  return s;
}

}  // namespace mesoscan
