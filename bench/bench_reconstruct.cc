// Reconstruction benchmark (figures, not assertions):
//  1. The paper's Table 1 rerun on the virtual rig (Ritz et al. 2012): PS 9, PS 21, and
//     LS 15/25/50/100/200 (+ PS 9) with the fast, LM and Ceres fitters, on a crop of the tilted
//     bar near the projector's focus. Per row: wall time of the reconstruction and of the
//     lens-shift fit, depth RMS vs ground truth, repeatability D (paper Eq. 3: RMS of the
//     difference of two scans of the same object with different noise seeds, divided by sqrt 2 so
//     it is a per-scan figure) and the ratio of the RMS to the Cramer-Rao floor of the simulator's
//     noise model. Written to table1.csv and plotted (error against run time) in table1.png.
//  1b. Table 1 with the disturbances of real rigs (Table1Disturbances): LS 50 + PS 9
//     with gain jitter 0 / 0.02 (joint frame gains, the older alternating gains, frame means) and
//     with lens-shifter position errors 0 / 0.02 px RMS (estimated, and nominal positions), each
//     with the plain fixed-frequency least-squares decoder (tests/plain_ls_decoder.h) on the same
//     pixels; and jitter 0 / 0.02 on a 24x18 view (joint and alternating gains), where the
//     phase-shift reference's in-band estimate is as noisy as the jitter it corrects. Written to
//     table1_disturbances.csv. MESOSCAN_BENCH_TABLE1_DISTURBANCES_ONLY=1 runs only this part.
//  2. Full resolution (2176 x 1434, 9 + 50 + 2 frames, the coin): bare PNG decode time of the
//     frames, compute time (frames in memory to height field), end-to-end (read session,
//     reconstruct, write the scan folder) and peak RSS of the reconstruction, measured in a child
//     process (this binary re-run with --fullres-child; the bare decode forked from it, so that
//     its leftovers do not count in that peak), with the wall time of every pipeline
//     stage and of writing the scan folder, plus the CPU times (all threads) of the bare decode,
//     the reconstruction and end to end, and the load average (the machine is shared: wall
//     times depend on the load); then the mesoscan reconstruct process on the simulated session
//     and on the same frames as a capture (no ground truth). MESOSCAN_BENCH_FULLRES_RUNS rounds
//     (default 3), the goals as medians. Written to fullres.csv. Skipped with
//     MESOSCAN_BENCH_QUICK=1; MESOSCAN_BENCH_FULLRES_ONLY=1 runs only this part.
// Output folder: $MESOSCAN_BENCH_OUT (default: current folder).

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <numeric>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "core/fs.h"
#include "core/image_input.h"
#include "core/image_io.h"
#include "core/json.h"
#include "core/malloc_tuning.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "core/scan_folder.h"
#include "heightfield/lens_shift_fit.h"
#include "heightfield/reconstruct.h"
#include "session/session.h"
#include "sim/ground_truth.h"
#include "sim/virtual_rig.h"
#include "tests/plain_ls_decoder.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

double Since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

struct Row {
  std::string config, fitter;
  int frames = 0;
  double seconds = 0, fit_seconds = 0, rms_um = 0, repeat_um = 0, crlb_um = 0, coverage = 0;
};

// Crop of the paper rig on the tilted bar 3 mm from its low end (as tests/reconstruct_sim_test).
SimulateOptions PlaneOptions(int w, int h, uint64_t seed) {
  SimulateOptions o;
  o.object = "plane";
  const int cx = static_cast<int>(std::lround(1087.5 - 17e-3 / 55e-6));
  o.crop = PixelRect{cx - w / 2, 717 - h / 2, w, h};
  o.seed = seed;
  o.focus_height_m = 0.0;  // focused on the mount (the bar near it)
  return o;
}

// Cramer-Rao floor of the depth RMS (lens shift: var(phi) from the Fisher information with the
// simulator's noise at the fitted offset and amplitude; phase shifting alone: the pipeline's
// own prediction from the residuals).
double CrlbDepthRms(const Session& s, const SimulateOptions& so, const ReconstructSummary& sum,
                    const GroundTruthErrors& e) {
  if (!sum.used_lens_shift || sum.diagnostics.ls_amplitude.empty())
    return sum.predicted_depth_rms_m;
  const NoiseModel noise = MakeNoiseModel(so);
  return LensShiftDepthCrlbRms(s, sum.diagnostics, e.error,
                               [&](double m) { return noise.Sigma(m); });
}

