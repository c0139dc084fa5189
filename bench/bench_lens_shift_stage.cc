// Lens-shift stage benchmark: the reconstruction's stage 4 (FitLensShift) alone on a
// full-resolution session whose frames are decoded once, run several times. Figures, not
// assertions. Per run: wall time and process CPU time (all threads; the machine is shared, CPU
// time depends much less on the load than wall time) of the stage and of its steps (4-parameter
// fit on the subsample, frequency map, frame corrections, fixed-frequency fit of every pixel),
// with the load average. The row kernel (the default fixed-frequency pass) is compared with the
// per-pixel path it replaced (LensShiftStageOptions::row_kernel = false) in the same run: time,
// and how far the outputs move (phase, amplitude, offset, residual; the phase against each
// pixel's predicted sigma).
//
// Session: argv[1], else $MESOSCAN_BENCH_OUT/reconstruct-work/fullres_coin (the folder
// bench_reconstruct simulates; simulated here if absent). MESOSCAN_BENCH_LS_RUNS: runs per
// variant (default 3; the fastest counts). CSV: $MESOSCAN_BENCH_OUT/lens_shift_stage.csv.

#include <sys/resource.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/fs.h"
#include "core/stage_timer.h"
#include "heightfield/reconstruct.h"
#include "heightfield/stage_lens_shift.h"
#include "heightfield/stage_stream.h"
#include "session/session.h"
#include "sim/virtual_rig.h"

namespace fs = std::filesystem;
using namespace mesoscan;

namespace {

double Load1() {
  double load[3] = {0, 0, 0};
  getloadavg(load, 3);
  return load[0];
}

struct Result {
  double wall = std::numeric_limits<double>::infinity(), cpu = 0.0;
  StageTimings steps;
  LensShiftPixels ls;
  PixelStates state;
};

}  // namespace

