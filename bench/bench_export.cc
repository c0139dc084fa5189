// Export of a full-resolution scan (the paper rig's 2176 x 1434 camera grid, 55 um pixels:
// 3.1 M samples), all formats and each alone. Target: all formats <= 5 s.
// Figures: wall time (real time), GLB triangles and its stated max height error; a CSV goes to
// $MESOSCAN_BENCH_OUT/bench_export.csv.

#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>

#include "core/log.h"
#include "core/scan_folder.h"
#include "maps/export.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

// A coin-like field: a 19 mm disk 1.3 mm high with a rim and a 60 um relief of rings and
// ripples, on the mount plane; shadows (holes) on one side of the rim; random dropped samples;
// 1 um Gaussian measurement noise everywhere (so the mesh budget, not flatness, limits the GLB).
const Scan& FullScan() {
  static const Scan scan = [] {
    Scan s;
    HeightField& hf = s.height;
    const int w = 2176, h = 1434;
    hf.pixel_size = 55e-6;
    hf.x0 = -(w - 1) / 2.0 * hf.pixel_size;
    hf.y0 = (h - 1) / 2.0 * hf.pixel_size;
    hf.z = ImageF(w, h, 1);
    hf.confidence = ImageF(w, h, 1);
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(0, 1);
    std::normal_distribution<double> noise(0.0, 1.0);
    for (int j = 0; j < h; ++j) {
      for (int i = 0; i < w; ++i) {
        const double x = hf.X(i), y = hf.Y(j), r = std::hypot(x, y);
        double z = 0.0;
        if (r < 9.5e-3) {
          z = 1.2e-3 + (r > 8.8e-3 ? 0.1e-3 : 0.0) +
              40e-6 * std::sin(r / 0.3e-3) * std::cos(std::atan2(y, x) * 7) +
              20e-6 * std::sin(x / 0.2e-3);
        }
        const bool shadow = r > 9.5e-3 && r < 10.5e-3 && x > 0;
        const bool hole = shadow || u(rng) < 1e-3;
        z += 1e-6 * noise(rng);  // measurement noise: no sample is exactly coplanar
        hf.z(i, j) = hole ? std::nanf("") : static_cast<float>(z);
        hf.confidence(i, j) = hole ? 0.0f : 0.95f;
      }
    }
    s.normals = hf.Normals();
    return s;
  }();
  return scan;
}

fs::path OutDir() {
  const char* env = std::getenv("MESOSCAN_BENCH_OUT");
  return fs::path(env ? env : fs::temp_directory_path().string()) / "bench_export";
}

void Csv(const std::string& name, double seconds, const ExportSummary& s) {
  const char* env = std::getenv("MESOSCAN_BENCH_OUT");
  if (!env) return;
  const fs::path csv = fs::path(env) / "bench_export.csv";
  const bool header = !fs::exists(csv);
  std::ofstream out(csv, std::ios::app);
  if (header) out << "case,seconds,files,triangles,max_height_error_um\n";
  out << name << "," << seconds << "," << s.files.size() << "," << s.triangles << ","
      << s.max_height_error_m * 1e6 << "\n";
  // Each writer's own wall time (they run in parallel), as rows "case/file".
  for (const auto& [file, sec] : s.seconds_per_file)
    out << name << "/" << file << "," << sec << ",,,\n";
}

void BM_Export(benchmark::State& state, std::string formats, std::string label) {
  SetLogLevel(LogLevel::kError);
  const Scan& scan = FullScan();
  ExportOptions o;
  ParseExportFormats(formats, &o);
  o.name = "coin";
  o.albedo_from_session = false;
  ExportSummary s;
  for (auto _ : state) s = ExportScan(scan, o, OutDir());
  state.counters["samples"] = static_cast<double>(scan.height.z.pixels());
  state.counters["triangles"] = static_cast<double>(s.triangles);
  state.counters["max_err_um"] = s.max_height_error_m * 1e6;
  Csv(label, s.seconds, s);
}

BENCHMARK_CAPTURE(BM_Export, all, ExportFormatList(), std::string("all"))
    ->Unit(benchmark::kSecond)
    ->UseRealTime()
    ->Iterations(1);
BENCHMARK_CAPTURE(BM_Export, exr, std::string("exr"), std::string("exr"))
    ->Unit(benchmark::kSecond)
    ->UseRealTime()
    ->Iterations(1);
BENCHMARK_CAPTURE(BM_Export, png16, std::string("png16"), std::string("png16"))
    ->Unit(benchmark::kSecond)
    ->UseRealTime()
    ->Iterations(1);
BENCHMARK_CAPTURE(BM_Export, glb, std::string("glb"), std::string("glb"))
    ->Unit(benchmark::kSecond)
    ->UseRealTime()
    ->Iterations(1);
BENCHMARK_CAPTURE(BM_Export, ply, std::string("ply"), std::string("ply"))
    ->Unit(benchmark::kSecond)
    ->UseRealTime()
    ->Iterations(1);

}  // namespace
}  // namespace mesoscan

BENCHMARK_MAIN();