std::vector<Row> Table1(const fs::path& work) {
  struct Config {
    std::string name;
    int phases, ls;
    double jitter = 0.005, position_error = 0.0;  // rows with the disturbances of real rigs
  };
  const std::vector<Config> configs = {{"PS 9", 3, 0},           {"PS 21", 7, 0},
                                       {"LS 15 + PS 9", 3, 15},  {"LS 25 + PS 9", 3, 25},
                                       {"LS 50 + PS 9", 3, 50},  {"LS 100 + PS 9", 3, 100},
                                       {"LS 200 + PS 9", 3, 200}};
  // The rows with disturbances of real rigs are Table1Disturbances below.
  std::vector<Row> rows;
  for (const Config& c : configs) {
    Session sessions[2];
    SimulateOptions so[2];
    for (int k = 0; k < 2; ++k) {
      so[k] = PlaneOptions(128, 96, 21 + k);
      so[k].ps_phases = c.phases;
      so[k].ls_frames = c.ls;
      so[k].gain_jitter = c.jitter;
      so[k].shift_position_error_px = c.position_error;
      const fs::path dir =
          work / ("t1_" + std::to_string(c.phases) + "_" + std::to_string(c.ls) + "_" +
                  std::to_string(k) + (c.jitter != 0.005 ? "_j" + std::to_string(c.jitter) : "") +
                  (c.position_error > 0 ? "_p" + std::to_string(c.position_error) : ""));
      if (!fs::exists(dir / "session.json")) Simulate(so[k], dir);
      sessions[k] = ReadSession(dir);
    }
    const std::vector<LensShiftFitter> fitters =
        c.ls ? std::vector<LensShiftFitter>{LensShiftFitter::kFast, LensShiftFitter::kLm,
                                            LensShiftFitter::kCeres}
             : std::vector<LensShiftFitter>{LensShiftFitter::kFast};
    for (LensShiftFitter fitter : fitters) {
      Row r;
      r.config = c.name;
      r.fitter = c.ls == 0                          ? "-"
                 : fitter == LensShiftFitter::kFast ? "fast"
                 : fitter == LensShiftFitter::kLm   ? "lm"
                                                    : "ceres";
      r.frames = static_cast<int>(sessions[0].frames.size());
      ReconstructOptions ro;
      ro.lens_shift.fitter = fitter;
      ro.keep_diagnostics = true;
      ReconstructSummary sum[2];
      Scan scans[2];
      for (int k = 0; k < 2; ++k) scans[k] = Reconstruct(sessions[k], ro, &sum[k]);
      r.seconds = sum[0].total_s;
      r.fit_seconds = sum[0].Seconds("lens_shift");
      const GroundTruthErrors e = EvaluateAgainstGroundTruth(sessions[0], scans[0].points);
      r.rms_um = e.rms_m * 1e6;
      r.coverage = e.coverage;
      // Repeatability: the two seeds' Z differences at pixels valid in both.
      double s2 = 0;
      int64_t n = 0;
      const ImageF& za = scans[0].points.xyz;
      const ImageF& zb = scans[1].points.xyz;
      for (size_t i = 0; i < za.pixels(); ++i) {
        const float a = za.channel(2)[i], b = zb.channel(2)[i];
        if (std::isfinite(a) && std::isfinite(b)) {
          s2 += (a - b) * (a - b);
          ++n;
        }
      }
      r.repeat_um = n ? std::sqrt(s2 / n / 2) * 1e6 : NAN;
      r.crlb_um = CrlbDepthRms(sessions[0], so[0], sum[0], e) * 1e6;
      std::printf(
          "%-28s %-6s frames %3d  total %7.3f s  fit %7.3f s  RMS %6.3f um  D %6.3f um  "
          "RMS/CRLB %5.3f  coverage %.4f\n",
          r.config.c_str(), r.fitter.c_str(), r.frames, r.seconds, r.fit_seconds, r.rms_um,
          r.repeat_um, r.rms_um / r.crlb_um, r.coverage);
      std::fflush(stdout);
      rows.push_back(r);
    }
  }
  return rows;
}

