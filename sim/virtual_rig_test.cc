#include "sim/virtual_rig.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>

#include "assets/objects.h"
#include "core/error.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/progress.h"
#include "core/scan_folder.h"
#include "core/test_temp_dir.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) { return TestTempPath("sim_test", name); }

// Small, fast options: a crop of the paper rig, 2 x 2 supersampling, no noise.
SimulateOptions Small(const std::string& object, PixelRect crop) {
  Progress::SetEnabled(false);
  SetLogLevel(LogLevel::kWarning);
  SimulateOptions o;
  o.object = object;
  o.crop = crop;
  o.ls_frames = 4;
  o.supersample = 2;
  o.noise = 0.0;
  o.focus_height_m = 0.0;  // the analytic light models below assume the focus on the mount
  return o;
}

// World x, y of camera pixel (px, py) on the mount for the paper rig (straight down, 55 um).
int PaperPixelOfX(double x) { return static_cast<int>(std::lround(1087.5 + x / 55e-6)); }

// ---- the spec's patterns and the light model of sim/README.md, written independently ----
double SpecPattern(const Pattern& p, int u) {
  switch (p.type) {
    case PatternType::kSine:
      return 0.5 + 0.5 * std::cos(2 * M_PI * u / p.period_px + p.phase);
    case PatternType::kStripes:
      return static_cast<int64_t>(std::floor(u / (p.period_px / 2))) % 2 == 0 ? 1.0 : 0.0;
    case PatternType::kWhite:
      return 1.0;
    case PatternType::kBlack:
      return 0.0;
    case PatternType::kGrayCode: {  // bit k (MSB first) of the block's reflected binary code
      const int64_t block = static_cast<int64_t>(std::floor(u / p.block_px));
      const int64_t gray = block ^ (block >> 1);
      return ((gray >> (p.bits - 1 - p.bit)) & 1) != p.inverted ? 1.0 : 0.0;
    }
  }
  return 0.0;
}
double Phi(double z) { return 0.5 * std::erfc(-z / std::sqrt(2.0)); }
// Box of width f (fill factor) convolved with a Gaussian of sigma, unit integral.
double W(double t, double f, double sigma) {
  return (Phi((t + f / 2) / sigma) - Phi((t - f / 2) / sigma)) / f;
}

class PlaneSession : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    // A 24 x 16 crop on the tilted steel bar, 0.6 mm right of the mount centre.
    options_ = Small("plane", {PaperPixelOfX(0.6e-3) - 12, 709, 24, 16});
    dir_ = TempDir("plane");
    summary_ = Simulate(options_, dir_);
  }
  static void TearDownTestSuite() { fs::remove_all(dir_); }
  static SimulateOptions options_;
  static fs::path dir_;
  static SimulateSummary summary_;
};
SimulateOptions PlaneSession::options_;
fs::path PlaneSession::dir_;
SimulateSummary PlaneSession::summary_;

TEST_F(PlaneSession, GroundTruthPointsOnTheAnalyticPlane) {
  const ImageF pts = ReadExrChannels(dir_ / "gt_points.exr", {"X", "Y", "Z"});
  const PinholeCamera cam = ResolveRig(options_).camera;
  ASSERT_EQ(pts.width(), 24);
  ASSERT_EQ(pts.height(), 16);
  const double slope = std::tan(kBarAngleRad);
  double max_plane = 0, max_ray = 0;
  for (int y = 0; y < pts.height(); ++y)
    for (int x = 0; x < pts.width(); ++x) {
      const Vec3d p(pts(x, y, 0), pts(x, y, 1), pts(x, y, 2));
      ASSERT_TRUE(p.allFinite()) << "pixel " << x << "," << y << " sees a lit surface";
      max_plane = std::max(max_plane, std::abs(p.z() - (p.x() - kBarX0) * slope));
      const Vec3d d = cam.RayDirectionInWorld(Vec2d(x, y));
      max_ray = std::max(max_ray, (p - cam.CentreInWorld()).cross(d).norm());
    }
  // 1e-7 m is the spec; float32 EXR storage adds < 1e-9 m here.
  EXPECT_LT(max_plane, 1e-7);
  EXPECT_LT(max_ray, 1e-7);
  EXPECT_EQ(summary_.lit_pixels, 24 * 16);
  EXPECT_EQ(summary_.unrefined_hits, 0);
}

