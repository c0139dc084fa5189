// Reconstruction round trips through the virtual rig (sim/virtual_rig.h) with ground truth:
// a tilted plane at the default noise against the Cramer-Rao floor predicted from the
// simulator's noise model and the fitted amplitudes, and lens shift against phase shifting alone.
// Crops keep these fast.

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <numeric>

#include "capture/session.h"
#include "core/progress.h"
#include "heightfield/lens_shift_fit.h"
#include "heightfield/reconstruct.h"
#include "sim/virtual_rig.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;
constexpr double kPi = 3.14159265358979323846;

fs::path TempDir(const std::string& name) {
  return fs::temp_directory_path() / ("mesoscan_reconsim_" + std::to_string(getpid()) + "_" + name);
}

// A crop of the paper rig's camera on the tilted bar 3 mm from its low end (z ~ 0.37 mm, near
// the projector's focus; further up the bar defocus leaves the 1-px stripes little contrast).
SimulateOptions PlaneOptions(int w, int h) {
  SimulateOptions o;
  o.object = "plane";
  const int cx = static_cast<int>(std::lround(1087.5 - 17e-3 / 55e-6));
  o.crop = std::array<int, 4>{w, h, cx - w / 2, 717 - h / 2};
  o.seed = 11;
  return o;
}

TEST(ReconstructSim, TiltedPlaneAtTheCramerRaoFloor) {
  Progress::SetEnabled(false);
  const SimulateOptions so = PlaneOptions(160, 120);
  const fs::path dir = TempDir("plane");
  Simulate(so, dir);
  const Session s = ReadSession(dir);
  ReconstructOptions ro;
  ro.keep_diagnostics = true;
  ReconstructSummary sum;
  const Scan scan = Reconstruct(s, ro, &sum);
  const GroundTruthErrors e = EvaluateAgainstGroundTruth(s, scan.points);
  // The floor: var(phi) >= [F^-1] (about 2 sigma^2 / (N a^2)) with sigma from the simulator's
  // noise model at the profile's mean and the fitted amplitude, f held (second pass), carried
  // through the triangulation's dZ/du; RMS over the pixels scored.
  const NoiseModel noise = MakeNoiseModel(so);
  int64_t n = 0;
  for (float v : e.error.data()) n += std::isfinite(v);
  ASSERT_GT(n, 1000);
  const double crlb = LensShiftDepthCrlbRms(s, sum.diagnostics, e.error,
                                           [&](double m) { return noise.Sigma(m); });
  std::printf("tilted plane: depth RMS %.3f um, CRLB %.3f um, ratio %.3f, coverage %.4f\n",
              e.rms_m * 1e6, crlb * 1e6, e.rms_m / crlb, e.coverage);
  EXPECT_GE(e.coverage, 0.99);
  EXPECT_LE(e.rms_m, 1.15 * crlb) << "RMS " << e.rms_m << " CRLB " << crlb;
  fs::remove_all(dir);
}

TEST(ReconstructSim, LensShiftHalvesThePhaseShiftError) {
  Progress::SetEnabled(false);
  // Same object and noise: 50 lens-shift + 9 phase-shift frames vs 21 phase-shift frames
  // (7 phases of 7/11/13 px).
  SimulateOptions ls = PlaneOptions(96, 72);
  SimulateOptions ps = ls;
  ps.ls_frames = 0;
  ps.ps_phases = 7;
  const fs::path dl = TempDir("ls"), dp = TempDir("ps");
  Simulate(ls, dl);
  Simulate(ps, dp);
  const Session sl = ReadSession(dl), sp = ReadSession(dp);
  const GroundTruthErrors el = EvaluateAgainstGroundTruth(sl, Reconstruct(sl, {}).points);
  const GroundTruthErrors ep = EvaluateAgainstGroundTruth(sp, Reconstruct(sp, {}).points);
  std::printf("LS 50 + PS 9: %.3f um; PS 21: %.3f um; ratio %.3f\n", el.rms_m * 1e6,
              ep.rms_m * 1e6, el.rms_m / ep.rms_m);
  EXPECT_GE(el.coverage, 0.99);
  // Phase shifting alone (21 frames) rejects ~5% of this crop (unwrapping/confidence); its
  // coverage is reported, not asserted (the issue asserts the RMS ratio).
  std::printf("coverage: LS %.4f, PS %.4f\n", el.coverage, ep.coverage);
  EXPECT_LE(el.rms_m, 0.5 * ep.rms_m);
  fs::remove_all(dl);
  fs::remove_all(dp);
}

}  // namespace
}  // namespace mesoscan
