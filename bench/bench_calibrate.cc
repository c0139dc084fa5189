// Calibration of six board sessions of 12 full-resolution frames each: the
// held-back real captures' shape (8-bit BMP frames 1688 x 1352, projector 1824 x 1140, 3 phases of
// a one-period cue and 16 periods per axis, no white frame, a low-contrast 13x9 board of 10 mm
// squares), simulated once with default noise (0.5% per-frame gain jitter included) and reused.
// Timed: DetectView of the six sessions (frame loading, corners, gains, decoding, homographies)
// and Calibrate (OpenCV initialisation and baseline, Ceres adjustment, covariance). Target: < 10 s
// on 2 cores. Figures: reprojection RMS of ours and of OpenCV's calibration on the same corners,
// focal length errors against the simulated truth; a CSV row goes to
// $MESOSCAN_BENCH_OUT/bench_calibrate.csv.

#include <benchmark/benchmark.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <numbers>

#include "calibration/calibrate.h"
#include "core/log.h"
#include "core/progress.h"
#include "session/session.h"
#include "sim/board_sim.h"
#include "sim/virtual_rig.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

fs::path OutDir() {
  const char* env = std::getenv("MESOSCAN_BENCH_OUT");
  return fs::path(env ? env : fs::temp_directory_path().string()) / "bench_calibrate";
}

const CalibrationBoard& Board() {
  static const CalibrationBoard b = CalibrationBoard::Parse("checker:13x9:10", "bench");
  return b;
}

// The six sessions, simulated on first use (kept under OutDir() for later runs).
const std::vector<fs::path>& Sessions() {
  static const std::vector<fs::path> dirs = [] {
    const std::vector<std::array<double, 6>> poses = {
        {0, 0, 0, 0, 0, 0},    {20, 0, 5, 0, 0, 5},      {-20, 5, -5, 5, 0, 0},
        {5, 20, 10, 0, 5, -5}, {-5, -20, -10, -5, 0, 8}, {15, -15, 0, 0, -5, 3}};
    const Rig rig = RealShapeRig();
    fs::create_directories(OutDir());
    const fs::path rig_file = OutDir() / "rig.json";
    WriteRigFile(rig_file, rig);
    std::vector<fs::path> out;
    for (size_t i = 0; i < poses.size(); ++i) {
      const fs::path dir = OutDir() / ("view" + std::to_string(i));
      out.push_back(dir);
      if (fs::exists(dir / "session.json")) continue;
      SimulateOptions so;
      so.rig = rig_file.string();
      so.supersample = 1;
      so.ps_phases = 3;
      so.white = false;
      so.black = false;
      so.ls_frames = 0;
      so.ps_periods_px = {1824, 114};
      so.defocus_px_per_m = 50;
      so.seed = 500 + i;
      BoardSimOptions bo;
      bo.board = Board();
      bo.ps_periods_y_px = {1140, 71.25};
      bo.frame_format = "bmp";
      bo.dark_albedo = 0.45;
      bo.light_albedo = 0.8;
      bo.pose = poses[i];
      SimulateBoard(so, bo, dir);
    }
    return out;
  }();
  return dirs;
}

void BM_CalibrateSixSessions(benchmark::State& state) {
  SetLogLevel(LogLevel::kError);
  Progress::SetEnabled(false);
  const std::vector<fs::path>& dirs = Sessions();
  const Rig truth = RealShapeRig();
  CalibrateOptions co;
  co.board = Board();
  co.fix_k3 = true;
  co.fix_tangential = true;
  CalibrationResult r;
  double detect_s = 0, calibrate_s = 0;
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    std::vector<CalibrationView> views;
    Rig size_rig;
    for (const auto& d : dirs) {
      const Session s = ReadSession(d);
      size_rig = s.rig;
      views.push_back(DetectView(s, co));
    }
    const auto t1 = std::chrono::steady_clock::now();
    r = Calibrate(std::move(views), size_rig, std::nullopt, co);
    const auto t2 = std::chrono::steady_clock::now();
    detect_s = std::chrono::duration<double>(t1 - t0).count();
    calibrate_s = std::chrono::duration<double>(t2 - t1).count();
  }
  const double f_cam = (r.rig.camera.K(0, 0) / truth.camera.K(0, 0) - 1) * 100;
  const double f_prj = (r.rig.projector.K(0, 0) / truth.projector.K(0, 0) - 1) * 100;
  state.counters["views"] = r.views_used;
  state.counters["detect_s"] = detect_s;
  state.counters["calibrate_s"] = calibrate_s;
  state.counters["rms_cam_px"] = r.rms_camera_px;
  state.counters["rms_prj_px"] = r.rms_projector_px;
  state.counters["rms_stereo_px"] = r.rms_stereo_px;
  state.counters["cv_rms_cam_px"] = r.opencv.value("rms_camera_px", 0.0);
  state.counters["cv_rms_prj_px"] = r.opencv.value("rms_projector_px", 0.0);
  state.counters["cv_rms_stereo_px"] = r.opencv.value("rms_stereo_px", 0.0);
  state.counters["f_cam_err_pct"] = f_cam;
  state.counters["f_prj_err_pct"] = f_prj;
  if (const char* env = std::getenv("MESOSCAN_BENCH_OUT")) {
    const fs::path csv = fs::path(env) / "bench_calibrate.csv";
    const bool header = !fs::exists(csv);
    std::ofstream out(csv, std::ios::app);
    if (header)
      out << "case,seconds,detect_s,calibrate_s,views,rms_cam_px,rms_prj_px,rms_stereo_px,"
             "opencv_rms_cam_px,opencv_rms_prj_px,opencv_rms_stereo_px,f_cam_err_pct,"
             "f_prj_err_pct\n";
    out << "six_sessions," << detect_s + calibrate_s << "," << detect_s << "," << calibrate_s << ","
        << r.views_used << "," << r.rms_camera_px << "," << r.rms_projector_px << ","
        << r.rms_stereo_px << "," << r.opencv.value("rms_camera_px", 0.0) << ","
        << r.opencv.value("rms_projector_px", 0.0) << "," << r.opencv.value("rms_stereo_px", 0.0)
        << "," << f_cam << "," << f_prj << "\n";
  }
}

BENCHMARK(BM_CalibrateSixSessions)->Unit(benchmark::kSecond)->UseRealTime()->Iterations(1);

}  // namespace
}  // namespace mesoscan

BENCHMARK_MAIN();
