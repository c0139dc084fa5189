// The mount plane and the lens-shifter fit (calibration/calibrate_mount.h,
// calibration/calibrate_shifter.h) on synthetic flat-target scans with known truth: points on a
// plane with noise and outliers, lens-shift frequencies from a known shifter.

#include "calibration/calibrate_mount.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "calibration/calibrate_shifter.h"
#include "core/error.h"

namespace mesoscan {
namespace {

constexpr int kW = 320, kH = 240;

// A camera above a world whose z = 0 is NOT the target (the world of a tilted first board).
Rig TestRig() {
  Rig rig;
  rig.camera.width = kW;
  rig.camera.height = kH;
  rig.camera.K << 700, 0, 159.5, 0, 700, 119.5, 0, 0, 1;
  const Rigid3d look = Rigid3d::LookAt(Vec3d(0.01, -0.02, 0.25), Vec3d(0, 0, 0), Vec3d(0, 1, 0));
  // The world of the scan: tilted 20 deg about x and shifted, relative to the mount's.
  Rigid3d tilt;
  tilt.rotation = Eigen::AngleAxisd(20.0 * std::numbers::pi / 180, Vec3d::UnitX()).matrix();
  tilt.translation = Vec3d(0.003, -0.004, 0.005);
  rig.camera.world_from_device = tilt * look;
  rig.projector.width = 400;
  rig.projector.height = 300;
  rig.projector.K << 800, 0, 199.5, 0, 800, 149.5, 0, 0, 1;
  rig.projector.world_from_device =
      tilt * Rigid3d::LookAt(Vec3d(0.09, 0, 0.24), Vec3d(0, 0, 0), Vec3d(0, 1, 0));
  rig.lens_shifter = LensShifter{'x', 2048, {-2048, 2048}};
  return rig;
}

// The mount (z = 0 in the mount's world) seen through `rig` whose world is tilted: points in the
// rig's world with normal noise `sigma` and a fraction of gross outliers.
FlatTargetScan MountScan(const Rig& rig, const Rigid3d& rig_from_mount, double sigma,
                         double outliers, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0, sigma);
  std::uniform_real_distribution<double> uni(0, 1);
  FlatTargetScan s;
  s.grid.width = kW;
  s.grid.height = kH;
  s.xyz = ImageF(kW, kH, 3, std::numeric_limits<float>::quiet_NaN());
  const Vec3d n = rig_from_mount.rotation.col(2), p0 = rig_from_mount.translation;
  const Vec3d o = rig.camera.CentreInWorld();
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      const Vec3d d = rig.camera.RayDirectionInWorld(Vec2d(x, y));
      Vec3d p = o + d * (n.dot(p0 - o) / n.dot(d));
      p += n * noise(rng);
      if (uni(rng) < outliers) p += n * (50e-6 + 200e-6 * uni(rng));
      const size_t i = static_cast<size_t>(y) * kW + x;
      for (int c = 0; c < 3; ++c) s.xyz.channel(c)[i] = static_cast<float>(p[c]);
      ++s.points;
    }
  return s;
}

TEST(CalibrateMount, PlaneThroughNoisyPointsWithOutliersDefinesTheWorld) {
  const Rig rig = TestRig();
  // The true mount in the rig's world: the inverse of the tilt (so the camera looks at it).
  Rigid3d rig_from_mount;
  rig_from_mount.rotation =
      Eigen::AngleAxisd(20.0 * std::numbers::pi / 180, Vec3d::UnitX()).matrix();
  rig_from_mount.translation = Vec3d(0.003, -0.004, 0.005);
  const double sigma = 2e-6;
  const FlatTargetScan scan = MountScan(rig, rig_from_mount, sigma, 0.03, 1);
  const MountPlane plane = FitMountPlane(scan, rig, MountPlaneOptions());
  // Noise-derived bounds: the RMS is the noise (outliers rejected), the normal within 5 of its
  // predicted sigmas.
  EXPECT_NEAR(plane.rms_m / sigma, 1.0, 0.1) << plane.ToJson().dump();
  const Vec3d n_true = rig_from_mount.rotation.col(2);
  const double angle = std::acos(std::min(1.0, plane.normal.dot(n_true)));
  EXPECT_LT(angle, 5 * plane.normal_sigma_rad) << plane.ToJson().dump();
  EXPECT_NEAR(plane.offset, n_true.dot(rig_from_mount.translation), 5 * plane.offset_sigma_m);
  EXPECT_GT(plane.inliers, 0.95 * kW * kH);
  EXPECT_LT(plane.inliers, 0.975 * kW * kH);  // the 3% outliers went
  // The world moved onto it: the points at z ~ 0, the camera above (+z towards the rig), the
  // camera's optical axis through the origin, the devices' relative pose kept.
  const Rig on = RigOnMount(rig, plane);
  const Rigid3d new_from_old = on.camera.world_from_device * rig.camera.world_from_device.Inverse();
  double sz = 0;
  int m = 0;
  for (size_t i = 0; i < scan.xyz.pixels(); i += 7) {
    const Vec3d p(scan.xyz.channel(0)[i], scan.xyz.channel(1)[i], scan.xyz.channel(2)[i]);
    const double z = (new_from_old * p).z();
    if (std::abs(z) < 20e-6) {
      sz += z * z;
      ++m;
    }
  }
  EXPECT_NEAR(std::sqrt(sz / m) / sigma, 1.0, 0.1);
  EXPECT_GT(on.camera.CentreInWorld().z(), 0.2);
  const Vec3d axis_hit =
      on.camera.world_from_device *
      Vec3d(0, 0, on.camera.CentreInWorld().z() / -on.camera.world_from_device.rotation.col(2).z());
  EXPECT_LT(axis_hit.norm(), 1e-9);
  // x along the camera's x projected: the camera's x axis has no world y component.
  EXPECT_NEAR(on.camera.world_from_device.rotation.col(0).y(), 0.0, 1e-12);
  const Rigid3d rel_old = rig.projector.world_from_device.Inverse() * rig.camera.world_from_device;
  const Rigid3d rel_new = on.projector.world_from_device.Inverse() * on.camera.world_from_device;
  EXPECT_LT((rel_old.translation - rel_new.translation).norm(), 1e-12);
  EXPECT_LT((rel_old.rotation - rel_new.rotation).norm(), 1e-12);
}

