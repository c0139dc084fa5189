// Reconstruction under the disturbances of real rigs, one test per row of a table of them, on
// the project's simulator (sim/virtual_rig.h) with ground truth. Figures are printed.

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>

#include "core/image_io.h"
#include "core/progress.h"
#include "core/test_temp_dir.h"
#include "heightfield/lens_shift_fit.h"
#include "heightfield/reconstruct.h"
#include "maps/export.h"
#include "session/session.h"
#include "sim/ground_truth.h"
#include "sim/virtual_rig.h"
#include "tests/plain_ls_decoder.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) { return TestTempPath("robust", name); }

// Simulates `so` into `dir` and reads the session back.
Session SimulateAndRead(const SimulateOptions& so, const fs::path& dir) {
  Simulate(so, dir);
  return ReadSession(dir);
}

struct Figures {
  GroundTruthErrors e;
  double crlb = 0;  // RMS Cramer-Rao depth floor over the scored pixels, m
  ReconstructSummary sum;
  Scan scan;
};

Figures RunCase(const Session& s, const SimulateOptions& so, const ReconstructOptions& ro_in = {}) {
  ReconstructOptions ro = ro_in;
  ro.keep_diagnostics = true;
  Figures f;
  f.scan = Reconstruct(s, ro, &f.sum);
  f.e = EvaluateAgainstGroundTruth(s, f.scan.points);
  const NoiseModel noise = MakeNoiseModel(so);
  f.crlb = LensShiftDepthCrlbRms(s, f.sum.diagnostics, f.e.error,
                                 [&](double m) { return noise.Sigma(m); });
  return f;
}

void Print(const char* label, const Figures& f) {
  std::printf(
      "%-34s RMS %.3f um, median |e| %.3f um, CRLB %.3f um (RMS/CRLB %.3f), coverage %.4f\n", label,
      f.e.rms_m * 1e6, f.e.median_abs_m * 1e6, f.crlb * 1e6, f.e.rms_m / f.crlb, f.e.coverage);
}

// Row 1 (and row 2, on this simulator): the coin with 15 lens-shift frames and strong ambient
// light, per-frame gain jitter 0 vs 0.02. Same seed: the same pixel noise, only the jitter differs.
SimulateOptions CoinJitter(double jitter) {
  SimulateOptions so;
  so.object = "coin";
  so.crop = PixelRect{1000, 600, 400, 300};
  so.ls_frames = 15;
  so.ambient = 0.15;
  so.gain_jitter = jitter;
  so.seed = 1;
  return so;
}

TEST(RobustReconstruct, GainJitterCostsAtMostFivePercent) {
  Progress::SetEnabled(false);
  const fs::path d0 = TempDir("coin_j0"), d1 = TempDir("coin_j2");
  const SimulateOptions s0 = CoinJitter(0.0), s1 = CoinJitter(0.02);
  const Session a = SimulateAndRead(s0, d0), b = SimulateAndRead(s1, d1);
  const Figures clean = RunCase(a, s0), jit = RunCase(b, s1);
  ReconstructOptions als;
  als.lens_shift.frame_gain_method = FrameGainMethod::kAlternating;
  ReconstructOptions means;
  means.lens_shift.frame_gain_method = FrameGainMethod::kFrameMeans;
  const Figures jit_als = RunCase(b, s1, als), jit_means = RunCase(b, s1, means);
  Print("coin, no jitter", clean);
  Print("coin, jitter 0.02 (joint)", jit);
  Print("coin, jitter 0.02 (als, before)", jit_als);
  Print("coin, jitter 0.02 (frame means)", jit_means);
  // True gains against the estimate (the simulator records them).
  const Json sim = ReadJsonFile(d1 / "session.json")["simulation"];
  std::printf("frame corrections: %s\n", jit.sum.frame_corrections.dump().c_str());
  // Gain error of the lens-shift frames (both normalised to mean 1 over those frames).
  auto gain_error = [&](const Figures& f) {
    std::vector<double> t, e;
    for (size_t k = 0; k < b.frames.size(); ++k)
      if (b.frames[k].pattern.type == PatternType::kStripes) {
        t.push_back(sim["frame_gains"][k].get<double>());
        e.push_back(f.sum.frame_gains[k]);
      }
    double mt = 0, me = 0;
    for (size_t k = 0; k < t.size(); ++k) {
      mt += t[k] / t.size();
      me += e[k] / t.size();
    }
    double s2 = 0;
    for (size_t k = 0; k < t.size(); ++k) s2 += std::pow(e[k] / me - t[k] / mt, 2);
    return std::sqrt(s2 / t.size());
  };
  std::printf("lens-shift frame gain error RMS: joint %.2e, als %.2e, means %.2e (jitter 2e-2)\n",
              gain_error(jit), gain_error(jit_als), gain_error(jit_means));
  EXPECT_GE(jit.e.coverage, clean.e.coverage - 0.002);
  EXPECT_LE(jit.e.rms_m, 1.05 * clean.e.rms_m);
  EXPECT_LE(jit.e.median_abs_m, 1.05 * clean.e.median_abs_m);

  // Row 2 on this simulator: pixels binned by their Cramer-Rao depth floor (sextiles of the
  // no-jitter floor); per bin, RMS error over RMS floor with and without the jitter.
  const NoiseModel n0 = MakeNoiseModel(s0), n1 = MakeNoiseModel(s1);
  const ImageF f0 = LensShiftDepthCrlbMap(a, clean.sum.diagnostics, clean.e.error,
                                          [&](double m) { return n0.Sigma(m); });
  const ImageF f1 = LensShiftDepthCrlbMap(b, jit.sum.diagnostics, jit.e.error,
                                          [&](double m) { return n1.Sigma(m); });
  const ImageF fa = LensShiftDepthCrlbMap(b, jit_als.sum.diagnostics, jit_als.e.error,
                                          [&](double m) { return n1.Sigma(m); });
  std::vector<float> floors;
  for (size_t i = 0; i < f0.data().size(); ++i)
    if (std::isfinite(f0.data()[i]) && std::isfinite(f1.data()[i])) floors.push_back(f0.data()[i]);
  ASSERT_GT(floors.size(), 6000u);
  std::sort(floors.begin(), floors.end());
  constexpr int kBins = 6;
  std::vector<float> edges;
  for (int k = 0; k <= kBins; ++k)
    edges.push_back(floors[std::min(floors.size() - 1, k * floors.size() / kBins)]);
  edges.back() = std::numeric_limits<float>::infinity();
  for (int k = 0; k < kBins; ++k) {
    double e2[3] = {0, 0, 0}, c2[3] = {0, 0, 0};
    int64_t n = 0;
    for (size_t i = 0; i < f0.data().size(); ++i) {
      const float fl = f0.data()[i];
      if (!(fl >= edges[k] && fl < edges[k + 1]) || !std::isfinite(f1.data()[i])) continue;
      e2[0] += std::pow(clean.e.error.data()[i], 2);
      e2[1] += std::pow(jit.e.error.data()[i], 2);
      c2[0] += std::pow(fl, 2);
      c2[1] += std::pow(f1.data()[i], 2);
      if (std::isfinite(fa.data()[i])) {  // the alternating gains (before), where they kept it
        e2[2] += std::pow(jit_als.e.error.data()[i], 2);
        c2[2] += std::pow(fa.data()[i], 2);
      }
      ++n;
    }
    const double r0 = std::sqrt(e2[0] / c2[0]), r1 = std::sqrt(e2[1] / c2[1]);
    std::printf(
        "floor bin %d [%.3f, %.3f) um, %lld px: RMS/floor no jitter %.3f, jitter 0.02 "
        "%.3f (x%.3f; alternating gains, before: %.3f)\n",
        k, edges[k] * 1e6, edges[k + 1] * 1e6, static_cast<long long>(n), r0, r1, r1 / r0,
        std::sqrt(e2[2] / c2[2]));
    // Target 1.05x; the measured 1.016-1.024x is ~5 standard errors of a bin's RMS (1/sqrt(2n),
    // n ~ 2e4) below it. Also at the floor in absolute terms (the tilted-plane test's 1.15).
    EXPECT_LE(r1, 1.05 * r0) << "bin " << k;
    EXPECT_LE(r1, 1.15) << "bin " << k;
  }
  fs::remove_all(d0);
  fs::remove_all(d1);
}

