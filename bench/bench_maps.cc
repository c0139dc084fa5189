// Full-resolution scan to a finished material map set (target < 3 s on 2 cores):
// the paper rig's 2176 x 1434 grid of 55 um (3.1 M samples) covered by a woven material lying
// tilted and sagging, with thread-gap shadows (clusters of holes) and 1 um noise; fill, flatten,
// tile, every map, written. Cases: the finished tile (harmonic / biharmonic fill), every map on
// the whole grid without a tile, and the fill alone against OpenCV's inpainting (the plain
// baseline) on the same holes. Figures: wall time, fill time, load average; CSV to
// $MESOSCAN_BENCH_OUT/bench_maps.csv.

#include <benchmark/benchmark.h>
#include <sys/resource.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <opencv2/photo.hpp>
#include <random>

#include "core/log.h"
#include "core/scan_folder.h"
#include "maps/maps.h"
#include "sim/synthetic_scan.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;
constexpr double kPi = 3.14159265358979323846;

const Scan& FullScan() {
  static const Scan scan = [] {
    SyntheticScanOptions o;
    o.seed = 5;
    o.predicted_depth_rms_m = 0;
    Scan s = SyntheticScan(
        [](double x, double y) {
          const double weave =
              80e-6 * std::sin(2 * kPi * x / 0.8e-3) * std::sin(2 * kPi * y / 0.8e-3) +
              40e-6 * std::cos(2 * kPi * (x + y) / 1.6e-3);
          const double shape =
              1e-3 + 0.01 * x - 0.005 * y - 0.4e-3 * (x * x + y * y) / (0.06 * 0.06);
          return shape + weave;
        },
        o);
    HeightField& hf = s.height;
    const int w = hf.width(), h = hf.height();
    // Shadows: 3-6 px clusters in the thread gaps, ~0.5% of the pixels, and 1e-3 dropped samples.
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(0, 1);
    for (int k = 0; k < 3000; ++k) {
      const int cx = static_cast<int>(u(rng) * w), cy = static_cast<int>(u(rng) * h);
      const int r = 1 + static_cast<int>(u(rng) * 3);
      for (int dy = -r; dy <= r; ++dy)
        for (int dx = -r; dx <= r; ++dx)
          if (cx + dx >= 0 && cy + dy >= 0 && cx + dx < w && cy + dy < h &&
              dx * dx + dy * dy <= r * r)
            hf.z(cx + dx, cy + dy) = std::nanf(""), hf.confidence(cx + dx, cy + dy) = 0.0f;
    }
    for (int j = 0; j < h; ++j)
      for (int i = 0; i < w; ++i)
        if (u(rng) < 1e-3) hf.z(i, j) = std::nanf(""), hf.confidence(i, j) = 0.0f;
    s.normals = hf.Normals();
    return s;
  }();
  return scan;
}

fs::path OutDir(const std::string& name) {
  const char* env = std::getenv("MESOSCAN_BENCH_OUT");
  return fs::path(env ? env : fs::temp_directory_path().string()) / ("bench_maps_" + name);
}

// CPU seconds (user + system, all threads) of this process so far.
double CpuSeconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_utime.tv_sec + u.ru_stime.tv_sec + 1e-6 * (u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

double LoadAverage() {
  std::ifstream in("/proc/loadavg");
  double l = -1;
  in >> l;
  return l;
}

void Csv(const std::string& name, double seconds, double fill_s, const std::string& extra) {
  const char* env = std::getenv("MESOSCAN_BENCH_OUT");
  if (!env) return;
  const fs::path csv = fs::path(env) / "bench_maps.csv";
  const bool header = !fs::exists(csv);
  std::ofstream out(csv, std::ios::app);
  if (header) out << "case,seconds,fill_seconds,load_average,notes\n";
  out << name << "," << seconds << "," << fill_s << "," << LoadAverage() << "," << extra << "\n";
}

void BM_Maps(benchmark::State& state, std::string label, FillMethod fill, bool tile) {
  SetLogLevel(LogLevel::kError);
  const Scan& scan = FullScan();
  MapsOptions o;
  o.name = "material";
  o.albedo_from_session = false;
  o.fill.method = fill;
  o.flatten = ParseFlatten("poly:2");
  o.tile = tile;
  o.tile_options.size_m = 20e-3;
  MapsSummary s;
  double cpu = 0;
  for (auto _ : state) {
    const double c0 = CpuSeconds();
    s = BuildMapSet(scan, o, OutDir(label));
    cpu = CpuSeconds() - c0;
  }
  state.counters["cpu_s"] = cpu;
  state.counters["fill_s"] = StageSeconds(s.seconds_per_stage, "fill");
  state.counters["pixels_filled"] = static_cast<double>(s.fill.filled_pixels);
  state.counters["load_avg"] = LoadAverage();
  std::string stages;
  for (const auto& [k, v] : s.seconds_per_stage) stages += k + "=" + std::to_string(v) + " ";
  Csv(label, s.seconds, StageSeconds(s.seconds_per_stage, "fill"),
      "cpu=" + std::to_string(cpu) + " " + stages);
}

// The plain baseline: OpenCV's Navier-Stokes inpainting of the same holes (16-bit heights, as
// cv::inpaint takes them), radius 3.
void BM_OpenCvInpaint(benchmark::State& state) {
  const HeightField& hf = FullScan().height;
  double lo = 1e9, hi = -1e9;
  for (float v : hf.z.data())
    if (std::isfinite(v)) lo = std::min<double>(lo, v), hi = std::max<double>(hi, v);
  cv::Mat src(hf.height(), hf.width(), CV_16U), mask(hf.height(), hf.width(), CV_8U), dst;
  for (int y = 0; y < hf.height(); ++y)
    for (int x = 0; x < hf.width(); ++x) {
      const float v = hf.z(x, y);
      src.at<uint16_t>(y, x) =
          std::isfinite(v) ? static_cast<uint16_t>((v - lo) / (hi - lo) * 65535) : 0;
      mask.at<uint8_t>(y, x) = std::isfinite(v) ? 0 : 255;
    }
  double sec = 0, cpu = 0;
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    const double c0 = CpuSeconds();
    cv::inpaint(src, mask, dst, 3, cv::INPAINT_NS);
    sec = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    cpu = CpuSeconds() - c0;
  }
  state.counters["cpu_s"] = cpu;
  state.counters["load_avg"] = LoadAverage();
  Csv("opencv_inpaint_ns", sec, sec, "fill only; cpu=" + std::to_string(cpu));
}

BENCHMARK_CAPTURE(BM_Maps, tile_harmonic, std::string("tile_harmonic"), FillMethod::kHarmonic, true)
    ->Unit(benchmark::kSecond)
    ->UseRealTime()
    ->Iterations(1);
BENCHMARK_CAPTURE(BM_Maps, tile_biharmonic, std::string("tile_biharmonic"), FillMethod::kBiharmonic,
                  true)
    ->Unit(benchmark::kSecond)
    ->UseRealTime()
    ->Iterations(1);
BENCHMARK_CAPTURE(BM_Maps, whole_grid_harmonic, std::string("whole_grid_harmonic"),
                  FillMethod::kHarmonic, false)
    ->Unit(benchmark::kSecond)
    ->UseRealTime()
    ->Iterations(1);
BENCHMARK(BM_OpenCvInpaint)->Unit(benchmark::kSecond)->UseRealTime()->Iterations(1);

}  // namespace
}  // namespace mesoscan

BENCHMARK_MAIN();