// Error against run time, log-x, one marker colour per fitter, each point labelled.
void PlotTable1(const std::vector<Row>& rows, const fs::path& png) {
  const int W = 900, H = 600, L = 90, R = 30, T = 50, B = 70;
  cv::Mat img(H, W, CV_8UC3, cv::Scalar(255, 255, 255));
  double tmin = 1e30, tmax = 0, emax = 0;
  for (const Row& r : rows) {
    tmin = std::min(tmin, r.seconds);
    tmax = std::max(tmax, r.seconds);
    if (std::isfinite(r.rms_um)) emax = std::max(emax, r.rms_um);
  }
  const double lx0 = std::floor(std::log10(std::max(tmin, 1e-4))),
               lx1 = std::ceil(std::log10(tmax));
  const double ey1 = emax * 1.1;
  auto px = [&](double t) {
    return L + static_cast<int>((std::log10(t) - lx0) / std::max(lx1 - lx0, 1e-9) * (W - L - R));
  };
  auto py = [&](double e) { return H - B - static_cast<int>(e / ey1 * (H - T - B)); };
  const cv::Scalar black(0, 0, 0), grey(200, 200, 200);
  cv::rectangle(img, {L, T}, {W - R, H - B}, black, 1);
  for (double lx = lx0; lx <= lx1 + 1e-9; lx += 1) {
    const int x = px(std::pow(10, lx));
    cv::line(img, {x, T}, {x, H - B}, grey, 1);
    char buf[32];
    std::snprintf(buf, sizeof buf, "%g s", std::pow(10, lx));
    cv::putText(img, buf, {x - 20, H - B + 22}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black, 1,
                cv::LINE_AA);
  }
  for (int k = 0; k <= 5; ++k) {
    const double e = ey1 * k / 5;
    const int y = py(e);
    cv::line(img, {L, y}, {W - R, y}, grey, 1);
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.1f", e);
    cv::putText(img, buf, {L - 45, y + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black, 1, cv::LINE_AA);
  }
  cv::putText(img, "reconstruction wall time (log scale)", {W / 2 - 160, H - 25},
              cv::FONT_HERSHEY_SIMPLEX, 0.6, black, 1, cv::LINE_AA);
  cv::putText(img, "depth RMS vs ground truth (um)", {10, T - 15}, cv::FONT_HERSHEY_SIMPLEX, 0.6,
              black, 1, cv::LINE_AA);
  cv::putText(img, "Table 1 rerun, tilted bar, 128x96 px", {W / 2 - 60, T - 15},
              cv::FONT_HERSHEY_SIMPLEX, 0.6, black, 1, cv::LINE_AA);
  auto colour = [](const std::string& f) {
    return f == "fast"    ? cv::Scalar(40, 160, 40)
           : f == "lm"    ? cv::Scalar(200, 100, 20)
           : f == "ceres" ? cv::Scalar(30, 30, 220)
                          : cv::Scalar(80, 80, 80);
  };
  for (const Row& r : rows) {
    if (!std::isfinite(r.rms_um)) continue;
    const cv::Point p(px(r.seconds), py(r.rms_um));
    cv::circle(img, p, 5, colour(r.fitter), cv::FILLED, cv::LINE_AA);
    if (r.fitter == "fast" || r.fitter == "-")
      cv::putText(img, r.config, p + cv::Point(8, -6), cv::FONT_HERSHEY_SIMPLEX, 0.42, black, 1,
                  cv::LINE_AA);
  }
  int ly = T + 20;
  for (const char* f : {"fast", "lm", "ceres", "-"}) {
    cv::circle(img, {W - R - 150, ly - 4}, 5, colour(f), cv::FILLED, cv::LINE_AA);
    cv::putText(img, std::string(f) == "-" ? "phase shift only" : std::string(f) + " fitter",
                {W - R - 138, ly}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black, 1, cv::LINE_AA);
    ly += 20;
  }
  ImageU8 out(W, H, 3);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const cv::Vec3b v = img.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) out(x, y, c) = v[2 - c];  // BGR -> RGB
    }
  WritePng8(png, out);
}

// CPU time (user + system) of the waited-for children so far, s, and their largest peak RSS, MB.
void ChildrenUsage(double* cpu_s, double* max_rss_mb) {
  rusage ru{};
  getrusage(RUSAGE_CHILDREN, &ru);
  *cpu_s =
      ru.ru_utime.tv_sec + ru.ru_stime.tv_sec + 1e-6 * (ru.ru_utime.tv_usec + ru.ru_stime.tv_usec);
  *max_rss_mb = ru.ru_maxrss / 1024.0;
}