// Row 3: the low-contrast leaf. The default pipeline's error is at or below
// the plain fixed-frequency linear least-squares decoder's (tests/plain_ls_decoder.h) on the same
// frames and the same pixels.
TEST(RobustReconstruct, NoWorseThanThePlainDecoderOnTheLowContrastLeaf) {
  Progress::SetEnabled(false);
  SimulateOptions so;
  so.object = "leaf";
  so.crop = PixelRect{900, 600, 384, 288};
  so.blur_sigma_px = 0.7;
  const fs::path dir = TempDir("leaf");
  const Session s = SimulateAndRead(so, dir);
  Figures f = RunCase(s, so);
  {  // the older estimate: alternating least squares gains (on the same pixels as below)
    ReconstructOptions als;
    als.lens_shift.frame_gain_method = FrameGainMethod::kAlternating;
    Figures b = RunCase(s, so, als);
    ScanPoints plain_b = testing::PlainLsDecode(s, b.scan.points.projector_u);
    testing::IntersectPoints(&b.scan.points, &plain_b);
    std::printf("leaf, als gains (before): pipeline RMS %.3f um, plain LS %.3f um\n",
                EvaluateAgainstGroundTruth(s, b.scan.points).rms_m * 1e6,
                EvaluateAgainstGroundTruth(s, plain_b).rms_m * 1e6);
  }
  ScanPoints plain = testing::PlainLsDecode(s, f.scan.points.projector_u);
  testing::IntersectPoints(&f.scan.points, &plain);
  const GroundTruthErrors ep = EvaluateAgainstGroundTruth(s, f.scan.points);
  const GroundTruthErrors eq = EvaluateAgainstGroundTruth(s, plain);
  std::printf(
      "leaf (blur 0.7), same %lld pixels: pipeline RMS %.3f um, plain LS %.3f um; "
      "CRLB %.3f um\n",
      static_cast<long long>(ep.pixels_both), ep.rms_m * 1e6, eq.rms_m * 1e6, f.crlb * 1e6);
  EXPECT_GT(ep.pixels_both, 50000);
  EXPECT_LE(ep.rms_m, eq.rms_m);
  fs::remove_all(dir);
}

// Row 4: the tilted plane 1.6-3.3 mm above the focus plane (focus on the mount,
// as before the simulator focused at the object's mid height). Where the 2-px stripes are blurred
// away, phase shifting decides (source 1), with its own predicted sigma and a lower confidence.
TEST(RobustReconstruct, DefocusedPlaneFallsBackToPhaseShifting) {
  Progress::SetEnabled(false);
  SimulateOptions so;
  so.object = "plane";
  so.crop = PixelRect{960, 620, 256, 192};
  so.focus_height_m = 0.0;
  const fs::path dir = TempDir("plane_defocus");
  const Session s = SimulateAndRead(so, dir);
  ReconstructOptions off;
  off.combine.phase_shift_fallback = false;
  const Figures before = RunCase(s, so, off), f = RunCase(s, so);
  Print("defocused plane, no fallback", before);
  Print("defocused plane, fallback", f);
  const ReconstructDiagnostics& d = f.sum.diagnostics;
  double s2[2] = {0, 0}, c_max[2] = {0, 0}, c_min[2] = {1, 1};
  int64_t n[2] = {0, 0};
  for (int y = 0; y < d.u.height(); ++y)
    for (int x = 0; x < d.u.width(); ++x) {
      const float e = f.e.error(x, y), src = f.scan.points.source(x, y);
      const float conf = f.scan.points.confidence(x, y);
      if (conf > 0) {
        ASSERT_TRUE(src == 0.0f || src == 1.0f) << x << "," << y;
      } else {
        ASSERT_TRUE(std::isnan(src));
      }
      if (!std::isfinite(e) || !(conf > 0)) continue;
      const int k = static_cast<int>(src);
      const double sz = d.sigma_u(x, y) * std::abs(d.dz_du(x, y));
      ASSERT_TRUE(sz > 0) << x << "," << y;
      s2[k] += (e / sz) * (e / sz);
      ++n[k];
      c_max[k] = std::max<double>(c_max[k], conf);
      c_min[k] = std::min<double>(c_min[k], conf);
    }
  const double r_ls = n[0] ? std::sqrt(s2[0] / n[0]) : 0, r_ps = n[1] ? std::sqrt(s2[1] / n[1]) : 0;
  std::printf(
      "lens-shift pixels %lld (RMS error / predicted sigma %.3f, confidence %.2f-%.2f); "
      "phase-shift pixels %lld (%.3f, confidence %.2f-%.2f)\n",
      static_cast<long long>(n[0]), r_ls, c_min[0], c_max[0], static_cast<long long>(n[1]), r_ps,
      c_min[1], c_max[1]);
  EXPECT_GE(f.e.coverage, 0.99);
  EXPECT_GT(n[1], 1000);  // the fallback is exercised
  EXPECT_LE(r_ps, 1.2);
  EXPECT_LE(c_max[1], 0.5);
  fs::remove_all(dir);
}

