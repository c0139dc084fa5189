// Gray-code round trips through the virtual rig (sim/virtual_rig.h) with ground truth: the Gray
// code alone (the projector column of every lit pixel), and one sine period whose fringe order a
// complementary Gray code fixes, each against a plain decoder on the same frames.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "core/image_io.h"
#include "core/numbers.h"
#include "core/progress.h"
#include "core/test_temp_dir.h"
#include "heightfield/reconstruct.h"
#include "session/session.h"
#include "sim/ground_truth.h"
#include "sim/virtual_rig.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) { return TestTempPath("graycode_sim", name); }

// The coin (depth edges: its rim and relief) in a crop of the paper rig, focused on the mount.
SimulateOptions CoinOptions(int w, int h) {
  SimulateOptions o;
  o.object = "coin";
  o.crop = PixelRect{1088 - w / 2, 717 - h / 2, w, h};
  o.focus_height_m = 0.0;
  o.seed = 5;
  o.ls_frames = 0;
  return o;
}

// The true projector coordinate (along x) of every camera pixel's ground-truth point, NaN where
// there is none or where the pixel's footprint is mixed (sees two surfaces or a shadow edge):
// the depth edges are left out.
ImageF TrueColumns(const Session& s) {
  // gt_points.exr: X, Y, Z, lit_fraction, relief (the channels in the file's order).
  const ImageF im = ReadImage(s.root / s.ground_truth->points);
  ImageF u(im.width(), im.height(), 1, std::numeric_limits<float>::quiet_NaN());
  const bool footprint = im.channels() >= 5;
  for (int y = 0; y < im.height(); ++y)
    for (int x = 0; x < im.width(); ++x) {
      const Vec3d p(im(x, y, 0), im(x, y, 1), im(x, y, 2));
      if (!p.allFinite()) continue;
      if (footprint && (im(x, y, 3) < 1.0f || im(x, y, 4) > 2e-6f)) continue;  // mixed
      Vec2d uv;
      if (s.rig.projector.Project(p, &uv)) u(x, y) = static_cast<float>(uv.x());
    }
  return u;
}

// The plain decoder: every bit thresholded at the middle of the white and black frames (or
// against its inverse), no unknown bits, the block index of the code read as it comes.
ImageF PlainGrayDecode(const Session& s) {
  const ImageF white = ReadImageGrey(s.FramePath(MakeFramePlan(s.frames).white.front()));
  const ImageF black = ReadImageGrey(s.FramePath(MakeFramePlan(s.frames).black.front()));
  int bits = 0;
  double block = 1;
  for (const Frame& f : s.frames)
    if (f.pattern.type == PatternType::kGrayCode) bits = f.pattern.bits, block = f.pattern.block_px;
  std::vector<ImageF> plain(bits), inverse(bits);
  for (size_t i = 0; i < s.frames.size(); ++i) {
    const Pattern& p = s.frames[i].pattern;
    if (p.type != PatternType::kGrayCode) continue;
    (p.inverted ? inverse : plain)[p.bit] = ReadImageGrey(s.FramePath(i));
  }
  ImageF u(white.width(), white.height(), 1, std::numeric_limits<float>::quiet_NaN());
  for (int y = 0; y < white.height(); ++y)
    for (int x = 0; x < white.width(); ++x) {
      uint32_t gray = 0;
      for (int k = 0; k < bits; ++k) {
        const float v = plain[k](x, y);
        const float t = inverse[k].pixels() ? inverse[k](x, y) : 0.5f * (white(x, y) + black(x, y));
        gray = gray << 1 | (v > t ? 1u : 0u);
      }
      uint32_t b = gray;
      for (uint32_t sh = gray >> 1; sh; sh >>= 1) b ^= sh;
      u(x, y) = static_cast<float>(b * block + 0.5 * (block - 1));
    }
  return u;
}

struct ColumnFigures {
  int64_t scored = 0, exact = 0, off_more_than_one = 0;
  double ExactFraction() const { return scored ? double(exact) / scored : 0.0; }
};

// Over the pixels with a true column: exact = the decoded coordinate within half a column of the
// truth (an edge pixel's coordinate is the edge: within half a column of either side's truth);
// off by more than one column = more than 1.5 px away. Pixels without a decoded coordinate (or
// with confidence 0) count as not exact, never as off.
ColumnFigures Score(const ImageF& truth, const ImageF& decoded, const ImageF* confidence) {
  ColumnFigures f;
  for (int y = 0; y < truth.height(); ++y)
    for (int x = 0; x < truth.width(); ++x) {
      if (!std::isfinite(truth(x, y))) continue;
      ++f.scored;
      const float u = decoded(x, y);
      if (!std::isfinite(u) || (confidence && !((*confidence)(x, y) > 0))) continue;
      const double d = std::abs(u - truth(x, y));
      f.exact += d <= 0.5 + 1e-3;
      f.off_more_than_one += d > 1.5;
    }
  return f;
}