// One `mesoscan reconstruct` process on `session_dir`: wall time, CPU time (getrusage of the
// waited-for children) and the peak RSS it reports itself (report.json peak_rss_mb; the
// children's maximum from getrusage(RUSAGE_CHILDREN) also counts the shell that std::system
// spawns, which is charged with this process's resident size when it starts: 1120 MB after the
// simulation ran in this process, against the CLI's own ~500 MB). A failure is printed.
struct CliRun {
  double wall = 0, cpu = 0, rss_mb = 0;
};
CliRun RunCli(const fs::path& session_dir, const fs::path& scan, const fs::path& log) {
  double cpu0 = 0, rss0 = 0;
  ChildrenUsage(&cpu0, &rss0);
  const std::string cmd = std::string("'") + MESOSCAN_EXE + "' reconstruct '" +
                          session_dir.string() + "' --out '" + scan.string() + "' --force > '" +
                          log.string() + "' 2>&1";
  const auto t = Clock::now();
  const int status = std::system(cmd.c_str());
  CliRun r;
  r.wall = Since(t);
  double cpu1 = 0, rss1 = 0;
  ChildrenUsage(&cpu1, &rss1);
  r.cpu = cpu1 - cpu0;
  r.rss_mb = rss1;
  if (status != 0) {
    std::printf("full resolution: mesoscan reconstruct %s failed (status %d, see %s)\n",
                session_dir.c_str(), status, log.c_str());
  } else {
    const Json report = ReadJsonFile(scan / "report.json");
    if (report.contains("peak_rss_mb")) r.rss_mb = report["peak_rss_mb"].get<double>();
  }
  return r;
}