// The simulator focuses at the object's mid height unless told otherwise.
TEST(RobustReconstruct, SimulatorFocusesAtTheObjectsMidHeight) {
  Progress::SetEnabled(false);
  SimulateOptions so;
  so.object = "plane";
  so.crop = PixelRect{960, 620, 16, 12};
  so.ls_frames = 0;
  const fs::path dir = TempDir("plane_focus");
  Simulate(so, dir);
  const Json sim = ReadJsonFile(dir / "session.json")["simulation"];
  const double focus = sim["projector"]["focus_height_m"].get<double>();
  std::printf("plane: focus at %.4f mm\n", focus * 1e3);
  EXPECT_GT(focus, 0.5e-3);
  so.focus_height_m = 0.0;
  Simulate(so, dir);
  EXPECT_EQ(
      ReadJsonFile(dir / "session.json")["simulation"]["projector"]["focus_height_m"].get<double>(),
      0.0);
  fs::remove_all(dir);
}

// Per-frame lens-shifter position errors of 0.02 px RMS cost at most 5% of the
// depth error of the error-free session once the positions are estimated jointly; the estimate
// matches the simulator's errors up to an affine map.
TEST(RobustReconstruct, ShifterPositionErrorsWithinFivePercent) {
  Progress::SetEnabled(false);
  SimulateOptions s0 = CoinJitter(0.005);
  s0.ls_frames = 50;
  s0.ambient = 0.03;
  SimulateOptions s1 = s0;
  s1.shift_position_error_px = 0.02;
  const fs::path d0 = TempDir("coin_p0"), d1 = TempDir("coin_p2");
  const Session a = SimulateAndRead(s0, d0), b = SimulateAndRead(s1, d1);
  ReconstructOptions nopos;
  nopos.lens_shift.correct_positions = false;
  const Figures clean = RunCase(a, s0), corrected = RunCase(b, s1),
                uncorrected = RunCase(b, s1, nopos);
  Print("coin, exact positions", clean);
  Print("coin, 0.02 px errors, estimated", corrected);
  Print("coin, 0.02 px errors, nominal", uncorrected);
  // Estimated positions against the truth with its affine part removed (shift order = frame order
  // of the stripes frames, which the simulator writes by ascending shift).
  const Json sim = ReadJsonFile(d1 / "session.json")["simulation"];
  std::vector<std::pair<double, double>> by_shift;  // the pipeline's order: ascending shift
  for (size_t f = 0; f < b.frames.size(); ++f)
    if (b.frames[f].pattern.type == PatternType::kStripes)
      by_shift.emplace_back(b.frames[f].shift_steps / b.rig.lens_shifter->steps_per_px,
                            sim["shift_position_errors_px"][f].get<double>());
  std::sort(by_shift.begin(), by_shift.end());
  std::vector<double> truth, x;
  for (const auto& [xs, t] : by_shift) {
    x.push_back(xs);
    truth.push_back(t);
  }
  const Json& fc = corrected.sum.frame_corrections;
  ASSERT_TRUE(fc.is_object());
  ASSERT_TRUE(fc["valid"].get<bool>());
  const std::vector<double> est = fc["positions_px"].get<std::vector<double>>();
  ASSERT_EQ(est.size(), truth.size());
  {
    const double nk = static_cast<double>(x.size());
    double sx = 0, sxx = 0, sd = 0, sxd = 0;
    for (size_t k = 0; k < x.size(); ++k) {
      sx += x[k];
      sxx += x[k] * x[k];
      sd += truth[k];
      sxd += x[k] * truth[k];
    }
    const double bb = (nk * sxd - sx * sd) / (nk * sxx - sx * sx), aa = (sd - bb * sx) / nk;
    double e2 = 0, t2 = 0;
    for (size_t k = 0; k < x.size(); ++k) {
      const double t = truth[k] - aa - bb * x[k];
      e2 += (est[k] - t) * (est[k] - t);
      t2 += t * t;
    }
    std::printf("positions: truth (affine-free) RMS %.4f px, estimate error RMS %.4f px\n",
                std::sqrt(t2 / nk), std::sqrt(e2 / nk));
    EXPECT_LT(std::sqrt(e2 / nk), 0.25 * std::sqrt(t2 / nk));
    // The affine map's constant (the frames' mean position error at the centre of the range)
    // comes from the phase-shift frames at shift 0.
    const double mid = 0.5 * (x.front() + x.back());
    const double offset = fc["phase_shift_offset_px"].get<double>();
    std::printf("positions: constant at the range centre %.5f px, from phase shifting %.5f px\n",
                aa + bb * mid, offset);
    EXPECT_NEAR(offset, aa + bb * mid, 0.0015);
  }
  EXPECT_LE(corrected.e.rms_m, 1.05 * clean.e.rms_m);
  EXPECT_GE(corrected.e.coverage, clean.e.coverage - 0.002);
  fs::remove_all(d0);
  fs::remove_all(d1);
}

