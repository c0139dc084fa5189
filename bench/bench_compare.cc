// Compare of two full-resolution scans (the paper rig's 2176 x 1434 camera grid, 55 um pixels:
// 3.1 M samples each) of the coin, B re-placed by 7 degrees and 1 mm with a 20 um scratch and a
// 5 um erosion patch, 1 um of noise in each. Target: <= 5 s. Figures: wall time (real time), the
// recovered rotation and its error against the true placement (RMS displacement over A's coin).
// Beside it, CloudCompare (2.11, command line under Xvfb, when installed) on the same pair's coin
// points: its ICP and cloud-to-cloud distance, timed as the run minus a run that only loads the
// two clouds. With $MESOSCAN_BENCH_OUT set, both scan folders and the PLYs are written there and
// a CSV line per case goes to bench_compare.csv.

#include <benchmark/benchmark.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "assets/objects.h"
#include "compare/compare.h"
#include "core/log.h"
#include "core/scan_folder.h"
#include "maps/export.h"
#include "sim/object_change.h"
#include "sim/synthetic_scan.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

ObjectChange Worn() {
  ObjectChange c;
  c.pose = {0, 0, 7, 0.8, 0.6, 0};
  c.scratches.push_back({3.5e-3, -3.5e-3, 5.5e-3, -1.0e-3, 0.3e-3, 20e-6});
  c.erosions.push_back({-4.5e-3, 3.5e-3, 1.2e-3, 5e-6});
  return c;
}

// The demo coin (assets/objects.h) as placed by `change` (sim/object_change.h), sampled on the
// full camera grid (the coin fills ~345 x 345 px of it; the rest is the mount), each pixel the
// mean over its footprint (3 x 3 samples), 1 um of noise.
Scan CoinScan(const ObjectChange& change, uint64_t seed) {
  SceneObject coin = MakeCoin(10e-6);
  ApplyObjectChange(change, &coin);
  SyntheticScanOptions o;
  o.seed = seed;
  o.supersample = 3;
  return SyntheticScan([&](double x, double y) { return coin.SurfaceZ(x, y); }, o);
}

const Scan& ScanA() {
  static const Scan s = CoinScan(ObjectChange(), 1);
  return s;
}
const Scan& ScanB() {
  static const Scan s = CoinScan(Worn(), 2);
  return s;
}

fs::path OutDir() {
  const char* env = std::getenv("MESOSCAN_BENCH_OUT");
  return env ? fs::path(env) : fs::temp_directory_path() / "bench_compare";
}

void Csv(const std::string& name, double seconds, const std::string& notes) {
  if (!std::getenv("MESOSCAN_BENCH_OUT")) return;
  const fs::path csv = OutDir() / "bench_compare.csv";
  const bool header = !fs::exists(csv);
  std::ofstream out(csv, std::ios::app);
  if (header) out << "case,seconds,notes\n";
  out << name << "," << seconds << "," << notes << "\n";
}

// RMS over A's coin points of the recovered b_to_a's displacement from the true one (metres).
double TransformErrorRms(const Mat4d& b_to_a) {
  const Mat4d truth = Worn().Pose().Inverse().Matrix();
  const HeightField& ha = ScanA().height;
  double ss = 0;
  int64_t n = 0;
  for (int j = 0; j < ha.height(); ++j)
    for (int i = 0; i < ha.width(); ++i)
      if (ha.z(i, j) > 50e-6) {
        const Vec4d p(ha.X(i), ha.Y(j), ha.z(i, j), 1);
        ss += ((b_to_a - truth) * p).head<3>().squaredNorm();
        ++n;
      }
  return std::sqrt(ss / n);
}