int main(int argc, char** argv) {
  const char* env = std::getenv("MESOSCAN_BENCH_OUT");
  const fs::path out = env ? fs::path(env) : fs::current_path();
  fs::path dir;
  if (argc > 1) {
    dir = argv[1];
  } else {
    dir = out / "reconstruct-work" / "fullres_coin";
    if (!fs::exists(dir / "session.json")) {
      std::printf("bench_lens_shift_stage: simulating the full-resolution coin into %s ...\n",
                  dir.c_str());
      std::fflush(stdout);
      SimulateOptions so;
      so.object = "coin";
      Simulate(so, dir);
    }
  }
  const char* runs_env = std::getenv("MESOSCAN_BENCH_LS_RUNS");
  const int runs = std::max(1, runs_env ? std::atoi(runs_env) : 3);
  // MESOSCAN_BENCH_LS_ROW_ONLY=1: the row kernel only (profiling).
  const char* row_only_env = std::getenv("MESOSCAN_BENCH_LS_ROW_ONLY");
  const bool row_only = row_only_env && std::string(row_only_env) == "1";
  try {
    const Session session = ReadSession(dir);
    ReconstructOptions ro;
    const ReconstructPlan plan = MakeReconstructPlan(session, ro.plan);
    Stopwatch decode_watch;
    StreamedFrames front =
        DecodeAndPhaseShift(session, plan, {ro.load, ro.classify, ro.gains, ro.phase_shift});
    std::printf("bench_lens_shift_stage: %s, %dx%d, %zu lens-shift frames decoded in %.2f s\n",
                dir.c_str(), front.stack.width(), front.stack.height(), plan.ls_stack.size(),
                decode_watch.Seconds());
    // Variant 0: the row kernel (default); 1: the per-pixel path.
    Result results[2];
    for (int run = 0; run < runs; ++run) {
      for (int v = 0; v < (row_only ? 1 : 2); ++v) {
        FrameGains gains = front.gains;
        PixelStates state = front.classes.state;
        LensShiftStageOptions lo = ro.lens_shift;
        lo.keep_offset_frequency = false;  // as in the pipeline without diagnostics
        lo.row_kernel = v == 0;
        StageTimings steps;
        lo.step_timings = &steps;
        const double load = Load1();
        const double c0 = ProcessCpuSeconds();
        Stopwatch watch;
        LensShiftPixels ls = FitLensShift(front.stack, plan, &gains, lo, &state);
        const double wall = watch.Seconds();
        const double cpu = ProcessCpuSeconds() - c0;
        std::printf("  %-10s run %d: %.3f s wall, %.3f CPU-s (load %.2f):",
                    v ? "per-pixel" : "row kernel", run, wall, cpu, load);
        for (const auto& [name, s] : steps) std::printf(" %s %.3f", name.c_str(), s);
        std::printf("\n");
        std::fflush(stdout);
        Result& r = results[v];
        if (wall < r.wall) {
          r.wall = wall;
          r.cpu = cpu;
          r.steps = steps;
        }
        if (run == 0) {
          r.ls = std::move(ls);
          r.state = std::move(state);
        }
      }
    }
    if (row_only) return 0;
    // How far the row kernel moves the outputs against the per-pixel path.
    const LensShiftPixels& a = results[0].ls;
    const LensShiftPixels& b = results[1].ls;
    double max_dphi = 0, sum_dphi2 = 0, max_dphi_sigma = 0, sum_dphi_sigma2 = 0, max_da = 0,
           max_dd = 0, max_dres = 0;
    int64_t both = 0, state_diff = 0;
    // The offsets are kept only with the diagnostics (LensShiftStageOptions::
    // keep_offset_frequency, off as in the pipeline): compared where both runs have them.
    const bool offsets = a.offset.size() == a.phase0.size() && b.offset.size() == b.phase0.size();
    for (size_t i = 0; i < a.phase0.size(); ++i) {
      state_diff += results[0].state[i] != results[1].state[i];
      if (!std::isfinite(a.phase0[i]) || !std::isfinite(b.phase0[i])) continue;
      ++both;
      const double d = std::remainder(static_cast<double>(a.phase0[i]) - b.phase0[i], 2 * M_PI);
      const double sigma = b.residual_rms[i] * std::sqrt(2.0 / b.samples[i]) / b.amplitude[i];
      max_dphi = std::max(max_dphi, std::abs(d));
      sum_dphi2 += d * d;
      max_dphi_sigma = std::max(max_dphi_sigma, std::abs(d) / sigma);
      sum_dphi_sigma2 += d * d / (sigma * sigma);
      const double amp = b.amplitude[i];
      max_da = std::max(max_da, std::abs(static_cast<double>(a.amplitude[i]) - amp) / amp);
      if (offsets)
        max_dd = std::max(max_dd, std::abs(static_cast<double>(a.offset[i]) - b.offset[i]) / amp);
      max_dres =
          std::max(max_dres, std::abs(static_cast<double>(a.residual_rms[i]) - b.residual_rms[i]) /
                                 std::max(1e-30, static_cast<double>(b.residual_rms[i])));
    }
    const double n = std::max<int64_t>(both, 1);
    std::printf(
        "lens_shift stage (fastest of %d runs): row kernel %.3f s wall %.3f CPU-s; "
        "per-pixel %.3f s wall %.3f CPU-s; load %.2f\n",
        runs, results[0].wall, results[0].cpu, results[1].wall, results[1].cpu, Load1());
    std::printf(
        "row kernel vs per-pixel on %lld pixels: phase max %.2e rad RMS %.2e rad, "
        "max %.2e RMS %.2e of the predicted sigma; amplitude max %.2e relative; offset max "
        "%.2e of a%s; residual_rms max %.2e relative; states differ at %lld pixels\n",
        static_cast<long long>(both), max_dphi, std::sqrt(sum_dphi2 / n), max_dphi_sigma,
        std::sqrt(sum_dphi_sigma2 / n), max_da, max_dd, offsets ? "" : " (offsets not kept)",
        max_dres, static_cast<long long>(state_diff));
    std::string csv = "variant,wall_s,cpu_s";
    for (const auto& [name, s] : results[0].steps) csv += "," + name + "_s";
    csv += ",load\n";
    for (int v = 0; v < 2; ++v) {
      char buf[128];
      std::snprintf(buf, sizeof buf, "%s,%.4f,%.4f", v ? "per_pixel" : "row_kernel",
                    results[v].wall, results[v].cpu);
      csv += buf;
      for (const auto& [name, s] : results[v].steps) {
        std::snprintf(buf, sizeof buf, ",%.4f", s);
        csv += buf;
      }
      std::snprintf(buf, sizeof buf, ",%.2f\n", Load1());
      csv += buf;
    }
    fs::create_directories(out);
    WriteTextFile(out / "lens_shift_stage.csv", csv);
    std::printf("wrote %s\n", (out / "lens_shift_stage.csv").c_str());
  } catch (const Error& e) {
    std::fprintf(stderr, "bench_lens_shift_stage: %s\n", e.what());
    return e.exit_code();
  }
  return 0;
}