// Very low signal (the stress test's coin without its saturation: 8 bits, exposure 0.08, blur
// 1 px, shifter position errors 0.02 px): where the periods' phases are mostly noise the
// unwrapping guesses a fringe order, wrong by centimetres, and the guesses do not join their
// neighbours (RejectIsolatedColumns). Without frame brightness jitter, at ambient 10, 3 and 1,
// and with 2% jitter at ambient 1: the points left with confidence > 0 are right (|error| <=
// 1 mm) but for at most one in a thousand, where the same reconstruction without the check
// keeps 5-25 wrong ones, and no right point is lost (more are kept: the mixed-pixel test no longer
// rejects right points beside wrong ones). Not asserted, printed: with 2% jitter at ambient 3 and
// 10 the wrong orders are the same over whole regions (the frames' common gain errors dominate
// the phases), which no neighbourhood test can see. The consistency stage now stands before this
// check: a session it refuses (its phases contradict each other at most pixels) keeps no point,
// and in every case here no point is kept more than 1 mm off.
TEST(RobustReconstruct, LowSignalGuessedFringeOrdersAreRejected) {
  Progress::SetEnabled(false);
  struct Case {
    double ambient, jitter;
    bool asserted;
  };
  for (const Case& k : {Case{10, 0, true}, Case{3, 0, true}, Case{1, 0, true}, Case{1, 0.02, true},
                        Case{3, 0.02, false}, Case{10, 0.02, false}}) {
    SimulateOptions so;
    so.object = "coin";
    so.colour = false;  // frames rewritten as grey below
    so.crop = PixelRect{1100, 650, 160, 120};
    so.adc_bits = 8;
    so.ambient = k.ambient;
    so.exposure = 0.08;
    so.blur_sigma_px = 1.0;
    so.gain_jitter = k.jitter;
    so.shift_position_error_px = 0.02;
    so.seed = 3;
    const fs::path dir = TempDir("low_signal");
    Simulate(so, dir);
    const Session s = ReadSession(dir);
    int64_t wrong[2] = {0, 0}, right[2] = {0, 0}, isolated = 0;
    for (int on = 0; on < 2; ++on) {
      ReconstructOptions ro;
      if (!on) ro.combine.isolated_max_region_px = 0;
      ReconstructSummary sum;
      Scan scan;
      try {
        scan = Reconstruct(s, ro, &sum);
      } catch (const Error& e) {
        std::printf("low signal, ambient %.0f, jitter %.2f, isolated check %s: refused (%s)\n",
                    k.ambient, k.jitter, on ? "on" : "off", e.what());
        continue;
      }
      if (on) isolated = sum.pixels_rejected_isolated;
      const GroundTruthErrors e = EvaluateAgainstGroundTruth(s, scan.points);
      for (int y = 0; y < e.error.height(); ++y)
        for (int x = 0; x < e.error.width(); ++x) {
          const float c = scan.points.confidence(x, y);
          ASSERT_FALSE(std::isnan(c));
          if (!(c > 0)) continue;
          const float err = e.error(x, y);
          if (std::isfinite(err) && std::abs(err) <= 1e-3)
            ++right[on];
          else
            ++wrong[on];
        }
    }
    std::printf(
        "low signal, ambient %.0f, jitter %.2f: points wrong by > 1 mm %lld -> %lld, "
        "right %lld -> %lld, rejected as isolated %lld%s\n",
        k.ambient, k.jitter, static_cast<long long>(wrong[0]), static_cast<long long>(wrong[1]),
        static_cast<long long>(right[0]), static_cast<long long>(right[1]),
        static_cast<long long>(isolated), k.asserted ? "" : " (not asserted)");
    EXPECT_EQ(wrong[1], 0) << "ambient " << k.ambient << ", jitter " << k.jitter;
    if (k.asserted) {
      EXPECT_LE(wrong[1], right[1] / 1000) << "ambient " << k.ambient << ", jitter " << k.jitter;
      EXPECT_GE(right[1], right[0]) << "ambient " << k.ambient << ", jitter " << k.jitter;
    }
    fs::remove_all(dir);
  }
}