// Full resolution: simulate once, then measure decode / compute / end-to-end / RSS in a child,
// and the `mesoscan reconstruct` process itself (first, so that its peak RSS is its own).
void FullResolution(const fs::path& work, const fs::path& out) {
  const fs::path dir = work / "fullres_coin";
  if (!fs::exists(dir / "session.json")) {
    SimulateOptions so;
    so.object = "coin";
    std::printf("full resolution: simulating the paper rig (2176x1434) ...\n");
    std::fflush(stdout);
    const auto t = Clock::now();
    Simulate(so, dir);
    std::printf("full resolution: simulation %.1f s\n", Since(t));
  }
  // The CLI as a user runs it (loading the libraries, reading the session, the ground-truth
  // comparison this simulated session has, writing the scan folder); then the same frames as a
  // capture would be, without ground truth (its session.json minus "ground_truth", the frames
  // hard-linked: a symlink leaving the session folder is refused): only simulations read the
  // ground truth and write the error map.
  const fs::path capture = work / "fullres_capture";
  {
    Json session = ReadJsonFile(dir / "session.json");
    session.erase("ground_truth");
    fs::remove_all(capture);
    fs::create_directories(capture / "frames");
    for (const auto& e : fs::directory_iterator(dir / "frames"))
      fs::create_hard_link(e.path(), capture / "frames" / e.path().filename());
    WriteJsonFile(capture / "session.json", session);
  }
  // MESOSCAN_BENCH_FULLRES_RUNS (default 3) rounds of the three processes, one after the other
  // (the machine's speed drifts by 10-15 % between minutes): each round printed, the goals from
  // the medians over the rounds, every round a row of fullres.csv.
  int runs = 3;
  if (const char* e = std::getenv("MESOSCAN_BENCH_FULLRES_RUNS")) runs = std::max(1, std::atoi(e));
  // The measurement runs in a fresh process (this binary with --fullres-child): TBB's worker
  // pool does not survive fork(), and a fresh process gives an honest peak RSS. The binary's
  // own path is resolved here (inside the shell of std::system, /proc/self/exe is the shell).
  const fs::path result = work / "fullres_child.txt";
  const std::string self = fs::read_symlink("/proc/self/exe").string();
  const std::string child_cmd = "'" + self + "' --fullres-child '" + dir.string() + "' '" +
                                (work / "fullres_coin.scan").string() + "' '" + result.string() +
                                "'";
  struct Round {
    CliRun cli, capture;
    double decode = 0, compute = 0, e2e = 0, total = 0, rms = 0, cpu_decode = 0,
           cpu_reconstruct = 0, cpu_e2e = 0, rss_mb = 0, load = 0;
  };
  std::vector<Round> rounds;
  std::string csv =
      "run,decode_s,compute_s,end_to_end_s,end_to_end_over_decode,peak_rss_mb,depth_rms_um,"
      "cpu_decode_s,cpu_reconstruct_s,cpu_end_to_end_s,cpu_over_decode,cli_wall_s,cli_cpu_s,"
      "cli_peak_rss_mb,capture_cli_wall_s,capture_cli_cpu_s,capture_cli_peak_rss_mb,"
      "load_average\n";
  for (int run = 1; run <= runs; ++run) {
    Round r;
    r.cli = RunCli(dir, work / "fullres_cli.scan", work / "fullres_cli.log");
    r.capture = RunCli(capture, work / "fullres_capture.scan", work / "fullres_capture.log");
    if (std::system(child_cmd.c_str()) != 0) {
      std::printf("full resolution: the measuring process failed (round %d)\n", run);
      return;
    }
    const std::string buf = ReadTextFile(result);
    int stages_at = 0;
    std::sscanf(buf.c_str(), "%lf %lf %lf %lf %lf %lf %lf %lf %lf%n", &r.decode, &r.compute, &r.e2e,
                &r.total, &r.rms, &r.cpu_decode, &r.cpu_reconstruct, &r.cpu_e2e, &r.rss_mb,
                &stages_at);
    double load[3] = {0, 0, 0};
    getloadavg(load, 3);
    r.load = load[0];
    std::printf("full resolution round %d of %d:\n", run, runs);
    std::printf(
        "  (2176x1434, 61 frames) bare PNG decode %.2f s; compute after the last frame %.2f s; "
        "end-to-end (read session, reconstruct, write) %.2f s = %.2fx decode; peak RSS %.0f MB; "
        "depth RMS %.2f um\n",
        r.decode, r.compute, r.e2e, r.e2e / r.decode, r.rss_mb, r.rms * 1e6);
    std::printf(
        "  CPU (s, all threads): bare decode %.2f, reconstruct incl. its decode %.2f, "
        "end to end %.2f = %.2fx the bare decode; load average %.2f\n",
        r.cpu_decode, r.cpu_reconstruct, r.cpu_e2e, r.cpu_e2e / r.cpu_decode, r.load);
    std::printf("  stages, wall | CPU (s):%s", buf.c_str() + stages_at);
    std::printf(
        "  the mesoscan reconstruct process (libraries, session, reconstruct, ground truth, "
        "writing): %.2f s wall = %.2fx the bare decode, %.2f CPU-s = %.2fx, peak RSS %.0f MB; "
        "the same frames as a capture (no ground truth, no error map): %.2f s wall = %.2fx, "
        "%.2f CPU-s = %.2fx, peak RSS %.0f MB\n",
        r.cli.wall, r.cli.wall / r.decode, r.cli.cpu, r.cli.cpu / r.cpu_decode, r.cli.rss_mb,
        r.capture.wall, r.capture.wall / r.decode, r.capture.cpu, r.capture.cpu / r.cpu_decode,
        r.capture.rss_mb);
    std::fflush(stdout);
    char row[512];
    std::snprintf(row, sizeof row,
                  "%d,%.4f,%.4f,%.4f,%.4f,%.1f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.1f,%.4f,%.4f,"
                  "%.1f,%.2f\n",
                  run, r.decode, r.compute, r.e2e, r.e2e / r.decode, r.rss_mb, r.rms * 1e6,
                  r.cpu_decode, r.cpu_reconstruct, r.cpu_e2e, r.cpu_e2e / r.cpu_decode, r.cli.wall,
                  r.cli.cpu, r.cli.rss_mb, r.capture.wall, r.capture.cpu, r.capture.rss_mb, r.load);
    csv += row;
    rounds.push_back(r);
  }
  WriteTextFile(out / "fullres.csv", csv);
  // The full-resolution goals, each the median over the rounds (ratios per round, then the
  // median), with the range.
  auto median = [&](double (*f)(const Round&), double* lo, double* hi) {
    std::vector<double> v;
    for (const Round& r : rounds) v.push_back(f(r));
    std::sort(v.begin(), v.end());
    *lo = v.front();
    *hi = v.back();
    const size_t n = v.size();
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
  };
  // The goals: what, the figure of a round, its unit, the goal.
  struct Figure {
    const char* what;
    double (*of)(const Round&);
    const char* unit;
    const char* goal;
  };
  const Figure figures[] = {
      {"end to end in process / bare decode, wall", [](const Round& r) { return r.e2e / r.decode; },
       "x", "goal <= 1.25"},
      {"end to end in process / bare decode, CPU",
       [](const Round& r) { return r.cpu_e2e / r.cpu_decode; }, "x", "goal <= 1.25"},
      {"CLI process (simulation) / bare decode, wall",
       [](const Round& r) { return r.cli.wall / r.decode; }, "x", "goal <= 1.25"},
      {"CLI process (simulation) / bare decode, CPU",
       [](const Round& r) { return r.cli.cpu / r.cpu_decode; }, "x", "goal <= 1.25"},
      {"CLI process (as a capture) / bare decode, wall",
       [](const Round& r) { return r.capture.wall / r.decode; }, "x", "goal <= 1.25"},
      {"CLI process (as a capture) / bare decode, CPU",
       [](const Round& r) { return r.capture.cpu / r.cpu_decode; }, "x", "goal <= 1.25"},
      {"compute after the last frame", [](const Round& r) { return r.compute; }, " s",
       "goal <= 0.5 s"},
      {"peak RSS in process", [](const Round& r) { return r.rss_mb; }, " MB", "goal <= 600 MB"},
      {"peak RSS of the CLI process", [](const Round& r) { return r.cli.rss_mb; }, " MB",
       "goal <= 600 MB"},
      {"load average", [](const Round& r) { return r.load; }, "", ""},
  };
  std::string goals;
  for (const Figure& fig : figures) {
    double lo = 0, hi = 0;
    const double m = median(fig.of, &lo, &hi);
    char buf[256];
    std::snprintf(buf, sizeof buf, "  %-52s %7.2f%s (%.2f-%.2f)  %s\n", fig.what, m, fig.unit, lo,
                  hi, fig.goal);
    goals += buf;
  }
  std::printf("full resolution goals, median over %d rounds (range):\n%s", runs, goals.c_str());
}

