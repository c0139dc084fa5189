// Compare of two full-resolution scans (the paper rig's 2176 x 1434 camera grid, 55 um pixels:
// 3.1 M samples each) of the coin, B re-placed by 7 degrees and 1 mm with a 20 um scratch and a
// 5 um erosion patch, 1 um of noise in each. Target: <= 5 s. Figures: wall time (real time), the
// recovered rotation; with $MESOSCAN_BENCH_OUT set, both scan folders are written there (a.scan,
// b.scan) for outside tools (CloudCompare) to time on the same pair, and a CSV line goes to
// bench_compare.csv.

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>

#include "assets/objects.h"
#include "compare/compare.h"
#include "core/log.h"
#include "core/scan_folder.h"
#include "sim/object_change.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

// The demo coin (assets/objects.h) as placed by `change` (sim/object_change.h), sampled on the
// full camera grid (the coin fills ~345 x 345 px of it; the rest is the mount), 1 um of noise.
Scan FullScan(const ObjectChange& change, uint64_t seed) {
  SceneObject coin = MakeCoin(10e-6);
  ApplyObjectChange(change, &coin);
  Scan scan;
  HeightField& hf = scan.height;
  const int w = 2176, h = 1434;
  hf.pixel_size = 55e-6;
  hf.x0 = -(w - 1) / 2.0 * hf.pixel_size;
  hf.y0 = (h - 1) / 2.0 * hf.pixel_size;
  hf.z = ImageF(w, h, 1);
  hf.confidence = ImageF(w, h, 1, 0.95f);
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 1e-6);
  for (int j = 0; j < h; ++j)
    for (int i = 0; i < w; ++i)
      hf.z(i, j) = static_cast<float>(coin.SurfaceZ(hf.X(i), hf.Y(j)) + noise(rng));
  scan.normals = hf.Normals();
  scan.points.xyz = ImageF(2, 2, 3, std::nanf(""));
  scan.points.confidence = ImageF(2, 2, 1, 0.0f);
  scan.points.projector_u = ImageF(2, 2, 1, std::nanf(""));
  scan.report["summary"]["predicted_depth_rms_m"] = 1e-6;
  return scan;
}

const Scan& ScanA() {
  static const Scan s = FullScan(ObjectChange(), 1);
  return s;
}
const Scan& ScanB() {
  static const Scan s = [] {
    ObjectChange c;
    c.pose = {0, 0, 7, 0.8, 0.6, 0};
    c.scratches.push_back({3.5e-3, -3.5e-3, 5.5e-3, -1.0e-3, 0.3e-3, 20e-6});
    c.erosions.push_back({-4.5e-3, 3.5e-3, 1.2e-3, 5e-6});
    return FullScan(c, 2);
  }();
  return s;
}

void BM_CompareFullResolution(benchmark::State& state) {
  SetLogLevel(LogLevel::kError);
  const Scan& a = ScanA();
  const Scan& b = ScanB();
  const char* env = std::getenv("MESOSCAN_BENCH_OUT");
  if (env && !fs::exists(fs::path(env) / "a.scan")) {
    WriteScanFolder(fs::path(env) / "a.scan", a);
    WriteScanFolder(fs::path(env) / "b.scan", b);
  }
  CompareResult r;
  for (auto _ : state) r = CompareScans(a, b, CompareOptions());
  state.counters["rotation_deg"] = r.report["b_to_a_rotation_deg"].get<double>();
  state.counters["deviation_rms_um"] = r.report["deviation_rms_um"].get<double>();
  state.counters["changed_pct"] = 100 * r.report["changed_fraction"].get<double>();
  state.counters["coarse_s"] = r.report["timings_s"]["coarse"].get<double>();
  state.counters["fine_s"] = r.report["timings_s"]["fine"].get<double>();
  if (env) {
    const fs::path csv = fs::path(env) / "bench_compare.csv";
    const bool header = !fs::exists(csv);
    std::ofstream out(csv, std::ios::app);
    if (header) out << "case,seconds,rotation_deg,deviation_rms_um\n";
    out << "full_resolution," << r.report["timings_s"]["total"].get<double>() << ","
        << r.report["b_to_a_rotation_deg"].get<double>() << ","
        << r.report["deviation_rms_um"].get<double>() << "\n";
  }
}
BENCHMARK(BM_CompareFullResolution)->Unit(benchmark::kSecond)->UseRealTime()->Iterations(3);

}  // namespace
}  // namespace mesoscan

BENCHMARK_MAIN();