// Stress: 8-bit frames, weak stripes (ambient light as bright as the projector, blur), saturation
// in 10% of the frames, gain jitter and shifter position errors: no NaN where confidence > 0,
// finite frame corrections. (At exposure 0.08 and ambient 10, as this test had it, no point is
// kept: the points such a session gave were centimetres off; tests/consistency_sweep_test.)
TEST(RobustReconstruct, StressEightBitLowAmplitudeSaturation) {
  Progress::SetEnabled(false);
  SimulateOptions so;
  so.object = "coin";
  so.colour = false;  // frames rewritten as grey below
  so.crop = PixelRect{1100, 650, 160, 120};
  so.adc_bits = 8;
  so.ambient = 1.0;
  so.exposure = 0.4;
  so.blur_sigma_px = 1.0;
  so.gain_jitter = 0.02;
  so.shift_position_error_px = 0.02;
  so.seed = 3;
  const fs::path dir = TempDir("stress");
  Simulate(so, dir);
  Session s = ReadSession(dir);
  // Saturate a block and a sprinkle of pixels in every tenth frame.
  int saturated_frames = 0;
  for (size_t f = 0; f < s.frames.size(); f += 10) {
    const fs::path file = dir / s.frames[f].file;
    const ImageF im = ReadImage(file);
    ImageU16 out(im.width(), im.height(), 1);
    for (int y = 0; y < im.height(); ++y)
      for (int x = 0; x < im.width(); ++x) {
        const bool sat = (x >= 40 && x < 80 && y >= 30 && y < 70) || (x * 7 + y * 13) % 97 == 0;
        out(x, y) = sat ? 65535 : static_cast<uint16_t>(std::lround(im(x, y) * 65535.0));
      }
    WritePng16(file, out);
    ++saturated_frames;
  }
  s = ReadSession(dir);
  ReconstructOptions ro;
  ro.keep_diagnostics = true;
  ReconstructSummary sum;
  const Scan scan = Reconstruct(s, ro, &sum);
  // Stripe amplitude relative to white, median over the fitted pixels.
  std::vector<float> rel;
  const ReconstructDiagnostics& d = sum.diagnostics;
  for (int y = 0; y < d.ls_amplitude.height(); ++y)
    for (int x = 0; x < d.ls_amplitude.width(); ++x)
      if (std::isfinite(d.ls_amplitude(x, y)) && d.white_level(x, y) > 0)
        rel.push_back(d.ls_amplitude(x, y) / d.white_level(x, y));
  std::sort(rel.begin(), rel.end());
  const double med = rel.empty() ? 0 : rel[rel.size() / 2];
  std::printf(
      "stress: %d frames saturated, stripe amplitude / white median %.4f (p10 %.4f), "
      "%lld points, %lld saturated pixels, frame corrections %s\n",
      saturated_frames, med, rel.empty() ? 0.0 : rel[rel.size() / 10],
      static_cast<long long>(sum.pixels_valid), static_cast<long long>(sum.pixels_saturated),
      sum.frame_corrections.dump().c_str());
  // Note: the stripes' amplitude is ~2% of white here (printed above); the 0.5% level is
  // exercised by frame_corrections_test and lens_shift_fit_test, not by this session.
  EXPECT_GT(sum.pixels_saturated, 1000);
  int64_t bad = 0, valid = 0;
  for (int y = 0; y < scan.points.confidence.height(); ++y)
    for (int x = 0; x < scan.points.confidence.width(); ++x) {
      const float c = scan.points.confidence(x, y);
      ASSERT_FALSE(std::isnan(c));
      if (!(c > 0)) continue;
      ++valid;
      bad += !std::isfinite(scan.points.xyz(x, y, 0)) || !std::isfinite(scan.points.xyz(x, y, 1)) ||
             !std::isfinite(scan.points.xyz(x, y, 2)) || !std::isfinite(scan.points.source(x, y)) ||
             !std::isfinite(scan.points.projector_u(x, y));
    }
  EXPECT_EQ(bad, 0);
  EXPECT_GT(valid, 0);
  for (double g : sum.frame_gains) EXPECT_TRUE(std::isfinite(g) && g > 0);
  for (float z : scan.height.z.data()) EXPECT_FALSE(std::isinf(z));
  fs::remove_all(dir);
}

// Row 5: another scanner's pattern set, 3 phases of 16 periods across the
// projector plus 3 phases of a one-period cue as wide as the projector: reconstructs (the
// unwrapper marks the ambiguous edge columns instead of refusing the session).
TEST(RobustReconstruct, CuePeriodEqualToTheProjectorWidth) {
  Progress::SetEnabled(false);
  SimulateOptions so;
  so.object = "plane";
  so.crop = PixelRect{960, 620, 128, 96};
  const double width = ResolveRig(so).projector.width;
  so.ps_periods_px = {width / 16, width};
  so.ps_phases = 3;
  const fs::path dir = TempDir("cue_width");
  const Session s = SimulateAndRead(so, dir);
  const Figures f = RunCase(s, so);
  Print("plane, cue = projector width", f);
  EXPECT_GE(f.e.coverage, 0.95);
  fs::remove_all(dir);
}

// ---- Row 5 and the rest: horizontal fringes, k1-only distortion, no white/black ----

// The tilted bar near the projector's focus (as tests/reconstruct_sim_test's CRLB test), with the
// fringes along `axis` (axis 'y': the paper rig's projector in portrait, shifter along y).
SimulateOptions BarOptions(char axis, int w = 160, int h = 120) {
  SimulateOptions o;
  o.object = "plane";
  const int cx = static_cast<int>(std::lround(1087.5 - 17e-3 / 55e-6));
  o.crop = PixelRect{cx - w / 2, 717 - h / 2, w, h};
  o.seed = 11;
  o.focus_height_m = 0.0;
  o.axis = axis;
  return o;
}

// The tilted bar w x h, LS 50 + PS 9, seed 21, simulated with gain jitter 0 (s0, a) and 0.02
// (s1, b): the same pixel noise, so the pair isolates the jitter. Its folders go with it.
struct BarJitterPair {
  BarJitterPair(const std::string& name, int w, int h)
      : s0(Options(w, h, 0.0)),
        s1(Options(w, h, 0.02)),
        d0(TempDir(name + "_j0")),
        d1(TempDir(name + "_j2")),
        a(SimulateAndRead(s0, d0)),
        b(SimulateAndRead(s1, d1)) {}
  ~BarJitterPair() {
    std::error_code ec;
    fs::remove_all(d0, ec);
    fs::remove_all(d1, ec);
  }
  static SimulateOptions Options(int w, int h, double jitter) {
    SimulateOptions so = BarOptions('x', w, h);
    so.seed = 21;
    so.ps_phases = 3;
    so.ls_frames = 50;
    so.gain_jitter = jitter;
    return so;
  }
  SimulateOptions s0, s1;
  fs::path d0, d1;
  Session a, b;
};

// Writes `rig` as a rig file (a JSON object with "rig", as `simulate --rig` reads).
fs::path WriteRig(const Rig& rig, const fs::path& file) {
  Session s;
  s.rig = rig;
  Json j;
  j["rig"] = SessionToJson(s)["rig"];
  fs::create_directories(file.parent_path());
  std::ofstream(file) << j.dump(2);
  return file;
}

// Plain baseline on the same pixels: the pipeline's RMS and the plain LS decoder's.
std::pair<double, double> AgainstPlain(const Session& s, Figures f) {
  ScanPoints plain = testing::PlainLsDecode(s, f.scan.points.projector_u);
  testing::IntersectPoints(&f.scan.points, &plain);
  return {EvaluateAgainstGroundTruth(s, f.scan.points).rms_m,
          EvaluateAgainstGroundTruth(s, plain).rms_m};
}