// The measuring process: decode, reconstruct, write; prints the figures into `result`: wall
// times, then the CPU times (the machine is shared: wall times depend on the load, CPU times
// much less), the peak RSS of the reconstruction and writing (before the ground-truth
// comparison, which is not part of the timed work), then every stage's wall and CPU time.
// The bare decode of the session's frames (wall and CPU seconds) in a forked process: what it
// leaves resident (~70 MB of its threads' heaps, the PNG libraries' pages) would otherwise count
// in the reconstruction's peak RSS measured after it (~110 MB more than `mesoscan reconstruct`
// shows). Called before anything starts a thread (fork keeps only the calling one).
bool BareDecodeInChild(const fs::path& dir, double* wall, double* cpu) {
  int fds[2];
  if (pipe(fds) != 0) return false;
  const pid_t pid = fork();
  if (pid < 0) return false;
  if (pid == 0) {
    close(fds[0]);
    TuneAllocatorForReconstruction();  // the same allocator as the reconstruction's
    const Session s = ReadSession(dir);
    const auto t = Clock::now();
    const double c = ProcessCpuSeconds();
    // Each PNG into its own 16-bit samples (no conversion to float; the pipeline keeps the
    // frames as 16-bit integers too), two at a time.
    ParallelFor(static_cast<int64_t>(s.frames.size()), [&](int64_t i) {
      auto in = OpenImageInput(s.FramePath(i), s.FramePath(i).string());
      const ImageHeader& spec = in->header();
      std::vector<uint16_t> samples(static_cast<size_t>(spec.width) * spec.height * spec.channels);
      if (!in->ReadWhole(PixelType::kUInt16, samples.data()))
        std::printf("full resolution: cannot decode %s\n", s.FramePath(i).c_str());
    });
    const double out[2] = {Since(t), ProcessCpuSeconds() - c};
    const bool ok = write(fds[1], out, sizeof out) == static_cast<ssize_t>(sizeof out);
    _exit(ok ? 0 : 1);
  }
  close(fds[1]);
  double in[2] = {0, 0};
  const bool ok = read(fds[0], in, sizeof in) == static_cast<ssize_t>(sizeof in);
  close(fds[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  *wall = in[0];
  *cpu = in[1];
  return ok && WIFEXITED(status) && WEXITSTATUS(status) == 0;
}

int FullResolutionChild(const fs::path& dir, const fs::path& scan_dir, const fs::path& result) {
  double decode = 0, cpu_decode = 0;
  if (!BareDecodeInChild(dir, &decode, &cpu_decode)) {
    std::printf("full resolution: the bare decode's process failed\n");
    return 1;
  }
  TuneAllocatorForReconstruction();  // as `mesoscan reconstruct` does
  const auto t = Clock::now();
  const double c = ProcessCpuSeconds();
  const Session s = ReadSession(dir);
  ReconstructSummary sum;
  const Scan scan = Reconstruct(s, {}, &sum);
  const double cpu_reconstruct = ProcessCpuSeconds() - c;
  const auto t_write = Clock::now();
  const double c_write = ProcessCpuSeconds();
  WriteScanFolder(scan_dir, scan);
  const double write = Since(t_write);
  const double cpu_write = ProcessCpuSeconds() - c_write;
  const double e2e = Since(t);
  const double cpu_e2e = ProcessCpuSeconds() - c;
  const double rss_mb = PeakRssMegabytes();
  const double compute = sum.total_s - sum.last_frame_s;  // after the last decoded frame
  const double rms = EvaluateAgainstGroundTruth(s, scan.points).rms_m;
  char buf[256];
  std::snprintf(buf, sizeof buf, "%f %f %f %f %.6e %f %f %f %f", decode, compute, e2e, sum.total_s,
                rms, cpu_decode, cpu_reconstruct, cpu_e2e, rss_mb);
  std::string text = buf;
  for (const auto& [name, seconds] : sum.timings_s) {
    std::snprintf(buf, sizeof buf, " %s %.3f", name.c_str(), seconds);
    text += buf;
    for (const auto& [cpu_name, cpu] : sum.cpu_s)
      if (cpu_name == name) {
        std::snprintf(buf, sizeof buf, " | %.3f", cpu);
        text += buf;
      }
  }
  std::snprintf(buf, sizeof buf, " write_scan %.3f | %.3f\n", write, cpu_write);
  WriteTextFile(result, text + buf);
  return 0;
}

// ==== Table 1 with the disturbances of real rigs (kept apart from
// Table1 above so that the two can change independently) ====
struct DisturbedRow {
  std::string config;
  double seconds = 0, rms_um = 0, repeat_um = 0, crlb_um = 0, coverage = 0, plain_um = 0,
         pipeline_same_um = 0;
};

std::vector<DisturbedRow> Table1Disturbances(const fs::path& work) {
  struct Config {
    std::string name;
    double jitter, position_error;
    FrameGainMethod gains = FrameGainMethod::kJoint;
    bool correct_positions = true;
    int w = 128, h = 96;  // the view (a 24x18 one: ~430 phase-shift reference pixels)
  };
  const std::vector<Config> configs = {
      {"LS 50 + PS 9 jitter 0", 0.0, 0.0},
      {"LS 50 + PS 9 jitter 0.02", 0.02, 0.0},
      {"LS 50 + PS 9 jitter 0.02 (alternating gains)", 0.02, 0.0, FrameGainMethod::kAlternating},
      {"LS 50 + PS 9 jitter 0.02 (frame means)", 0.02, 0.0, FrameGainMethod::kFrameMeans},
      {"LS 50 + PS 9 jitter 0.005 shifter 0", 0.005, 0.0},
      {"LS 50 + PS 9 jitter 0.005 shifter 0.02px", 0.005, 0.02},
      {"LS 50 + PS 9 jitter 0.005 shifter 0.02px (nominal)", 0.005, 0.02, FrameGainMethod::kJoint,
       false},
      {"24x18 view: LS 50 + PS 9 jitter 0", 0.0, 0.0, FrameGainMethod::kJoint, true, 24, 18},
      {"24x18 view: jitter 0 (alternating gains)", 0.0, 0.0, FrameGainMethod::kAlternating, true,
       24, 18},
      {"24x18 view: jitter 0.02", 0.02, 0.0, FrameGainMethod::kJoint, true, 24, 18},
      {"24x18 view: jitter 0.02 (alternating gains)", 0.02, 0.0, FrameGainMethod::kAlternating,
       true, 24, 18}};
  std::vector<DisturbedRow> rows;
  for (const Config& c : configs) {
    Session sessions[2];
    SimulateOptions so[2];
    for (int k = 0; k < 2; ++k) {
      so[k] = PlaneOptions(c.w, c.h, 21 + k);
      so[k].ps_phases = 3;
      so[k].ls_frames = 50;
      so[k].gain_jitter = c.jitter;
      so[k].shift_position_error_px = c.position_error;
      char name[96];
      std::snprintf(name, sizeof name, "t1d_j%.3f_p%.3f_%d", c.jitter, c.position_error, k);
      const std::string view =
          c.w == 128 && c.h == 96 ? "" : "_" + std::to_string(c.w) + "x" + std::to_string(c.h);
      const fs::path dir = work / (name + view);
      if (!fs::exists(dir / "session.json")) Simulate(so[k], dir);
      sessions[k] = ReadSession(dir);
    }
    ReconstructOptions ro;
    ro.keep_diagnostics = true;
    ro.lens_shift.frame_gain_method = c.gains;
    ro.lens_shift.correct_positions = c.correct_positions;
    ReconstructSummary sum[2];
    Scan scans[2];
    for (int k = 0; k < 2; ++k) scans[k] = Reconstruct(sessions[k], ro, &sum[k]);
    DisturbedRow r;
    r.config = c.name;
    r.seconds = sum[0].total_s;
    const GroundTruthErrors e = EvaluateAgainstGroundTruth(sessions[0], scans[0].points);
    r.rms_um = e.rms_m * 1e6;
    r.coverage = e.coverage;
    double s2 = 0;
    int64_t n = 0;
    for (size_t i = 0; i < scans[0].points.xyz.pixels(); ++i) {
      const float a = scans[0].points.xyz.channel(2)[i], b = scans[1].points.xyz.channel(2)[i];
      if (std::isfinite(a) && std::isfinite(b)) {
        s2 += (a - b) * (a - b);
        ++n;
      }
    }
    r.repeat_um = n ? std::sqrt(s2 / n / 2) * 1e6 : NAN;
    r.crlb_um = CrlbDepthRms(sessions[0], so[0], sum[0], e) * 1e6;
    ScanPoints pipeline = scans[0].points;
    ScanPoints plain = testing::PlainLsDecode(sessions[0], pipeline.projector_u);
    testing::IntersectPoints(&pipeline, &plain);
    r.pipeline_same_um = EvaluateAgainstGroundTruth(sessions[0], pipeline).rms_m * 1e6;
    r.plain_um = EvaluateAgainstGroundTruth(sessions[0], plain).rms_m * 1e6;
    std::printf(
        "%-52s total %7.3f s  RMS %6.3f um  D %6.3f um  RMS/CRLB %5.3f  coverage %.4f  "
        "same pixels: pipeline %6.3f um, plain LS %6.3f um\n",
        r.config.c_str(), r.seconds, r.rms_um, r.repeat_um, r.rms_um / r.crlb_um, r.coverage,
        r.pipeline_same_um, r.plain_um);
    std::fflush(stdout);
    rows.push_back(r);
  }
  return rows;
}

void WriteTable1Disturbances(const fs::path& work, const fs::path& out) {
  std::string csv =
      "config,wall_s,depth_rms_um,repeatability_D_um,crlb_um,rms_over_crlb,coverage,"
      "pipeline_same_pixels_um,plain_ls_same_pixels_um\n";
  for (const DisturbedRow& r : Table1Disturbances(work)) {
    char buf[512];
    std::snprintf(buf, sizeof buf, "%s,%.4f,%.4f,%.4f,%.4f,%.4f,%.5f,%.4f,%.4f\n", r.config.c_str(),
                  r.seconds, r.rms_um, r.repeat_um, r.crlb_um, r.rms_um / r.crlb_um, r.coverage,
                  r.pipeline_same_um, r.plain_um);
    csv += buf;
  }
  WriteTextFile(out / "table1_disturbances.csv", csv);
  std::printf("bench_reconstruct: wrote %s\n", (out / "table1_disturbances.csv").c_str());
}
// ==== end of the Table 1 rows with disturbances ====

}  // namespace
}  // namespace mesoscan