TEST_F(PlaneSession, NoiselessFramesMatchTheAnalyticLightModel) {
  const Session s = ReadSession(dir_);
  const Rig& rig = s.rig;
  const PinholeCamera& cam = rig.camera;
  const PinholeCamera& prj = rig.projector;
  const SceneObject obj = MakeObject("plane");
  const Vec3d cp = prj.CentreInWorld(), cc = cam.CentreInWorld();
  const double r0 = cp.norm(), slope = std::tan(kBarAngleRad);
  const Vec3d n = Vec3d(-slope, 0, 1).normalized();
  const SimulateOptions& o = options_;
  const int S = o.supersample;
  // Tolerance: ADC rounding 0.5 / 16383 + bit replication 1 / 65535, plus the simulator's table
  // interpolation (sim/README.md "Light tables"): in x, (1/128)^2 / 8 * max|L''| with
  // max|L''| <= 2 * 2 * 0.242 / (f sigma^2); in sigma, (0.02)^2 / 8 * max|d2L/dsigma2| with
  // max|d2L/dsigma2| <= 2 * 2 * 0.33 / (f sigma^2); float x: 0.5 ulp(800) * max|L'| (<= 2 /
  // (f sigma sqrt(2 pi))). Each bound applies to L and R, scaled by exposure * shading <= 1.
  const double sig = o.blur_sigma_px, f = o.fill_factor;
  const double table = std::pow(1.0 / 128, 2) / 8 * 4 * 0.242 / (f * sig * sig) +
                       0.02 * 0.02 / 8 * 4 * 0.33 / (f * sig * sig) +
                       3.05e-5 * 2 / (f * sig * std::sqrt(2 * M_PI));
  const double tol = 0.5 / 16383 + 1.0 / 65535 + 2 * o.exposure * table;
  double max_err = 0, vmin = 1, vmax = 0;
  for (size_t fi = 0; fi < s.frames.size(); ++fi) {
    const Frame& frame = s.frames[fi];
    const ImageF img = ReadImageGrey(s.FramePath(fi));
    const double shift = frame.shift_steps / rig.lens_shifter->steps_per_px;
    for (int py = 1; py < cam.height; py += 5)
      for (int px = 1; px < cam.width; px += 5) {
        double light = 0, albedo = 0;
        for (int b = 0; b < S; ++b)
          for (int a = 0; a < S; ++a) {
            const Vec3d d =
                cam.RayDirectionInWorld(Vec2d(px + (a + 0.5) / S - 0.5, py + (b + 0.5) / S - 0.5));
            // Ray / bar plane z = (x - kBarX0) * slope.
            const double t = ((cc.x() - kBarX0) * slope - cc.z()) / (d.z() - d.x() * slope);
            const Vec3d p = cc + t * d;
            const double alb = obj.Albedo(p.x(), p.y());
            albedo += alb;
            Vec3d l = cp - p;
            const double r = l.norm();
            l /= r;
            Vec2d uv;
            ASSERT_TRUE(prj.Project(p, &uv));
            const double sigma = o.blur_sigma_px + o.defocus_px_per_m * std::abs(p.z());
            const double un = (uv.x() - prj.K(0, 2)) / (prj.width / 2.0);
            const double vn = (uv.y() - prj.K(1, 2)) / (prj.height / 2.0);
            const double g = 1 + o.shift_gain_x * un + o.shift_gain_y * vn +
                             o.shift_gain_r * (un * un + vn * vn);
            const double x = uv.x() - shift * g;
            double L = 0, R = 0;
            for (int u = static_cast<int>(x) - 8; u <= static_cast<int>(x) + 8; ++u)
              if (u >= 0 && u < prj.width) L += SpecPattern(frame.pattern, u) * W(x - u, f, sigma);
            for (int v = static_cast<int>(uv.y()) - 8; v <= static_cast<int>(uv.y()) + 8; ++v)
              if (v >= 0 && v < prj.height) R += W(uv.y() - v, f, sigma);
            light += alb * n.dot(l) * (r0 / r) * (r0 / r) * L * R;
          }
        const double expected = o.exposure * (light + o.ambient * albedo) / (S * S);
        const double got = img(px, py);
        max_err = std::max(max_err, std::abs(got - expected));
        vmin = std::min(vmin, expected);
        vmax = std::max(vmax, expected);
      }
  }
  EXPECT_LT(max_err, tol) << "tolerance " << tol;
  // The frames are not trivially flat: stripes and sines swing over most of the range.
  EXPECT_LT(vmin, 0.05);
  EXPECT_GT(vmax, 0.3);
  std::cout << "max |frame - analytic| = " << max_err << " (tolerance " << tol << ")\n";
}

TEST_F(PlaneSession, SessionReadsBack) {
  const Session s = ReadSession(dir_);
  EXPECT_EQ(s.frames.size(), 9u + 4u + 2u);
  EXPECT_EQ(s.rig.camera.width, 24);
  EXPECT_EQ(s.rig.camera.height, 16);
  EXPECT_EQ(s.frames[9].shift_steps, -2048);
  EXPECT_EQ(s.frames[12].shift_steps, 2048);
  ASSERT_TRUE(s.ground_truth.has_value());
  ASSERT_TRUE(s.extra.contains("simulation"));
  EXPECT_EQ(s.extra["simulation"]["frame_gains"].size(), s.frames.size());
  EXPECT_EQ(s.object, "plane");
}