TEST(GrayCodeSim, ColumnOfEveryLitPixelAwayFromDepthEdges) {
  Progress::SetEnabled(false);
  SimulateOptions so = CoinOptions(200, 160);
  so.ps_periods_px.clear();
  so.graycode_bits = 10;  // the paper rig's 800 px projector
  const fs::path dir = TempDir("coin");
  Simulate(so, dir);
  const Session s = ReadSession(dir);
  ReconstructSummary sum;
  const Scan scan = Reconstruct(s, {}, &sum);
  EXPECT_EQ(sum.unwrapping, "graycode");
  const ImageF truth = TrueColumns(s);
  const ColumnFigures got = Score(truth, scan.points.projector_u, &scan.points.confidence);
  const ColumnFigures plain = Score(truth, PlainGrayDecode(s), nullptr);
  std::printf(
      "graycode alone: exact column %.5f of %lld lit single-surface pixels, %lld "
      "confident points off by more than one column; plain decoder %.5f exact, %lld "
      "off by more than one\n",
      got.ExactFraction(), static_cast<long long>(got.scored),
      static_cast<long long>(got.off_more_than_one), plain.ExactFraction(),
      static_cast<long long>(plain.off_more_than_one));
  ASSERT_GT(got.scored, 10000);
  EXPECT_GE(got.ExactFraction(), 0.999);
  EXPECT_EQ(got.off_more_than_one, 0);
  fs::remove_all(dir);
}

// One 60-px sine period in 12 steps whose fringe order a complementary Gray code (blocks of half
// the period) fixes, on the tilted bar without gain jitter: every pixel's column at the noise
// floor of its phase set (Cramer-Rao: sigma_u = P / (2 pi) sqrt(2 / N) sigma / B, sigma the
// simulator's noise at the frames' mean, B the modulation), no period jump; the plain decoder (the
// order read from the Gray code's period-wide bits alone, as it comes) beside it.
TEST(GrayCodeSim, SinePeriodOrderedByAComplementaryGrayCodeAtTheNoiseFloor) {
  Progress::SetEnabled(false);
  SimulateOptions so;
  so.object = "plane";
  const int w = 200, h = 160, cx = static_cast<int>(std::lround(1087.5 - 17e-3 / 55e-6));
  so.crop = PixelRect{cx - w / 2, 717 - h / 2, w, h};
  so.focus_height_m = 0.0;
  so.seed = 12;
  so.gain_jitter = 0.0;
  so.ls_frames = 0;
  constexpr double kPeriod = 60;
  constexpr int kSteps = 12;
  so.ps_periods_px = {kPeriod};
  so.ps_phases = kSteps;
  so.graycode_block_px = kPeriod / 2;
  so.graycode_bits = 5;  // 32 blocks of 30 px cover the 800-px projector
  const fs::path dir = TempDir("sine_graycode");
  Simulate(so, dir);
  const Session s = ReadSession(dir);
  ReconstructOptions ro;
  ro.keep_diagnostics = true;
  // One 60-px period on the paper rig's 800-px projector: a column sigma of ~0.04 px is ~15 um
  // of depth, near the default depth-sigma gate (20 um), which is about trusting depth, not
  // about decoding: the columns are judged here.
  ro.consistency.max_depth_sigma_m = 1e-3;
  ReconstructSummary sum;
  const Scan scan = Reconstruct(s, ro, &sum);
  EXPECT_EQ(sum.unwrapping, "graycode");
  const ImageF truth = TrueColumns(s);
  const ImageF black = ReadImageGrey(s.FramePath(MakeFramePlan(s.frames).black.front()));
  const NoiseModel noise = MakeNoiseModel(so);
  const ReconstructDiagnostics& d = sum.diagnostics;
  // The plain decoder's column: the fringe order from the Gray code's period-wide bits (the block
  // index of all but the last bit), the phase from the pipeline's own wrapped phase.
  const ImageF plain_blocks = PlainGrayDecode(s);
  double chi2 = 0, chi2_plain = 0;
  int64_t n = 0, n_plain = 0, jumps = 0, jumps_plain = 0, scored = 0;
  for (int y = 0; y < truth.height(); ++y)
    for (int x = 0; x < truth.width(); ++x) {
      const double t = truth(x, y), wl = d.white_level(x, y), mod = d.ps_modulation(x, y);
      if (!std::isfinite(t) || !(wl > 0) || !(mod > 0)) continue;
      ++scored;
      const double b = mod * wl, mean = black(x, y) + 0.5 * wl;
      const double sigma_u = kPeriod / (2 * kPi) * std::sqrt(2.0 / kSteps) * noise.Sigma(mean) / b;
      const double u = scan.points.projector_u(x, y);
      if (std::isfinite(u) && scan.points.confidence(x, y) > 0) {
        const double e = u - t;
        if (std::abs(e) > kPeriod / 2) {
          ++jumps;
        } else {
          chi2 += (e / sigma_u) * (e / sigma_u);
          ++n;
        }
      }
      // Plain: order = floor(block / 2) of the half-period blocks, phase from u modulo P.
      if (std::isfinite(u) && std::isfinite(plain_blocks(x, y))) {
        const double order = std::floor(plain_blocks(x, y) / kPeriod);
        const double phase = u / kPeriod - std::floor(u / kPeriod);
        const double e = kPeriod * (order + phase) - t;
        if (std::abs(e) > kPeriod / 2) {
          ++jumps_plain;
        } else {
          chi2_plain += (e / sigma_u) * (e / sigma_u);
          ++n_plain;
        }
      }
    }
  const double chi = std::sqrt(chi2 / n), chi_plain = std::sqrt(chi2_plain / n_plain);
  std::printf(
      "sine + complementary Gray code: chi %.3f against the phase set's Cramer-Rao sigma "
      "on %lld of %lld lit pixels, %lld period jumps; plain decoder: chi %.3f, %lld "
      "period jumps\n",
      chi, static_cast<long long>(n), static_cast<long long>(scored), static_cast<long long>(jumps),
      chi_plain, static_cast<long long>(jumps_plain));
  ASSERT_GT(n, 10000);
  EXPECT_GE(static_cast<double>(n) / scored, 0.98);
  EXPECT_LE(chi, 1.10);
  EXPECT_EQ(jumps, 0);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace mesoscan
