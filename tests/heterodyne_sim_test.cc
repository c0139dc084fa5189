// A three-frequency heterodyne set (42, 45, 48 px, three steps each, 8-bit, no lens shift) on a
// coarse rig (a 640x480 camera, 250 um footprint) through the virtual rig, with ground truth: a
// projector of gamma 2.2 whose response the session does not give (as a real capture) is
// estimated from the phases and undone (heightfield/phase_harmonics.h), against the same capture
// without gamma (the floor) and the plain decoder on the same frames; then a projector whose
// response is no power law (SimulateOptions::projector_curve "s-curve").

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>

#include "core/error.h"
#include "core/image_io.h"
#include "core/numbers.h"
#include "core/progress.h"
#include "core/stage_timer.h"
#include "core/test_temp_dir.h"
#include "heightfield/reconstruct.h"
#include "session/session.h"
#include "sim/board_sim.h"
#include "sim/virtual_rig.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

constexpr double kPeriods[] = {42, 45, 48};

// The true projector column of every camera pixel, NaN where there is none or the pixel's
// footprint is mixed (two surfaces or a shadow edge).
ImageF TrueColumns(const Session& s) {
  const ImageF im = ReadImage(s.root / s.ground_truth->points);
  ImageF u(im.width(), im.height(), 1, std::numeric_limits<float>::quiet_NaN());
  for (int y = 0; y < im.height(); ++y)
    for (int x = 0; x < im.width(); ++x) {
      const Vec3d p(im(x, y, 0), im(x, y, 1), im(x, y, 2));
      if (!p.allFinite() || im(x, y, 3) < 1.0f || im(x, y, 4) > 2e-6f) continue;
      Vec2d uv;
      if (s.rig.projector.Project(p, &uv)) u(x, y) = static_cast<float>(uv.x());
    }
  return u;
}

struct Figures {
  bool refused = false;
  int64_t scored = 0, covered = 0, jumps = 0;
  double column_rms_px = 0, phase_rmse_rad = 0;
  Json response;
  double Coverage() const { return scored ? double(covered) / scored : 0.0; }
};

// Coverage (points with confidence > 0 of the lit single-surface pixels), the column's RMS error
// (period jumps counted apart) and the periods' wrapped phase RMSE against the truth.
Figures Evaluate(const Session& s, HarmonicsMode mode) {
  ReconstructOptions ro;
  ro.keep_diagnostics = true;
  ro.phase_shift.harmonics.mode = mode;
  ReconstructSummary sum;
  StageTimer timer(&sum.timings_s);
  Figures f;
  std::optional<ReconstructedPoints> r;
  try {
    r.emplace(ReconstructPoints(s, ro, &timer, &sum));
  } catch (const Error&) {
    f.refused = true;  // the sine frames contradict each other: nothing kept
  }
  const ImageF truth = TrueColumns(s);
  double e2 = 0, p2 = 0;
  int64_t pn = 0;
  for (int y = 0; y < truth.height(); ++y)
    for (int x = 0; x < truth.width(); ++x) {
      const double t = truth(x, y);
      if (!std::isfinite(t)) continue;
      ++f.scored;
      if (f.refused) continue;
      const size_t i = static_cast<size_t>(y) * truth.width() + x;
      for (size_t p = 0; p < r->ps.theta.size(); ++p) {
        const double th = r->ps.theta[p][i];
        if (!std::isfinite(th)) continue;
        double d = th - 2 * kPi * t / kPeriods[p];
        d -= 2 * kPi * std::round(d / (2 * kPi));
        p2 += d * d, ++pn;
      }
      const double u = r->tri.points.projector_u(x, y);
      if (!std::isfinite(u) || !(r->tri.points.confidence(x, y) > 0)) continue;
      ++f.covered;
      if (std::abs(u - t) > kPeriods[0] / 2) {
        ++f.jumps;
        continue;
      }
      e2 += (u - t) * (u - t);
    }
  f.column_rms_px = std::sqrt(e2 / std::max<int64_t>(1, f.covered - f.jumps));
  f.phase_rmse_rad = std::sqrt(p2 / std::max<int64_t>(1, pn));
  f.response = sum.projector_response;
  return f;
}

void Print(const char* what, const Figures& f) {
  if (f.refused) {
    std::printf("%-34s refused (the periods' phases contradict each other)\n", what);
    return;
  }
  std::printf("%-34s coverage %.4f, column RMS %.4f px, %lld period jumps, phase RMSE %.4f rad\n",
              what, f.Coverage(), f.column_rms_px, static_cast<long long>(f.jumps),
              f.phase_rmse_rad);
}