void BM_CompareFullResolution(benchmark::State& state) {
  SetLogLevel(LogLevel::kError);
  const Scan& a = ScanA();
  const Scan& b = ScanB();
  if (std::getenv("MESOSCAN_BENCH_OUT") && !fs::exists(OutDir() / "a.scan")) {
    WriteScanFolder(OutDir() / "a.scan", a);
    WriteScanFolder(OutDir() / "b.scan", b);
  }
  CompareResult r;
  for (auto _ : state) r = CompareScans(a, b, CompareOptions());
  const Json& t = r.report["timings_s"];
  const double err = TransformErrorRms(r.b_to_a);
  state.counters["rotation_deg"] = r.report["b_to_a_rotation_deg"].get<double>();
  state.counters["transform_err_um"] = err * 1e6;
  state.counters["deviation_rms_um"] = r.report["deviation_rms_um"].get<double>();
  state.counters["changed_pct"] = 100 * r.report["changed_fraction"].get<double>();
  state.counters["planar_s"] = t["planar"].get<double>();
  state.counters["coarse_s"] = t["coarse"].get<double>();
  state.counters["fine_s"] = t["fine"].get<double>();
  state.counters["deviation_s"] = t["deviation"].get<double>();
  Csv("mesoscan_compare", t["total"].get<double>(),
      "rotation_deg=" + std::to_string(r.report["b_to_a_rotation_deg"].get<double>()) +
          " transform_err_um=" + std::to_string(err * 1e6) +
          " deviation_rms_um=" + std::to_string(r.report["deviation_rms_um"].get<double>()));
}
BENCHMARK(BM_CompareFullResolution)->Unit(benchmark::kSecond)->UseRealTime()->Iterations(3);

// The scan's coin points (above the mount) as a PLY (export's binary x y z nx ny nz confidence).
fs::path CoinPly(const Scan& scan, const std::string& name) {
  const fs::path dir = OutDir() / ("ply_" + name);
  if (fs::exists(dir / (name + ".ply"))) return dir / (name + ".ply");
  Scan s = scan;
  for (float& z : s.height.z.data())
    if (!(z > 50e-6)) z = std::nanf("");
  ExportOptions o;
  o.exr = o.png16 = o.glb = false;
  o.name = name;
  o.albedo_from_session = false;
  ExportScan(s, o, dir);
  return dir / (name + ".ply");
}

double RunSeconds(const std::string& command) {
  const auto t0 = std::chrono::steady_clock::now();
  const int rc = std::system(command.c_str());
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return rc == 0 ? s : -1;
}

// The rotation (degrees) of the newest registration matrix CloudCompare wrote beside `ply`; NaN
// if none.
double CloudCompareRotationDeg(const fs::path& ply) {
  fs::path newest;
  for (const auto& e : fs::directory_iterator(ply.parent_path()))
    if (e.path().filename().string().find("REGISTRATION_MATRIX") != std::string::npos &&
        (newest.empty() || fs::last_write_time(e.path()) > fs::last_write_time(newest)))
      newest = e.path();
  std::ifstream in(newest);
  Mat4d m;
  for (int k = 0; k < 16; ++k)
    if (!(in >> m(k / 4, k % 4))) return std::nan("");
  return Eigen::AngleAxisd(Mat3d(m.topLeftCorner<3, 3>())).angle() * 180 / 3.14159265358979323846;
}

// CloudCompare on the same pair: ICP of B onto A (point-to-point, its defaults), then A's
// cloud-to-cloud distance to B. Skipped when CloudCompare is missing.
void BM_CloudCompareIcpC2C(benchmark::State& state) {
  if (std::system("command -v CloudCompare >/dev/null && command -v xvfb-run >/dev/null") != 0) {
    state.SkipWithError("CloudCompare or xvfb-run not installed");
    return;
  }
  const fs::path pa = CoinPly(ScanA(), "a"), pb = CoinPly(ScanB(), "b");
  const std::string cc = "xvfb-run -a CloudCompare -SILENT -AUTO_SAVE OFF -O '" + pa.string() +
                         "' -O '" + pb.string() + "'";
  const std::string quiet = " >/dev/null 2>&1";
  double load = 0, full = 0;
  for (auto _ : state) {
    load = RunSeconds(cc + quiet);
    full = RunSeconds(cc + " -ICP -REFERENCE_IS_FIRST -C2C_DIST" + quiet);
  }
  if (load < 0 || full < 0) {
    state.SkipWithError("CloudCompare failed");
    return;
  }
  state.counters["load_s"] = load;
  state.counters["icp_c2c_s"] = full - load;
  const double deg = CloudCompareRotationDeg(pb);
  state.counters["rotation_deg"] = deg;
  Csv("cloudcompare_icp_c2c", full - load,
      "load_s=" + std::to_string(load) + " rotation_deg=" + std::to_string(deg));
}
BENCHMARK(BM_CloudCompareIcpC2C)->Unit(benchmark::kSecond)->UseRealTime()->Iterations(1);

}  // namespace
}  // namespace mesoscan

BENCHMARK_MAIN();