TEST(CalibrateMount, RefusesTooFewPoints) {
  const Rig rig = TestRig();
  FlatTargetScan scan;
  scan.grid.width = kW;
  scan.grid.height = kH;
  scan.xyz = ImageF(kW, kH, 3, std::numeric_limits<float>::quiet_NaN());
  try {
    FitMountPlane(scan, rig, MountPlaneOptions());
    ADD_FAILURE() << "no points accepted";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
    EXPECT_NE(std::string(e.what()).find("0 points"), std::string::npos) << e.what();
  }
}

TEST(CalibrateShifter, RecoversStepsPerPxAndGainFromFrequencies) {
  const Rig rig = TestRig();
  Rigid3d rig_from_mount;
  rig_from_mount.rotation =
      Eigen::AngleAxisd(20.0 * std::numbers::pi / 180, Vec3d::UnitX()).matrix();
  rig_from_mount.translation = Vec3d(0.003, -0.004, 0.005);
  FlatTargetScan scan = MountScan(rig, rig_from_mount, 1e-6, 0.0, 2);
  // True shifter: S = 2150 steps per px at the projector centre, gain 0.04, -0.02, 0.03.
  const double S = 2150, gx = 0.04, gy = -0.02, gr = 0.03, nominal = 2048, rel_noise = 0.01;
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0, rel_noise);
  std::uniform_real_distribution<double> uni(0, 1);
  scan.ls_frequency.assign(scan.xyz.pixels(), std::numeric_limits<float>::quiet_NaN());
  const PinholeCamera& prj = rig.projector;
  int outliers = 0;
  for (size_t i = 0; i < scan.xyz.pixels(); ++i) {
    Vec2d uv;
    if (!prj.Project(Vec3d(scan.xyz.channel(0)[i], scan.xyz.channel(1)[i], scan.xyz.channel(2)[i]),
                     &uv))
      continue;
    const double un = (uv.x() - prj.K(0, 2)) / (prj.width / 2.0);
    const double vn = (uv.y() - prj.K(1, 2)) / (prj.height / 2.0);
    const double g = 1 + gx * un + gy * vn + gr * (un * un + vn * vn);
    // f in cycles per nominal px of a period-2 pattern: (nominal / S) g / 2.
    double f = nominal / S * g / 2 * (1 + noise(rng));
    if (uni(rng) < 0.02) {
      f *= 0.5 + uni(rng);  // failed fits
      ++outliers;
    }
    scan.ls_frequency[i] = static_cast<float>(f);
  }
  Session session;
  session.root = "synthetic";
  session.rig = rig;
  const ShifterCalibration cal = CalibrateShifter(session, scan, rig, ShifterCalibrationOptions());
  SCOPED_TRACE(cal.ToJson().dump());
  EXPECT_GT(cal.pixels, kW * kH * 9 / 10);
  EXPECT_NEAR(cal.pixel_sigma_rel / rel_noise, 1.0, 0.1);
  EXPECT_NEAR(cal.calibrated.steps_per_px, S, 4 * cal.steps_per_px_sigma);
  EXPECT_LT(cal.steps_per_px_sigma, 0.5);
  EXPECT_NEAR(cal.gain_x, gx, 4 * cal.gain_sigma[0]);
  EXPECT_NEAR(cal.gain_y, gy, 4 * cal.gain_sigma[1]);
  EXPECT_NEAR(cal.gain_r, gr, 4 * cal.gain_sigma[2]);
  EXPECT_EQ(cal.calibrated.axis, 'x');
  EXPECT_EQ(cal.calibrated.range_steps[1], 2048);
  EXPECT_NEAR(cal.median_steps_per_px, S, 0.1 * S);
  // No lens shift: one line, bad input.
  scan.ls_frequency.clear();
  EXPECT_THROW(CalibrateShifter(session, scan, rig, ShifterCalibrationOptions()), Error);
}

}  // namespace
}  // namespace mesoscan