int main(int argc, char** argv) {
  using namespace mesoscan;
  Progress::SetEnabled(false);
  if (argc == 5 && std::string(argv[1]) == "--fullres-child") {
    try {
      return FullResolutionChild(argv[2], argv[3], argv[4]);
    } catch (const Error& e) {
      std::fprintf(stderr, "bench_reconstruct: %s\n", e.what());
      return e.exit_code();
    }
  }
  const char* env = std::getenv("MESOSCAN_BENCH_OUT");
  const fs::path out = env ? fs::path(env) : fs::current_path();
  const fs::path work = out / "reconstruct-work";
  fs::create_directories(work);
  try {
    // MESOSCAN_BENCH_FULLRES_ONLY=1: only the full-resolution figures (no Table 1).
    const char* fullres_only = std::getenv("MESOSCAN_BENCH_FULLRES_ONLY");
    if (fullres_only && std::string(fullres_only) == "1") {
      FullResolution(work, out);
      return 0;
    }
    const char* disturbances_only = std::getenv("MESOSCAN_BENCH_TABLE1_DISTURBANCES_ONLY");
    if (disturbances_only && std::string(disturbances_only) == "1") {
      WriteTable1Disturbances(work, out);
      return 0;
    }
    const std::vector<Row> rows = Table1(work);
    std::string csv =
        "config,fitter,frames,wall_s,lens_shift_fit_s,depth_rms_um,repeatability_D_um,crlb_um,"
        "rms_over_crlb,coverage\n";
    for (const Row& r : rows) {
      char buf[512];
      std::snprintf(buf, sizeof buf, "%s,%s,%d,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.5f\n",
                    r.config.c_str(), r.fitter.c_str(), r.frames, r.seconds, r.fit_seconds,
                    r.rms_um, r.repeat_um, r.crlb_um, r.rms_um / r.crlb_um, r.coverage);
      csv += buf;
    }
    WriteTextFile(out / "table1.csv", csv);
    PlotTable1(rows, out / "table1.png");
    std::printf("bench_reconstruct: wrote %s and %s\n", (out / "table1.csv").c_str(),
                (out / "table1.png").c_str());
    WriteTable1Disturbances(work, out);
    const char* quick = std::getenv("MESOSCAN_BENCH_QUICK");
    if (!(quick && std::string(quick) == "1")) FullResolution(work, out);
  } catch (const Error& e) {
    std::fprintf(stderr, "bench_reconstruct: %s\n", e.what());
    return e.exit_code();
  }
  return 0;
}