// Horizontal fringes: the same bar with sines and stripes along the projector's y axis
// reconstructs from projector rows at the same distance to the Cramer-Rao floor as the x-axis
// session (tolerance of the x-axis test, reconstruct_sim_test: RMS <= 1.15 CRLB), and no worse
// than the plain decoder. A calibration-style session holding both axes' sines reconstructs from
// the lens shifter's axis, with the same result as the y-only session.
TEST(RobustReconstruct, HorizontalFringesAtTheNoiseFloor) {
  Progress::SetEnabled(false);
  const SimulateOptions sx = BarOptions('x'), sy = BarOptions('y');
  const fs::path dx = TempDir("bar_x"), dy = TempDir("bar_y");
  const Session a = SimulateAndRead(sx, dx), b = SimulateAndRead(sy, dy);
  ASSERT_EQ(b.rig.lens_shifter->axis, 'y');
  for (const Frame& f : b.frames) {
    if (f.pattern.type == PatternType::kSine || f.pattern.type == PatternType::kStripes) {
      ASSERT_EQ(f.pattern.axis, 'y');
    }
  }
  const Figures fx = RunCase(a, sx), fy = RunCase(b, sy);
  Print("bar, vertical fringes (x)", fx);
  Print("bar, horizontal fringes (y)", fy);
  const auto [py, qy] = AgainstPlain(b, fy);
  std::printf("bar (y), same pixels: pipeline RMS %.3f um, plain LS %.3f um\n", py * 1e6, qy * 1e6);
  EXPECT_EQ(fx.sum.axis, "x");
  EXPECT_EQ(fy.sum.axis, "y");
  EXPECT_GE(fy.e.coverage, 0.99);
  EXPECT_LE(fy.e.rms_m, 1.15 * fy.crlb);
  EXPECT_LE(fy.e.rms_m / fy.crlb, 1.05 * fx.e.rms_m / fx.crlb);
  EXPECT_LE(py, qy);
  // Calibration style: x-axis sines of the same rig added to the y session.
  const fs::path dxs = TempDir("bar_xs"), dboth = TempDir("bar_both");
  SimulateOptions sxs = sy;
  sxs.axis = 'x';
  sxs.ls_frames = 0;
  sxs.white = sxs.black = false;
  sxs.rig = WriteRig(PortraitProjector(PaperRig()), TempDir("rig") / "portrait.json").string();
  Simulate(sxs, dxs);
  fs::copy(dy, dboth, fs::copy_options::recursive);
  Session both = ReadSession(dboth);
  const Session xs = ReadSession(dxs);
  for (const Frame& f : xs.frames) {
    Frame g = f;
    g.file = "frames/x_" + fs::path(f.file).filename().string();
    fs::copy_file(dxs / f.file, dboth / g.file);
    both.frames.push_back(g);
  }
  WriteSessionJson(both);
  both = ReadSession(dboth);
  const Figures fb = RunCase(both, sy);
  Print("bar, both axes' sines (shifter y)", fb);
  EXPECT_EQ(fb.sum.axis, "y");
  EXPECT_EQ(fb.sum.phase_shift_frames, fy.sum.phase_shift_frames);
  EXPECT_DOUBLE_EQ(fb.e.rms_m, fy.e.rms_m);
  for (const fs::path& d : {dx, dy, dxs, dboth, TempDir("rig")}) fs::remove_all(d);
}

// Camera and projector distortion with k1 only (as many real calibrations give): the bar stays at
// the floor, and the same frames reconstructed with the distortion dropped from the rig are
// clearly worse (the distortion matters here, so the first check can fail).
TEST(RobustReconstruct, RadialK1OnlyDistortion) {
  Progress::SetEnabled(false);
  Rig rig = PaperRig();
  rig.camera.distortion = {-0.12, 0, 0, 0, 0};
  rig.projector.distortion = {0.06, 0, 0, 0, 0};
  SimulateOptions so = BarOptions('x');
  so.rig = WriteRig(rig, TempDir("rig_k1") / "k1.json").string();
  const fs::path dir = TempDir("bar_k1");
  Simulate(so, dir);
  Session s = ReadSession(dir);
  const Figures f = RunCase(s, so);
  Print("bar, k1-only distortion", f);
  const auto [p, q] = AgainstPlain(s, f);
  std::printf("bar (k1), same pixels: pipeline RMS %.3f um, plain LS %.3f um\n", p * 1e6, q * 1e6);
  EXPECT_GE(f.e.coverage, 0.99);
  EXPECT_LE(f.e.rms_m, 1.15 * f.crlb);
  EXPECT_LE(p, q);
  s.rig.camera.distortion = {};
  s.rig.projector.distortion = {};
  const Figures g = RunCase(s, so);
  Print("bar, k1 ignored", g);
  EXPECT_GT(g.e.rms_m, 3 * f.e.rms_m);
  fs::remove_all(dir);
  fs::remove_all(TempDir("rig_k1"));
}

// No white and no black frame (other scanners' sets): the pipeline reconstructs from the sines
// and stripes alone at the floor, and the export's albedo comes from a phase set's mean, matching
// the white-frame albedo of the same scene.
TEST(RobustReconstruct, NoWhiteNoBlackFrame) {
  Progress::SetEnabled(false);
  SimulateOptions with = BarOptions('x');
  with.object = "leaf";  // textured albedo
  with.crop = PixelRect{1000, 650, 160, 120};
  with.focus_height_m = std::numeric_limits<double>::quiet_NaN();
  SimulateOptions without = with;
  without.white = without.black = false;
  const fs::path dw = TempDir("leaf_white"), dn = TempDir("leaf_nowhite");
  const Session a = SimulateAndRead(with, dw), b = SimulateAndRead(without, dn);
  const Figures fw = RunCase(a, with), fn = RunCase(b, without);
  Print("leaf, white + black", fw);
  Print("leaf, no white, no black", fn);
  EXPECT_GE(fn.e.coverage, fw.e.coverage - 0.01);
  EXPECT_LE(fn.e.rms_m, 1.05 * fw.e.rms_m);
  EXPECT_LE(fn.e.rms_m, 1.15 * fn.crlb);
  std::string src_w, src_n;
  const ImageF aw = AlbedoFromSession(fw.scan.height, dw, &src_w);
  const ImageF an = AlbedoFromSession(fw.scan.height, dn, &src_n);
  std::printf("albedo: '%s' vs '%s'\n", src_w.c_str(), src_n.c_str());
  EXPECT_NE(src_n.find("no white frame"), std::string::npos);
  // Both relative: compare after normalising by their medians.
  std::vector<double> ra, rb;
  for (size_t i = 0; i < aw.data().size(); ++i)
    if (std::isfinite(aw.data()[i]) && std::isfinite(an.data()[i]) && aw.data()[i] > 0) {
      ra.push_back(aw.data()[i]);
      rb.push_back(an.data()[i]);
    }
  ASSERT_GT(ra.size(), 1000u);
  auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  };
  const double ma = median(ra), mb = median(rb);
  std::vector<double> rel, spread;
  for (size_t i = 0; i < ra.size(); ++i) {
    rel.push_back(std::abs(rb[i] / mb - ra[i] / ma) / (ra[i] / ma));
    spread.push_back(std::abs(ra[i] / ma - 1));
  }
  const double med_rel = median(rel), med_spread = median(spread);
  std::printf("albedo: median relative difference %.4f; the albedo's own median spread %.4f\n",
              med_rel, med_spread);
  EXPECT_LT(med_rel, 0.02);
  EXPECT_GT(med_spread, 3 * med_rel);  // the texture is there, not a flat match
  fs::remove_all(dw);
  fs::remove_all(dn);
}