TEST(VirtualRig, GroundTruthHeightMatchesGenerator) {
  struct Case {
    std::string object;
    double grid_m;
    double x_mm;     // crop centre on the mount
    double min_max;  // the crop must contain heights above this (the object is there)
  };
  const Case cases[] = {{"coin", 40e-6, 8.8, 1.25e-3},
                        {"ramp", 40e-6, -12.0, 1.5 * kRampSheetM},
                        {"leaf", 40e-6, 0.0, 0.9e-3},
                        {"plane", 100e-6, 10.0, 3e-3}};
  for (const Case& c : cases) {
    SimulateOptions o = Small(c.object, {PaperPixelOfX(c.x_mm * 1e-3) - 16, 700, 32, 32});
    o.object_pixel_size_m = c.grid_m;
    o.ps_periods_px = {};
    o.ls_frames = 0;
    o.black = false;
    o.supersample = 1;
    const fs::path dir = TempDir("gt_" + c.object);
    Simulate(o, dir);
    const HeightField gt = ReadHeightExr(dir / "gt_height.exr");
    const SceneObject obj = MakeObject(c.object, c.grid_m);
    EXPECT_EQ(gt.width(), 32) << c.object;
    EXPECT_EQ(gt.height(), 32) << c.object;
    EXPECT_NEAR(gt.pixel_size, 55e-6, 1e-9) << c.object;
    double max_err = 0, zmax = 0;
    for (int j = 0; j < gt.height(); ++j)
      for (int i = 0; i < gt.width(); ++i) {
        const double z = gt.z(i, j);
        max_err = std::max(max_err, std::abs(z - obj.SurfaceZ(gt.X(i), gt.Y(j))));
        zmax = std::max(zmax, z);
      }
    EXPECT_LT(max_err, 1e-9) << c.object;  // float32 storage of mm heights
    EXPECT_GT(zmax, c.min_max) << c.object;
    fs::remove_all(dir);
  }
}

TEST(VirtualRig, CoinCastsAShadowOnTheMount) {
  // The projector is on the +x side, 20 degrees off the vertical: left of the coin's edge
  // (x = -9.5 mm, 1.3 mm tall at the rim) the mount is in shadow for 1.3 mm * tan(incidence).
  SimulateOptions o = Small("coin", {PaperPixelOfX(-11.5e-3), 713, 80, 8});
  o.object_pixel_size_m = 40e-6;
  o.ps_periods_px = {};
  o.ls_frames = 0;
  o.supersample = 1;
  const fs::path dir = TempDir("shadow");
  Simulate(o, dir);
  const ImageF pts = ReadExrChannels(dir / "gt_points.exr", {"X", "Y", "Z"});
  const PinholeCamera cam = ResolveRig(o).camera;
  const Vec3d cp = PaperRig().projector.CentreInWorld();
  const double edge = -9.5e-3;
  const double incidence = std::atan2(cp.x() - edge, cp.z());
  const double shadow_end = edge - 1.3e-3 * std::tan(incidence);
  int shadowed = 0, checked = 0;
  for (int x = 0; x < pts.width(); ++x) {
    const Vec3d d = cam.RayDirectionInWorld(Vec2d(x, 4));
    const double wx = cam.CentreInWorld().x() + d.x() * (-cam.CentreInWorld().z() / d.z());
    const bool finite = std::isfinite(pts(x, 4, 2));
    if (wx < shadow_end - 2 * 55e-6) {
      EXPECT_TRUE(finite) << "x = " << wx;
      ++checked;
    } else if (wx > shadow_end + 2 * 55e-6 && wx < edge - 2 * 55e-6) {
      EXPECT_FALSE(finite) << "x = " << wx << " should be in shadow";
      ++shadowed;
    }
  }
  EXPECT_GE(shadowed, 5);
  EXPECT_GE(checked, 20);
  // The white frame is darker in the shadow (ambient only) than on the lit mount.
  const ImageF white = ReadImageGrey(dir / "frames/white.png");
  const int lit_x = 5, dark_x = PaperPixelOfX(0.5 * (shadow_end + edge)) - PaperPixelOfX(-11.5e-3);
  EXPECT_GT(white(lit_x, 4), 5 * white(dark_x, 4));
  fs::remove_all(dir);
}

