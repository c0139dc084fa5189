#include "calibration/calibrate_mount.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>

#include "core/error.h"
#include "core/log.h"
#include "core/numbers.h"
#include "core/robust_stats.h"
#include "core/stage_timer.h"
#include "heightfield/reconstruct.h"

namespace mesoscan {

bool HasBoardPatterns(const Session& session) {
  const FramePlan plan = MakeFramePlan(session.frames);
  bool axis[2] = {false, false};
  for (const auto& set : plan.sine) {
    int n = 0;
    for (size_t f : set.frames) n += session.frames[f].shift_steps == 0;
    if (n >= 3) axis[set.axis == 'x' ? 0 : 1] = true;
  }
  return axis[0] && axis[1];
}

FlatTargetScan ScanFlatTarget(const Session& session_in, const Rig& rig) {
  const Stopwatch timer;
  const std::string where = session_in.root.string() + "/session.json";
  if (session_in.rig.camera.width != rig.camera.width ||
      session_in.rig.camera.height != rig.camera.height ||
      session_in.rig.projector.width != rig.projector.width ||
      session_in.rig.projector.height != rig.projector.height)
    MESOSCAN_BAD_INPUT(where << ": rig: device sizes " << session_in.rig.camera.width << "x"
                             << session_in.rig.camera.height << " / "
                             << session_in.rig.projector.width << "x"
                             << session_in.rig.projector.height
                             << " differ from the calibrated rig's, expected the same rig");
  Session session = session_in;
  const std::optional<LensShifter> shifter = session.rig.lens_shifter;
  session.rig = rig;
  session.rig.uncalibrated = false;
  session.rig.lens_shifter = shifter;
  // The session's own radiometry (responses, black level) describes its frames.
  session.rig.camera_response = session_in.rig.camera_response;
  session.rig.projector_response = session_in.rig.projector_response;
  session.rig.black_level = session_in.rig.black_level;

  // The reconstruction's own pipeline, keeping every pixel's own lens-shift frequency (the
  // shifter's variation over the image) instead of the smoothed map.
  ReconstructOptions ro;
  ro.lens_shift.smooth_frequency = false;
  ro.keep_diagnostics = true;  // the lens-shift fits (their frequencies) are read below
  ReconstructSummary summary;
  StageTimer stage_timer(&summary.timings_s, &summary.cpu_s);
  ReconstructedPoints r = ReconstructPoints(session, ro, &stage_timer, &summary);
  const ReconstructPlan& plan = r.plan;
  const PixelStates& state = r.classes.state;
  const LensShiftPixels& ls = r.ls;
  TriangulatedPoints& tri = r.tri;
  FlatTargetScan out;
  out.grid = r.grid;
  out.xyz = std::move(tri.points.xyz);
  out.sigma_z.assign(out.xyz.pixels(), std::numeric_limits<float>::quiet_NaN());
  for (int y = 0; y < out.grid.height; ++y)
    for (int x = 0; x < out.grid.width; ++x) {
      const size_t i = static_cast<size_t>(y) * out.grid.width + x;
      if (state[i] == PixelState::kOk)
        out.sigma_z[static_cast<size_t>(y + out.grid.roi.y) * session.rig.camera.width + x +
                    out.grid.roi.x] = tri.sigma_z[i];
    }
  out.lens_shift_frames = static_cast<int>(plan.ls_stack.size());
  if (!ls.empty()) {
    // ROI grid -> camera grid (the ROI is the whole image here, but keep the mapping explicit).
    const int W = session.rig.camera.width;
    out.ls_frequency.assign(static_cast<size_t>(W) * session.rig.camera.height,
                            std::numeric_limits<float>::quiet_NaN());
    for (int y = 0; y < out.grid.height; ++y)
      for (int x = 0; x < out.grid.width; ++x) {
        const size_t i = static_cast<size_t>(y) * out.grid.width + x;
        if (state[i] != PixelState::kOk) continue;
        out.ls_frequency[static_cast<size_t>(y + out.grid.roi.y) * W + x + out.grid.roi.x] =
            ls.frequency[i];
      }
  }
  for (size_t i = 0; i < out.xyz.pixels(); ++i) out.points += std::isfinite(out.xyz.channel(2)[i]);
  out.seconds = timer.Seconds();
  return out;
}

Json MountPlane::ToJson() const {
  return {{"session", session},
          {"normal", {normal.x(), normal.y(), normal.z()}},
          {"offset_m", offset},
          {"points", points},
          {"inliers", inliers},
          {"rms_um", rms_m * 1e6},
          {"robust_sigma_um", robust_sigma_m * 1e6},
          {"normal_sigma_deg", normal_sigma_rad * 180.0 / kPi},
          {"offset_sigma_um", offset_sigma_m * 1e6},
          {"predicted_rms_um", predicted_rms_m * 1e6},
          {"rms_over_predicted", rms_over_predicted},
          {"seconds", seconds}};
}

MountPlane FitMountPlane(const FlatTargetScan& scan, const Rig& rig,
                         const MountPlaneOptions& options) {
  const Stopwatch timer;
  MountPlane plane;
  const ImageF& xyz = scan.xyz;
  std::vector<size_t> idx;
  for (size_t i = 0; i < xyz.pixels(); ++i)
    if (std::isfinite(xyz.channel(2)[i])) idx.push_back(i);
  plane.points = static_cast<int64_t>(idx.size());
  if (plane.points < options.min_points)
    MESOSCAN_BAD_INPUT("mount: " << plane.points << " points triangulated, expected at least "
                                 << options.min_points << " (is the mount lit and in focus?)");
  const size_t stride = std::max<size_t>(1, idx.size() / options.max_samples);
  std::vector<Vec3d> p;
  std::vector<float> sig;  // their predicted sigmas (NaN: none)
  const bool have_sigma = scan.sigma_z.size() == xyz.pixels();
  for (size_t k = 0; k < idx.size(); k += stride) {
    p.emplace_back(xyz.channel(0)[idx[k]], xyz.channel(1)[idx[k]], xyz.channel(2)[idx[k]]);
    sig.push_back(have_sigma ? scan.sigma_z[idx[k]] : std::numeric_limits<float>::quiet_NaN());
  }
  std::vector<uint8_t> use(p.size(), 1);
  Vec3d n = Vec3d::UnitZ(), c = Vec3d::Zero();
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  size_t m = 0;
  std::vector<double> dist(p.size());
  for (int round = 0; round < std::max(1, options.rounds); ++round) {
    c.setZero();
    m = 0;
    for (size_t k = 0; k < p.size(); ++k)
      if (use[k]) {
        c += p[k];
        ++m;
      }
    if (m < 3) MESOSCAN_BAD_INPUT("mount: too few points on a common plane");
    c /= static_cast<double>(m);
    scatter.setZero();
    for (size_t k = 0; k < p.size(); ++k)
      if (use[k]) scatter += (p[k] - c) * (p[k] - c).transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(scatter);
    n = es.eigenvectors().col(0);
    for (size_t k = 0; k < p.size(); ++k) dist[k] = std::abs(n.dot(p[k] - c));
    const double sigma = kMadToSigma * Median(dist);
    plane.robust_sigma_m = sigma;
    for (size_t k = 0; k < p.size(); ++k) use[k] = dist[k] <= options.reject_sigmas * sigma + 1e-12;
  }
  // Orientation: +z towards the rig (the camera's centre is above the plane).
  const Vec3d cam = rig.camera.CentreInWorld();
  if (n.dot(cam - c) < 0) n = -n;
  plane.normal = n;
  plane.offset = n.dot(c);
  double s2 = 0;
  int64_t inl = 0;
  for (size_t k = 0; k < p.size(); ++k)
    if (use[k]) {
      s2 += dist[k] * dist[k];
      ++inl;
    }
  plane.rms_m = inl ? std::sqrt(s2 / inl) : 0;
  double p2 = 0, r2 = 0;
  int64_t n_sig = 0;
  for (size_t k = 0; k < p.size(); ++k)
    if (use[k] && std::isfinite(sig[k]) && sig[k] > 0) {
      p2 += static_cast<double>(sig[k]) * sig[k];
      r2 += std::pow(dist[k] / sig[k], 2);
      ++n_sig;
    }
  if (n_sig > 0) {
    plane.predicted_rms_m = std::sqrt(p2 / n_sig);
    plane.rms_over_predicted = std::sqrt(r2 / n_sig);
  }
  plane.inliers = inl * static_cast<int64_t>(stride);
  if (inl < 3 || static_cast<double>(inl) < 0.5 * static_cast<double>(p.size()))
    MESOSCAN_BAD_INPUT("mount: only "
                       << inl << " of " << p.size()
                       << " points lie on one plane; expected the empty, flat mount");
  // Least-squares covariance (per-point sigma = the RMS; the subsample's points are
  // independent): offset at the centroid sigma/sqrt(m); tilt sigma / sqrt(second moment).
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(scatter);
  const double lmid = std::max(es.eigenvalues()(1), 1e-30);
  plane.offset_sigma_m = plane.rms_m / std::sqrt(static_cast<double>(inl));
  plane.normal_sigma_rad = plane.rms_m / std::sqrt(lmid);
  plane.session = "";
  plane.seconds = timer.Seconds();
  return plane;
}

std::string MountFlatnessWarning(const MountPlane& plane, double factor) {
  if (!(plane.rms_over_predicted > factor)) return "";
  std::ostringstream o;
  o << std::setprecision(3) << "mount plane: the empty mount's points lie " << plane.rms_m * 1e6
    << " um RMS from a plane, " << plane.rms_over_predicted << "x the noise predicted for them ("
    << plane.predicted_rms_m * 1e6
    << " um): the rig bends a flat surface; see the held-out views and the coverage";
  return o.str();
}

Rigid3d MountWorldFromCamera(const MountPlane& plane, const Rig& rig) {
  // Everything in the old world, then expressed relative to the camera.
  const Rigid3d& old_from_cam = rig.camera.world_from_device;
  const Vec3d z = plane.normal.normalized();
  const Vec3d cam_x = old_from_cam.rotation.col(0), axis = old_from_cam.rotation.col(2);
  Vec3d x = cam_x - z * z.dot(cam_x);
  if (x.norm() < 1e-9) x = Vec3d::UnitX() - z * z.x();  // a camera looking along the plane
  x.normalize();
  const Vec3d y = z.cross(x);
  const Vec3d o_cam = old_from_cam.translation;
  const double denom = z.dot(axis);
  Vec3d origin;
  if (std::abs(denom) > 1e-6) {
    origin = o_cam + axis * ((plane.offset - z.dot(o_cam)) / denom);
  } else {
    origin = o_cam - z * (z.dot(o_cam) - plane.offset);  // the foot of the camera centre
  }
  Rigid3d old_from_new;
  old_from_new.rotation.col(0) = x;
  old_from_new.rotation.col(1) = y;
  old_from_new.rotation.col(2) = z;
  old_from_new.translation = origin;
  return old_from_new.Inverse() * old_from_cam;
}

Rig RigOnMount(const Rig& rig, const MountPlane& plane) {
  const Rigid3d new_from_cam = MountWorldFromCamera(plane, rig);
  const Rigid3d new_from_old = new_from_cam * rig.camera.world_from_device.Inverse();
  Rig out = rig;
  out.camera.world_from_device = new_from_cam;
  out.projector.world_from_device = new_from_old * rig.projector.world_from_device;
  return out;
}

}  // namespace mesoscan