TEST(HeterodyneSim, ProjectorResponseEstimatedFromThePhasesAndUndoneAtTheFloorOfALinearCapture) {
  Progress::SetEnabled(false);
  const fs::path dir = TestTempPath("heterodyne_sim", "gamma");
  Rig rig = PaperRig();
  rig.camera.width = 640;
  rig.camera.height = 480;
  rig.camera.K << 1000, 0, 319.5, 0, 1000, 239.5, 0, 0, 1;
  fs::create_directories(dir);
  WriteRigFile(dir / "coarse_rig.json", rig);
  SimulateOptions so;
  so.object = "coin";
  so.rig = (dir / "coarse_rig.json").string();
  // Half the crop sees projector columns beyond 673 px, where the set's nearest code rival (673 px
  // away: 0.34 rad over the three periods) is within reach: the fringe orders there stand only
  // with the phases' honest noise.
  so.crop = PixelRect{400, 165, 180, 150};
  so.ps_periods_px = {kPeriods[0], kPeriods[1], kPeriods[2]};
  so.ps_phases = 3;
  so.ls_frames = 0;
  so.adc_bits = 8;
  so.seed = 7;
  Simulate(so, dir / "linear");
  so.projector_gamma = 2.2;
  Simulate(so, dir / "gamma");
  const Session linear = ReadSession(dir / "linear");
  Session gamma = ReadSession(dir / "gamma");
  gamma.rig.projector_response = Response();  // unknown to the decoder, as in a real capture

  const Figures floor = Evaluate(linear, HarmonicsMode::kAuto);
  const Figures floor_plain = Evaluate(linear, HarmonicsMode::kOff);
  const Figures ours = Evaluate(gamma, HarmonicsMode::kAuto);
  const Figures plain = Evaluate(gamma, HarmonicsMode::kOff);
  Print("no gamma (floor):", floor);
  Print("gamma 2.2, harmonics-aware:", ours);
  Print("gamma 2.2, plain decoder:", plain);
  std::printf("column RMS over the floor: %.3f; estimated response: %s\n",
              ours.column_rms_px / floor.column_rms_px, ours.response.dump().c_str());

  // A gamma-free capture: the estimate finds nothing to undo, the decode is the plain one.
  ASSERT_TRUE(floor.response.is_object());
  EXPECT_FALSE(floor.response.at("applied").get<bool>()) << floor.response.dump();
  EXPECT_EQ(floor.covered, floor_plain.covered);
  EXPECT_EQ(floor.column_rms_px, floor_plain.column_rms_px);
  EXPECT_EQ(floor.phase_rmse_rad, floor_plain.phase_rmse_rad);
  // Gamma 2.2: found and undone.
  ASSERT_GT(ours.scored, 15000);
  ASSERT_TRUE(ours.response.is_object());
  EXPECT_TRUE(ours.response.at("applied").get<bool>()) << ours.response.dump();
  EXPECT_NEAR(ours.response.at("gamma").get<double>(), 2.2, 0.15) << ours.response.dump();
  EXPECT_GE(ours.Coverage(), 0.98);
  EXPECT_LE(ours.column_rms_px, 1.10 * floor.column_rms_px);
  EXPECT_LE(ours.jumps, floor.jumps + ours.scored / 1000);
  EXPECT_LE(ours.phase_rmse_rad, 1.10 * floor.phase_rmse_rad);
  // The plain decoder on the same frames is what the estimate is for.
  if (!plain.refused) {
    EXPECT_GT(plain.phase_rmse_rad, 2 * ours.phase_rmse_rad);
  }

  // A response that is no power law (black offset, crushed shadows, soft highlights; session.json
  // says linear): the harmonics are free, so it is found and undone as well as a gamma.
  so.projector_gamma = 1.0;
  so.projector_curve = "s-curve";
  Simulate(so, dir / "scurve");
  const Session scurve = ReadSession(dir / "scurve");
  const Figures s_ours = Evaluate(scurve, HarmonicsMode::kAuto);
  const Figures s_plain = Evaluate(scurve, HarmonicsMode::kOff);
  Print("s-curve, harmonics-aware:", s_ours);
  Print("s-curve, plain decoder:", s_plain);
  std::printf("column RMS over the floor: %.3f; estimated response: %s\n",
              s_ours.column_rms_px / floor.column_rms_px, s_ours.response.dump().c_str());
  ASSERT_TRUE(s_ours.response.is_object());
  EXPECT_TRUE(s_ours.response.at("applied").get<bool>()) << s_ours.response.dump();
  // No gamma explains it: the nearest power law's phase errors are off by more than the fit's
  // residual.
  EXPECT_GT(s_ours.response.at("gamma_misfit_rad").get<double>(),
            s_ours.response.at("residual_rms_rad").get<double>())
      << s_ours.response.dump();
  EXPECT_GE(s_ours.Coverage(), 0.98);
  EXPECT_LE(s_ours.column_rms_px, 1.10 * floor.column_rms_px);
  EXPECT_LE(s_ours.jumps, floor.jumps + s_ours.scored / 1000);
  EXPECT_LE(s_ours.phase_rmse_rad, 1.10 * floor.phase_rmse_rad);
  if (!s_plain.refused) {
    EXPECT_GT(s_plain.phase_rmse_rad, 2 * s_ours.phase_rmse_rad);
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace mesoscan