TEST(VirtualRig, NoiseMatchesTheNoiseModel) {
  // On the bare mount: the residual of a noisy frame against the noiseless one, after the
  // recorded per-frame gain, has the model's variance (plus the noiseless frame's rounding).
  SimulateOptions o = Small("plane", {150, 150, 64, 64});
  o.ps_periods_px = {};
  o.ls_frames = 0;
  o.supersample = 1;
  const fs::path clean_dir = TempDir("clean"), noisy_dir = TempDir("noisy");
  Simulate(o, clean_dir);
  o.noise = 1.0;
  o.seed = 5;
  Simulate(o, noisy_dir);
  const Session noisy = ReadSession(noisy_dir);
  const NoiseModel model = MakeNoiseModel(o);
  const double q = 1.0 / 16383;
  for (size_t fi = 0; fi < noisy.frames.size(); ++fi) {
    const double gain = noisy.extra["simulation"]["frame_gains"][fi].get<double>();
    EXPECT_NE(gain, 1.0);
    EXPECT_LT(std::abs(gain - 1.0), 5 * model.GainJitterSigma());
    const ImageF clean = ReadImageGrey(clean_dir / noisy.frames[fi].file);
    const ImageF img = ReadImageGrey(noisy.FramePath(fi));
    double sum = 0, sum2 = 0;
    const size_t n = img.pixels();
    for (size_t k = 0; k < n; ++k) {
      const double m = clean.data()[k];
      const double r = (img.data()[k] - gain * m) / std::sqrt(model.Variance(m) + q * q / 12);
      sum += r;
      sum2 += r * r;
    }
    const double mean = sum / n, var = sum2 / n - mean * mean;
    // 4.5 standard errors of the mean and of a chi-square variance with n = 4096.
    EXPECT_NEAR(mean, 0.0, 4.5 / std::sqrt(n)) << noisy.frames[fi].file;
    EXPECT_NEAR(var, 1.0, 4.5 * std::sqrt(2.0 / n)) << noisy.frames[fi].file;
  }
  fs::remove_all(clean_dir);
  fs::remove_all(noisy_dir);
}

TEST(VirtualRig, CropIsACameraOfItsOwn) {
  const PinholeCamera full = PaperRig().camera;
  const PinholeCamera crop = CropCamera(full, PixelRect{300, 200, 100, 80});
  EXPECT_EQ(crop.width, 100);
  EXPECT_EQ(crop.height, 80);
  const Vec3d a = crop.RayDirectionInWorld(Vec2d(10, 20));
  const Vec3d b = full.RayDirectionInWorld(Vec2d(310, 220));
  EXPECT_LT((a - b).norm(), 1e-15);
  try {
    CropCamera(full, PixelRect{2100, 0, 100, 80});
    FAIL() << "a crop outside the camera must be refused";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kUsage);
  }
}

TEST(VirtualRig, BadOptionsAreRefused) {
  SimulateOptions o;
  o.supersample = 0;
  EXPECT_THROW(o.Check(), Error);
  o = SimulateOptions();
  o.ps_phases = 2;
  EXPECT_THROW(o.Check(), Error);
  o = SimulateOptions();
  o.ls_frames = 3;
  EXPECT_THROW(o.Check(), Error);
  try {
    MakeObject("teapot", 0.0, "SimulateOptions.object");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
    EXPECT_EQ(e.option(), "SimulateOptions.object");
    EXPECT_NE(std::string(e.what()).find("'teapot'"), std::string::npos) << e.what();
  }
}

TEST(VirtualRig, PaperRigGeometry) {
  const Rig rig = PaperRig();
  // 55 um per camera pixel on the mount; the projector covers the whole camera field.
  EXPECT_NEAR(rig.camera.K(0, 0) * 55e-6, 0.25, 1e-12);
  const Vec3d cp = rig.projector.CentreInWorld();
  EXPECT_NEAR(std::atan2(cp.x(), cp.z()) * 180 / M_PI, 20.0, 1e-9);
  for (double x : {-0.06, 0.06})
    for (double y : {-0.04, 0.04}) {
      Vec2d uv;
      ASSERT_TRUE(rig.projector.Project(Vec3d(x, y, 0), &uv));
      EXPECT_GT(uv.x(), 0);
      EXPECT_LT(uv.x(), rig.projector.width - 1);
      EXPECT_GT(uv.y(), 0);
      EXPECT_LT(uv.y(), rig.projector.height - 1);
    }
  // u grows along world +x.
  Vec2d a, b;
  rig.projector.Project(Vec3d(0, 0, 0), &a);
  rig.projector.Project(Vec3d(1e-3, 0, 0), &b);
  EXPECT_GT(b.x() - a.x(), 5.0);
  EXPECT_NEAR(b.y(), a.y(), 1e-9);
}

}  // namespace
}  // namespace mesoscan
