// Unit tests of the reconstruction pipeline on tiny synthetic sessions written here from the
// pattern definitions of docs/formats.md (ideal band-limited profiles, no optics),
// independent of the virtual rig: sign and half-pixel conventions, the centre-of-range phase
// mapping with a per-pixel frequency, distortion on both devices, phase-shift-only decoding of a
// hierarchical pattern set from 8-bit frames, rejection of pixels mixing two surfaces.

#include "heightfield/reconstruct.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <functional>
#include <random>

#include "core/image_io.h"
#include "core/numbers.h"
#include "core/progress.h"
#include "core/scan_folder.h"
#include "core/test_temp_dir.h"
#include "heightfield/frames.h"
#include "heightfield/resample.h"
#include "heightfield/triangulate.h"
#include "session/session.h"
#include "sim/ground_truth.h"

namespace mesoscan {
namespace {

namespace fs = std::filesystem;

Rig TestRig(int w, int h, bool distortion) {
  Rig rig;
  rig.camera.width = w;
  rig.camera.height = h;
  rig.camera.K << 4545.45, 0, (w - 1) / 2.0, 0, 4545.45, (h - 1) / 2.0, 0, 0, 1;
  rig.camera.world_from_device.rotation << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  rig.camera.world_from_device.translation = Vec3d(0, 0, 0.25);
  rig.projector.width = 800;
  rig.projector.height = 600;
  rig.projector.K << 1650, 0, 399.5, 0, 1650, 299.5, 0, 0, 1;
  const double a = 20 * kPi / 180;
  rig.projector.world_from_device.rotation << std::cos(a), 0, -std::sin(a), 0, -1, 0, -std::sin(a),
      0, -std::cos(a);
  rig.projector.world_from_device.translation = Vec3d(0.0906, 0, 0.249);
  if (distortion) {
    // Strong enough to matter at these crops: a pinhole decoder is off by many microns.
    rig.camera.distortion = {-0.3, 0.2, 0.001, -0.002, 0.0};
    rig.projector.distortion = {0.15, -0.1, 0.002, 0.001, 0.0};
    rig.camera.K(0, 2) += 300;  // off-axis crop: distortion is large there
  }
  LensShifter ls;
  rig.lens_shifter = ls;
  return rig;
}

struct SyntheticOptions {
  int width = 48, height = 36;
  bool distortion = false;
  std::vector<double> periods{7, 11, 13};
  int phases = 3;
  int ls_frames = 50;
  int ls_first = -2048, ls_last = 1966;  // asymmetric on purpose: centre != 0
  double shift_gain = 1.03;              // true displacement per nominal px (per-pixel f)
  bool eight_bit = false;
  double noise = 0.0;
  double jitter = 0.0;  // relative sigma of a per-frame gain (camera brightness jitter)
  std::vector<double>* applied_gains = nullptr;  // receives each frame's gain, session order
  // Surface height z(x, y) (world metres) and, for mixed pixels, a second surface and the
  // world x beyond which it is seen.
  std::function<double(double, double)> surface = [](double x, double y) {
    return 0.001 + 0.05 * x + 0.02 * y;
  };
  std::function<double(double, double)> surface2;
  double edge_x = 1e9;
};

// World point seen by camera pixel (px, py) on z = surface(x, y) (fixed-point on the ray).
Vec3d HitSurface(const Rig& rig, double px, double py,
                 const std::function<double(double, double)>& surface) {
  const Vec3d o = rig.camera.CentreInWorld();
  const Vec3d d = rig.camera.RayDirectionInWorld({px, py});
  double t = (o.z() - surface(o.x(), o.y())) / -d.z();
  for (int it = 0; it < 50; ++it) {
    const Vec3d p = o + t * d;
    t = (o.z() - surface(p.x(), p.y())) / -d.z();
  }
  return o + t * d;
}

// Writes a session whose pixels see ideal profiles: sine frames 0.5 + 0.5 cos(2 pi u / p + delta)
// and lens-shift frames 0.5 + 0.4 cos(pi (g s - u)) (the stripes' fundamental, g the shifter
// gain), scaled by albedo 0.8 over ambient 0.05. Returns the session; ground truth is written.
Session WriteSynthetic(const fs::path& dir, const SyntheticOptions& o) {
  fs::remove_all(dir);
  fs::create_directories(dir / "frames");
  Session s;
  s.root = fs::absolute(dir);
  s.object = "synthetic";
  s.rig = TestRig(o.width, o.height, o.distortion);
  // Per pixel: up to 4 sub-samples across x (mixing at the edge), each with its u.
  const int sub = 4;
  std::vector<std::vector<double>> us(static_cast<size_t>(o.width) * o.height);
  ImageF gt(o.width, o.height, 3, std::numeric_limits<float>::quiet_NaN());
  for (int y = 0; y < o.height; ++y)
    for (int x = 0; x < o.width; ++x) {
      auto& u = us[static_cast<size_t>(y) * o.width + x];
      for (int k = 0; k < sub; ++k) {
        const double px = x - 0.5 + (k + 0.5) / sub;
        Vec3d p = HitSurface(s.rig, px, y, o.surface);
        if (o.surface2 && p.x() > o.edge_x) p = HitSurface(s.rig, px, y, o.surface2);
        Vec2d uv(std::numeric_limits<double>::quiet_NaN(), 0.0);  // unset if Project fails
        s.rig.projector.Project(p, &uv);
        u.push_back(uv.x());
      }
      Vec3d c = HitSurface(s.rig, x, y, o.surface);
      if (o.surface2 && c.x() > o.edge_x) c = HitSurface(s.rig, x, y, o.surface2);
      for (int ch = 0; ch < 3; ++ch) gt(x, y, ch) = static_cast<float>(c[ch]);
    }
  std::mt19937 rng(7);
  std::normal_distribution<double> gauss(0.0, 1.0);
  auto write = [&](const std::string& name, const std::function<double(double)>& value) {
    ImageF im(o.width, o.height, 1);
    const double gain = 1.0 + o.jitter * gauss(rng);
    if (o.applied_gains) o.applied_gains->push_back(gain);
    for (size_t i = 0; i < im.pixels(); ++i) {
      double v = 0;
      for (double u : us[i]) v += value(u);
      im.data()[i] =
          static_cast<float>(gain * (0.05 + 0.8 * v / us[i].size()) + o.noise * gauss(rng));
    }
    const fs::path rel = fs::path("frames") / (name + ".png");
    if (o.eight_bit)
      WritePng8(dir / rel, QuantizeU8(im));
    else
      WritePng16(dir / rel, QuantizeU16(im));
    return rel.string();
  };
  for (double p : o.periods)
    for (int k = 0; k < o.phases; ++k) {
      Frame f;
      f.pattern.type = PatternType::kSine;
      f.pattern.period_px = p;
      f.pattern.phase = 2 * kPi * k / o.phases;
      f.file =
          write("ps" + std::to_string(static_cast<int>(p)) + "_" + std::to_string(k),
                [&](double u) { return 0.5 + 0.5 * std::cos(2 * kPi * u / p + f.pattern.phase); });
      s.frames.push_back(f);
    }
  for (int k = 0; k < o.ls_frames; ++k) {
    Frame f;
    f.pattern.type = PatternType::kStripes;
    f.pattern.period_px = 2;
    f.shift_steps = static_cast<int>(std::lround(
        o.ls_first + (o.ls_last - o.ls_first) * static_cast<double>(k) / (o.ls_frames - 1)));
    const double s_px = f.shift_steps / 2048.0;
    f.file = write("ls_" + std::to_string(k),
                   [&](double u) { return 0.5 + 0.4 * std::cos(kPi * (o.shift_gain * s_px - u)); });
    s.frames.push_back(f);
  }
  Frame white, black;
  white.pattern.type = PatternType::kWhite;
  white.file = write("white", [](double) { return 1.0; });
  black.pattern.type = PatternType::kBlack;
  black.file = write("black", [](double) { return 0.0; });
  s.frames.push_back(white);
  s.frames.push_back(black);
  if (o.ls_frames == 0) s.rig.lens_shifter.reset();
  WriteExr(dir / "gt_points.exr", gt, {"X", "Y", "Z"});
  HeightField gt_height;  // not used by these tests; the reader wants the file
  gt_height.z = ImageF(1, 1, 1, 0.0f);
  WriteHeightExr(dir / "gt_height.exr", gt_height);
  s.ground_truth = GroundTruth{"gt_points.exr", "gt_height.exr"};
  WriteSessionJson(s);
  return ReadSession(dir);
}

fs::path TestDir(const std::string& name) { return TestTempPath("reconstruct_test", name); }

class ReconstructTest : public ::testing::Test {
 protected:
  void SetUp() override { Progress::SetEnabled(false); }
};

TEST_F(ReconstructTest, TriangulatorInvertsProjectionWithDistortion) {
  const Rig rig = TestRig(64, 48, /*distortion=*/true);
  const Triangulator tri(rig.camera, rig.projector);
  for (const Vec3d& p :
       {Vec3d(0.001, 0.002, 0.003), Vec3d(-0.004, 0.001, 0.0), Vec3d(0.0, -0.003, 0.006)}) {
    Vec2d c, q;
    ASSERT_TRUE(rig.camera.Project(p, &c));
    ASSERT_TRUE(rig.projector.Project(p, &q));
    const auto r = tri.Triangulate(c.x(), c.y(), q.x());
    ASSERT_TRUE(r.has_value());
    EXPECT_LT((*r - p).norm(), 1e-9) << p.transpose() << " -> " << r->transpose();
  }
}

TEST_F(ReconstructTest, ResampleKeepsPlaneAndLeavesDiscontinuitiesEmpty) {
  // A 40x30 camera grid of a tilted plane, with a 1 mm step at column 20.
  ImageF xyz(40, 30, 3), conf(40, 30, 1, 1.0f);
  const double pitch = 50e-6;
  for (int y = 0; y < 30; ++y)
    for (int x = 0; x < 40; ++x) {
      const double wx = x * pitch, wy = -y * pitch;
      xyz(x, y, 0) = static_cast<float>(wx);
      xyz(x, y, 1) = static_cast<float>(wy);
      xyz(x, y, 2) = static_cast<float>(0.01 * wx + (x >= 20 ? 1e-3 : 0.0));
    }
  xyz(5, 5, 2) = std::numeric_limits<float>::quiet_NaN();  // a hole
  const HeightField hf = ResampleToGrid(xyz, conf, {});
  EXPECT_NEAR(hf.pixel_size, pitch, 1e-9);
  int filled = 0, between = 0;
  for (int j = 0; j < hf.height(); ++j)
    for (int i = 0; i < hf.width(); ++i) {
      const float z = hf.z(i, j);
      if (!std::isfinite(z)) continue;
      ++filled;
      const double plane = 0.01 * hf.X(i);
      const double dz = z - plane;
      if (std::abs(dz) > 1e-7 && std::abs(dz - 1e-3) > 1e-7) ++between;
    }
  EXPECT_EQ(between, 0);
  EXPECT_GT(filled, 39 * 29 - 60);  // all but the step column and the hole's neighbourhood
  // The step column is not bridged: the grid column between x = 19 and 20 pitches is empty.
  EXPECT_FALSE(std::isfinite(hf.z(static_cast<int>(std::lround(hf.I(19.5 * pitch))), 10)));
}

TEST_F(ReconstructTest, NoiselessLensShiftSessionIsExact) {
  SyntheticOptions o;
  const Session s = WriteSynthetic(TestDir("noiseless"), o);
  ReconstructOptions opt;
  opt.keep_diagnostics = true;
  ReconstructSummary sum;
  const Scan scan = Reconstruct(s, opt, &sum);
  const GroundTruthErrors e = EvaluateAgainstGroundTruth(s, scan.points);
  EXPECT_GE(e.coverage, 0.999) << sum.BriefReport();
  // 16-bit quantisation only: the model and the triangulation carry no bias.
  EXPECT_LT(e.rms_m, 0.1e-6) << "mean " << e.mean_m << " max " << e.max_abs_m;
  // The per-pixel frequency was found (nominal 0.5 cycles/px times the shifter gain).
  EXPECT_NEAR(sum.diagnostics.ls_frequency(10, 10), 0.5 * o.shift_gain, 1e-4);
  EXPECT_TRUE(sum.used_lens_shift);
  EXPECT_EQ(sum.unwrapping, "temporal");
}

TEST_F(ReconstructTest, DistortionOnBothDevices) {
  SyntheticOptions o;
  o.distortion = true;
  const Session s = WriteSynthetic(TestDir("distortion"), o);
  const Scan scan = Reconstruct(s, {});
  const GroundTruthErrors e = EvaluateAgainstGroundTruth(s, scan.points);
  EXPECT_GE(e.coverage, 0.999);
  EXPECT_LT(e.rms_m, 0.1e-6) << "max " << e.max_abs_m;
}

TEST_F(ReconstructTest, PhaseShiftOnlyHierarchicalEightBit) {
  // A plain phase-shift scanner: a single-period cue plus a short period, 8-bit frames,
  // distortion on both devices, no lens shifter.
  SyntheticOptions o;
  o.periods = {800, 40};
  o.phases = 6;
  o.ls_frames = 0;
  o.eight_bit = true;
  o.distortion = true;
  o.noise = 0.002;
  const Session s = WriteSynthetic(TestDir("ps_only"), o);
  ReconstructSummary sum;
  const Scan scan = Reconstruct(s, {}, &sum);
  const GroundTruthErrors e = EvaluateAgainstGroundTruth(s, scan.points);
  EXPECT_FALSE(sum.used_lens_shift);
  EXPECT_EQ(sum.unwrapping, "hierarchical");
  // Every pixel decodes; the few whose predicted depth sigma exceeds max_depth_sigma_m (20 um:
  // the tail of the 8-bit noise, 3 of 1728 here) and the mixed pixels are rejected.
  EXPECT_GE(e.coverage, 0.985) << sum.BriefReport();
  EXPECT_LE(sum.pixels_rejected_ambiguous, 1728 / 200) << sum.BriefReport();
  // Noise 0.002 plus 8-bit quantisation (1/255/sqrt(12) = 0.0011): the depth error follows the
  // Cramer-Rao prediction from the residuals (6 phases, 3 residual degrees of freedom per
  // period, so the estimate itself scatters: 1.5x).
  ASSERT_GT(sum.predicted_depth_rms_m, 0);
  EXPECT_LT(e.rms_m, 1.5 * sum.predicted_depth_rms_m)
      << e.rms_m << " vs predicted " << sum.predicted_depth_rms_m;
  EXPECT_LT(std::abs(e.mean_m), 0.2 * sum.predicted_depth_rms_m);
  EXPECT_EQ(e.gross, 0);
}

// A 1.5 mm step seen from above: camera pixels straddling it mix the two surfaces.
void ExpectNoPointBetweenSurfaces(const SyntheticOptions& o, const Scan& scan) {
  int on = 0, between = 0;
  for (int y = 0; y < o.height; ++y)
    for (int x = 0; x < o.width; ++x) {
      const float z = scan.points.xyz(x, y, 2);
      if (!std::isfinite(z)) continue;
      if (std::abs(z) < 10e-6 || std::abs(z - 0.0015) < 10e-6)
        ++on;
      else
        ++between;
    }
  EXPECT_EQ(between, 0);
  // Only the column of mixed pixels is lost (one of 48).
  EXPECT_GE(on, o.width * o.height * 45 / 48);
}

TEST_F(ReconstructTest, MixedPixelsAtADepthStepAreRejectedPhaseShiftOnly) {
  SyntheticOptions o;
  o.periods = {800, 40};
  o.phases = 6;
  o.ls_frames = 0;
  o.surface = [](double, double) { return 0.0; };
  o.surface2 = [](double, double) { return 0.0015; };
  o.edge_x = 15e-6;  // inside camera column 24: 1 of 4 sub-samples on the lower surface
  const Session s = WriteSynthetic(TestDir("mixed_ps"), o);
  ReconstructSummary sum;
  const Scan scan = Reconstruct(s, {}, &sum);
  EXPECT_GT(sum.pixels_rejected_discontinuity, 0);
  ExpectNoPointBetweenSurfaces(o, scan);
}

TEST_F(ReconstructTest, MixedPixelsAtADepthStepAreRejectedLensShift) {
  SyntheticOptions o;
  o.surface = [](double, double) { return 0.0; };
  o.surface2 = [](double, double) { return 0.0015; };
  o.edge_x = 15e-6;  // inside camera column 24: 1 of 4 sub-samples on the lower surface
  const Session s = WriteSynthetic(TestDir("mixed_ls"), o);
  const Scan scan = Reconstruct(s, {});
  ExpectNoPointBetweenSurfaces(o, scan);
}

TEST_F(ReconstructTest, OptionsCheckNamesTheField) {
  ReconstructOptions o;
  o.phase_shift.min_modulation = 0.9;
  try {
    o.Check();
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("min_modulation"), std::string::npos);
  }
}

TEST_F(ReconstructTest, PerFrameBrightnessJitterIsNormalised) {
  // Every frame (sine, lens shift, white, black) has its own gain, 1% rms (the paper's Sec. 5.1
  // camera; twice the virtual rig's default), no other noise. The part of the jitter along the
  // sinusoid is absorbed by each pixel's fit and biases its phase by ~0.01 sqrt(2/50) d/a =
  // 2.6e-3 rad = 0.4 um here; normalisation must not make it worse.
  SyntheticOptions o;
  o.jitter = 0.01;
  const Session s = WriteSynthetic(TestDir("jitter"), o);
  ReconstructOptions off;
  off.gains.normalize_luminance = false;
  const GroundTruthErrors raw = EvaluateAgainstGroundTruth(s, Reconstruct(s, off).points);
  ReconstructSummary sum;
  const GroundTruthErrors e = EvaluateAgainstGroundTruth(s, Reconstruct(s, {}, &sum).points);
  EXPECT_GE(e.coverage, 0.999);
  EXPECT_LT(e.rms_m, 0.4e-6);
  EXPECT_LE(e.rms_m, 1.05 * raw.rms_m);
  // The sine frames' gains are estimated too (not left at 1).
  int moved = 0;
  for (size_t f = 0; f < 9; ++f) moved += std::abs(sum.frame_gains[f] - 1.0) > 1e-3;
  EXPECT_GE(moved, 3);
}

// The ground truth's reader (the CLI's, through OpenEXR directly) returns the Z and footprint
// channels of gt_points.exr as stored, and names the file and the channel when X, Y or Z is
// missing; the evaluation is the same as from the image read whole through OIIO.
TEST_F(ReconstructTest, GroundTruthReaderTakesZAndFootprintChannels) {
  const fs::path dir = TestDir("gt_reader");
  fs::create_directories(dir);
  const int w = 7, h = 5;
  ImageF gt(w, h, 5);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      gt(x, y, 0) = 0.001f * x;
      gt(x, y, 1) = 0.002f * y;
      gt(x, y, 2) = (x + y) % 4 == 0 ? NAN : 1e-4f * (x * 3 + y);
      gt(x, y, 3) = (x % 3) / 2.0f;
      gt(x, y, 4) = 1e-6f * y;
    }
  WriteExr(dir / "gt_points.exr", gt, {"X", "Y", "Z", "lit_fraction", "relief"});
  Session s;
  s.root = dir;
  s.ground_truth = GroundTruth{"gt_points.exr", "gt_height.exr"};
  const GroundTruthPoints read = ReadGroundTruthPoints(s);
  ASSERT_EQ(read.info.channel_names, (std::vector<std::string>{"Z", "lit_fraction", "relief"}));
  ASSERT_EQ(read.image.width(), w);
  ASSERT_EQ(read.image.height(), h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < 3; ++c) {
        const float want = gt(x, y, c + 2), got = read.image(x, y, c);
        EXPECT_TRUE(std::isnan(want) ? std::isnan(got) : got == want) << x << "," << y << "," << c;
      }
  // The same figures as from the whole image read through OIIO.
  ScanPoints points;
  points.xyz = ImageF(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      points.xyz(x, y, 0) = gt(x, y, 0);
      points.xyz(x, y, 1) = gt(x, y, 1);
      points.xyz(x, y, 2) = (x == 1 && y == 1) ? NAN : gt(x, y, 2) + 1e-7f * ((x * 7 + y) % 5);
    }
  GroundTruthPoints whole;
  whole.path = dir / "gt_points.exr";
  whole.image = ReadImage(whole.path, &whole.info);
  const Json a = EvaluateAgainstGroundTruth(read, points).ToJson();
  const Json b = EvaluateAgainstGroundTruth(whole, points).ToJson();
  EXPECT_EQ(a.dump(), b.dump());
  EXPECT_TRUE(a["footprint_known"].get<bool>());
  // A missing Y channel: bad input naming the file and the channel.
  ImageF xz(w, h, 2, 0.0f);
  WriteExr(dir / "gt_points.exr", xz, {"X", "Z"});
  try {
    ReadGroundTruthPoints(s);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
    EXPECT_NE(std::string(e.what()).find("gt_points.exr"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("'Y'"), std::string::npos) << e.what();
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace mesoscan