// Stress with weak stripes: 8-bit frames, stripe amplitude (relative to white - black) from ~2%
// down to 0.5% (projector blur; the amplitude is measured on a noise-free 16-bit twin of each
// session), saturation in 10% of the frames, gain jitter 0.02 with the frame gains estimated. No
// NaN where confidence > 0, and where a pixel claims confidence its error matches its predicted
// sigma: RMS(error / sigma) within 1.3 per deciding cue (the honest value is 1.0).
TEST(RobustReconstruct, WeakStripesConfidenceIsHonest) {
  Progress::SetEnabled(false);
  double lowest_amplitude = 1;
  for (const double blur : {0.6, 0.75, 0.95}) {
    SimulateOptions so = BarOptions('x');
    so.adc_bits = 8;
    so.ambient = 0.15;
    so.gain_jitter = 0.02;
    so.blur_sigma_px = blur;
    so.seed = 5;
    const fs::path dir = TempDir("weak");
    double amplitude = 0;  // median stripe amplitude / (white - black), noise-free twin
    {
      SimulateOptions clean = so;
      clean.noise = 0;
      clean.adc_bits = 16;
      Simulate(clean, dir);
      const Figures t = RunCase(ReadSession(dir), clean);
      std::vector<float> rel;
      const ReconstructDiagnostics& d = t.sum.diagnostics;
      for (int y = 0; y < d.ls_amplitude.height(); ++y)
        for (int x = 0; x < d.ls_amplitude.width(); ++x)
          if (std::isfinite(d.ls_amplitude(x, y)) && d.white_level(x, y) > 0)
            rel.push_back(d.ls_amplitude(x, y) / d.white_level(x, y));
      ASSERT_GT(rel.size(), 1000u);
      std::nth_element(rel.begin(), rel.begin() + rel.size() / 2, rel.end());
      amplitude = rel[rel.size() / 2];
      lowest_amplitude = std::min(lowest_amplitude, amplitude);
    }
    Simulate(so, dir);
    Session s = ReadSession(dir);
    for (size_t f = 0; f < s.frames.size(); f += 10) {  // saturate a block in every tenth frame
      const fs::path file = dir / s.frames[f].file;
      const ImageF im = ReadImage(file);
      ImageU16 out(im.width(), im.height(), 1);
      for (int y = 0; y < im.height(); ++y)
        for (int x = 0; x < im.width(); ++x) {
          const bool sat = x >= 40 && x < 70 && y >= 30 && y < 60;
          out(x, y) = sat ? 65535 : static_cast<uint16_t>(std::lround(im(x, y) * 65535.0));
        }
      WritePng16(file, out);
    }
    s = ReadSession(dir);
    const Figures f = RunCase(s, so);
    const ReconstructDiagnostics& d = f.sum.diagnostics;
    int64_t bad = 0, n[2] = {0, 0};
    double s2[2] = {0, 0};
    for (int y = 0; y < f.scan.points.confidence.height(); ++y)
      for (int x = 0; x < f.scan.points.confidence.width(); ++x) {
        const float c = f.scan.points.confidence(x, y);
        ASSERT_FALSE(std::isnan(c));
        if (!(c > 0)) continue;
        bad += !std::isfinite(f.scan.points.xyz(x, y, 2)) ||
               !std::isfinite(f.scan.points.source(x, y)) || !std::isfinite(d.sigma_u(x, y));
        const float e = f.e.error(x, y);
        if (!std::isfinite(e)) continue;
        const double sz = d.sigma_u(x, y) * std::abs(d.dz_du(x, y));
        const int k = f.scan.points.source(x, y) == 0.0f ? 0 : 1;
        s2[k] += (e / sz) * (e / sz);
        ++n[k];
      }
    const double r0 = n[0] ? std::sqrt(s2[0] / n[0]) : 0, r1 = n[1] ? std::sqrt(s2[1] / n[1]) : 0;
    // Phase shifting alone on the same frames and pixels: the lens shift may decide only where it
    // helps, so the combination is not worse.
    ReconstructOptions ps_only;
    ps_only.plan.use_lens_shift = false;
    Figures p = RunCase(s, so, ps_only), q = f;
    testing::IntersectPoints(&q.scan.points, &p.scan.points);
    const double rms_q = EvaluateAgainstGroundTruth(s, q.scan.points).rms_m;
    const double rms_p = EvaluateAgainstGroundTruth(s, p.scan.points).rms_m;
    std::printf(
        "weak stripes, blur %.2f, same pixels: pipeline %.3f um, phase shifting alone "
        "%.3f um\n",
        blur, rms_q * 1e6, rms_p * 1e6);
    EXPECT_LE(rms_q, 1.02 * rms_p) << "blur " << blur;
    std::printf(
        "weak stripes, blur %.2f: amplitude/white %.4f (noise-free); coverage %.4f; "
        "lens-shift pixels %lld (RMS e/sigma %.3f), phase-shift pixels %lld (%.3f); RMS "
        "%.3f um\n",
        blur, amplitude, f.e.coverage, static_cast<long long>(n[0]), r0,
        static_cast<long long>(n[1]), r1, f.e.rms_m * 1e6);
    EXPECT_EQ(bad, 0);
    EXPECT_GT(f.sum.pixels_saturated, 500);
    EXPECT_GE(f.e.coverage, 0.9);
    if (n[0] > 100) {
      EXPECT_LE(r0, 1.3) << "blur " << blur;
    }
    if (n[1] > 100) {
      EXPECT_LE(r1, 1.3) << "blur " << blur;
    }
    for (double g : f.sum.frame_gains) EXPECT_TRUE(std::isfinite(g) && g > 0);
    fs::remove_all(dir);
  }
  EXPECT_LE(lowest_amplitude, 0.006);  // the sweep reaches 0.5% of white
}

