// Wall time of the full-resolution paper-rig simulation (2176 x 1434, 9 + 50 + 2 frames,
// 3 x 3 supersampling): the figure the virtual rig promises (< 60 s on 2 cores).
// Counters: the stage times and the process CPU seconds (all threads), which on a shared
// machine says more than the wall time. Output session: $MESOSCAN_BENCH_OUT/simulate_coin.session
// (removed unless MESOSCAN_BENCH_KEEP is set).

#include <benchmark/benchmark.h>
#include <sys/resource.h>

#include <cstdlib>
#include <filesystem>

#include "core/log.h"
#include "core/progress.h"
#include "sim/virtual_rig.h"

namespace {
namespace fs = std::filesystem;

double CpuSeconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_utime.tv_sec + u.ru_stime.tv_sec + 1e-6 * (u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

fs::path OutDir(const std::string& name) {
  const char* env = std::getenv("MESOSCAN_BENCH_OUT");
  const fs::path base = env ? fs::path(env) : fs::temp_directory_path();
  fs::create_directories(base);
  return base / name;
}

void BM_SimulatePaperRig(benchmark::State& state, const std::string& object) {
  mesoscan::Progress::SetEnabled(false);
  mesoscan::SetLogLevel(mesoscan::LogLevel::kWarning);
  mesoscan::SimulateOptions options;  // the defaults: full paper rig, 61 frames, S = 3
  options.object = object;
  const fs::path out = OutDir("simulate_" + object + ".session");
  mesoscan::SimulateSummary summary;
  double cpu = 0;
  for (auto _ : state) {
    const double cpu0 = CpuSeconds();
    summary = mesoscan::Simulate(options, out);
    cpu = CpuSeconds() - cpu0;
  }
  state.counters["frames"] = summary.frames;
  state.counters["rays"] = static_cast<double>(summary.rays);
  state.counters["scene_s"] = summary.seconds_scene;
  state.counters["raycast_s"] = summary.seconds_raycast;
  state.counters["frames_s"] = summary.seconds_frames;
  state.counters["total_s"] = summary.seconds_total;
  state.counters["cpu_s"] = cpu;
  if (!std::getenv("MESOSCAN_BENCH_KEEP")) fs::remove_all(out);
}

BENCHMARK_CAPTURE(BM_SimulatePaperRig, coin, std::string("coin"))
    ->Iterations(1)
    ->UseRealTime()
    ->Unit(benchmark::kSecond);

}  // namespace

BENCHMARK_MAIN();