// Row 1 on a small view (bench_reconstruct's Table-1 disturbance rows): the tilted bar 128x96,
// LS 50 + PS 9, gain jitter 0 vs 0.02 (same seed: the same pixel noise). Its stripes do not
// average out over the view (residual stripe ~2.6e-3 of the mean level), so frame means are
// biased and the alternating gains leave the in-band jitter: before the phase-shift reference,
// 1.864 um (alternating), 1.246 um (frame means) against 1.170 um without jitter and 1.315 um
// for the plain decoder.
TEST(RobustReconstruct, GainJitterOnASmallViewOfTheTiltedBar) {
  Progress::SetEnabled(false);
  const BarJitterPair pair("bar", 128, 96);
  const SimulateOptions &s0 = pair.s0, &s1 = pair.s1;
  const Session &a = pair.a, &b = pair.b;
  const Figures clean = RunCase(a, s0), jit = RunCase(b, s1);
  ReconstructOptions means;
  means.lens_shift.frame_gain_method = FrameGainMethod::kFrameMeans;
  const Figures jit_means = RunCase(b, s1, means);
  Print("bar 128x96, no jitter", clean);
  Print("bar 128x96, jitter 0.02", jit);
  Print("bar 128x96, jitter 0.02 (means)", jit_means);
  const auto [pipe, plain] = AgainstPlain(b, jit);
  std::printf("bar 128x96, jitter 0.02, same pixels: pipeline RMS %.3f um, plain LS %.3f um\n",
              pipe * 1e6, plain * 1e6);
  const Json& fc = jit.sum.frame_corrections;
  ASSERT_TRUE(fc.is_object());
  std::printf(
      "frame corrections: model %s, in-band from %d phase-shift pixels, correction "
      "%s, sigma %.1e\n",
      fc["model"].get<std::string>().c_str(), fc["in_band_pixels"].get<int>(),
      fc["in_band_correction"].dump().c_str(), fc["in_band_sigma"].get<double>());
  EXPECT_GT(fc["in_band_pixels"].get<int>(), 5000);  // the phase-shift reference was used
  EXPECT_GE(jit.e.coverage, clean.e.coverage - 0.002);
  EXPECT_LE(jit.e.rms_m, 1.05 * clean.e.rms_m);
  EXPECT_LE(jit.e.median_abs_m, 1.05 * clean.e.median_abs_m);
  EXPECT_LE(pipe, plain);
  EXPECT_LE(jit.e.rms_m, jit_means.e.rms_m);
}

// The in-band gains from the phase-shift reference on a view too small for them to be precise
// (24x18 px of the tilted bar, ~430 reference pixels: standard error ~3e-3 per component, as
// large as the in-band part of 2% jitter over 50 frames). Without jitter the pipeline stays
// within 5% (the jitter allowance) of the same session with the alternating gains, which
// leave the in-band gains at 1, i.e. right here: applied in full (before the shrinkage), the
// reference's noise made it 1.236 um against 1.088 um here (seeds 1-3: 1.39-1.44 um against
// 1.02-1.08 um), and 1.200 um with jitter (now 1.110). With 2% jitter: at or below the plain
// decoder and the alternating gains (the jitter's own cost is not held to 5% here: the reference's
// noise is the floor of what it can correct, reported).
TEST(RobustReconstruct, InBandReferenceOnATinyViewOfTheTiltedBar) {
  Progress::SetEnabled(false);
  const BarJitterPair pair("tiny", 24, 18);
  const SimulateOptions &s0 = pair.s0, &s1 = pair.s1;
  const Session &a = pair.a, &b = pair.b;
  ReconstructOptions als;
  als.lens_shift.frame_gain_method = FrameGainMethod::kAlternating;
  const Figures clean = RunCase(a, s0), clean_als = RunCase(a, s0, als);
  const Figures jit = RunCase(b, s1), jit_als = RunCase(b, s1, als);
  Print("bar 24x18, no jitter", clean);
  Print("bar 24x18, no jitter (als)", clean_als);
  Print("bar 24x18, jitter 0.02", jit);
  Print("bar 24x18, jitter 0.02 (als)", jit_als);
  const auto [pipe, plain] = AgainstPlain(b, jit);
  std::printf("bar 24x18, jitter 0.02, same pixels: pipeline RMS %.3f um, plain LS %.3f um\n",
              pipe * 1e6, plain * 1e6);
  for (const Figures* f : {&clean, &jit}) {
    const Json& fc = f->sum.frame_corrections;
    ASSERT_TRUE(fc.is_object());
    std::printf("frame corrections: model %s, in-band from %d pixels, sigma %.1e, shrink %.3f\n",
                fc["model"].get<std::string>().c_str(), fc["in_band_pixels"].get<int>(),
                fc["in_band_sigma"].get<double>(), fc["in_band_shrink"].get<double>());
    EXPECT_GT(fc["in_band_pixels"].get<int>(), 0);  // the reference was used
  }
  EXPECT_GE(clean.e.coverage, clean_als.e.coverage - 0.002);
  EXPECT_LE(clean.e.rms_m, 1.05 * clean_als.e.rms_m);
  EXPECT_LE(pipe, plain);
  EXPECT_LE(jit.e.rms_m, jit_als.e.rms_m);
}

}  // namespace
}  // namespace mesoscan
