// Evaluations and importance samples per second for every BRDF model (closing-note figures). Each
// benchmark reports items/s; one "item" is one f() call, one Sample() or one Pdf().

#include <benchmark/benchmark.h>

#include <filesystem>
#include <random>

#include "brdf/brdf.h"
#include "core/log.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

const fs::path kRglFile = fs::path(MESOSCAN_SHARED_DIR) / "data" / "brdf" / "cg_sunflower_rgb.bsdf";
// The one shared file whose energy clamp is active (one extra scale lookup per value).
const fs::path kRglClampedFile =
    fs::path(MESOSCAN_SHARED_DIR) / "data" / "brdf" / "satin_rosaline_rgb.bsdf";

const Brdf& Model(int index) {
  static const Brdf lambert(LambertBrdf(Rgb(0.8, 0.5, 0.2)));
  static const Brdf ggx(
      GgxBrdf<double>::Conductor(0.2, Rgb(0.200, 0.924, 1.102), Rgb(3.912, 2.452, 2.142)));
  static const Brdf merl(MerlBrdf::Tabulate([](const Vec3& wo, const Vec3& wi) {
    return Rgb(GgxBrdf<double>::Dielectric(0.2, 1.5).f(wo, wi) + Rgb(0.3, 0.2, 0.1) * kInvPi);
  }));
  static const Brdf rgl = fs::exists(kRglFile) ? LoadBrdf(kRglFile) : Brdf(LambertBrdf());
  static const Brdf rgl_clamped =
      fs::exists(kRglClampedFile) ? LoadBrdf(kRglClampedFile) : Brdf(LambertBrdf());
  // Over-bright table (albedo ~1.2): f carries the reciprocal clamp min(s(theta_o), s(theta_i)).
  static const Brdf merl_clamped(MerlBrdf::Tabulate([](const Vec3& wo, const Vec3& wi) {
    return Rgb(GgxBrdf<double>::Dielectric(0.2, 1.5).f(wo, wi) + Rgb(1.1, 1.0, 0.9) * kInvPi);
  }));
  switch (index) {
    case 0:
      return lambert;
    case 1:
      return ggx;
    case 2:
      return merl;
    case 3:
      return rgl;
    case 4:
      return rgl_clamped;
    default:
      return merl_clamped;
  }
}
const char* kNames[] = {"lambert",           "ggx",
                        "merl_tabulated",    "rgl_cg_sunflower",
                        "rgl_satin_clamped", "merl_tabulated_clamped"};

// 1024 fixed direction pairs and uniform samples, reused cyclically.
struct Inputs {
  std::vector<Vec3> wo, wi;
  std::vector<Vec2> u;
  Inputs() {
    std::mt19937 rng(1);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    for (int i = 0; i < 1024; ++i) {
      wo.push_back(SampleCosineHemisphere(Vec2(uni(rng), uni(rng))));
      wi.push_back(SampleCosineHemisphere(Vec2(uni(rng), uni(rng))));
      u.emplace_back(uni(rng), uni(rng));
    }
  }
};
const Inputs& In() {
  static const Inputs in;
  return in;
}

void BM_Eval(benchmark::State& state) {
  const Brdf& b = Model(static_cast<int>(state.range(0)));
  const Inputs& in = In();
  size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(b.f(in.wo[i & 1023], in.wi[i & 1023]));
    ++i;
  }
  state.SetItemsProcessed(state.iterations());
  state.SetLabel(kNames[state.range(0)]);
}
void BM_Sample(benchmark::State& state) {
  const Brdf& b = Model(static_cast<int>(state.range(0)));
  const Inputs& in = In();
  size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(b.Sample(in.wo[i & 1023], in.u[i & 1023]));
    ++i;
  }
  state.SetItemsProcessed(state.iterations());
  state.SetLabel(kNames[state.range(0)]);
}
void BM_Pdf(benchmark::State& state) {
  const Brdf& b = Model(static_cast<int>(state.range(0)));
  const Inputs& in = In();
  size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(b.Pdf(in.wo[i & 1023], in.wi[i & 1023]));
    ++i;
  }
  state.SetItemsProcessed(state.iterations());
  state.SetLabel(kNames[state.range(0)]);
}
// Load time of an RGL file, energy clamp included (the albedo quadrature on ~57 elevations) and
// without it (energy_clamp = false still estimates the albedo, for energy(); so the two differ by
// the scale only): wall time, both cores.
void BM_LoadRgl(benchmark::State& state) {
  const fs::path file = state.range(0) ? kRglClampedFile : kRglFile;
  if (!fs::exists(file)) {
    state.SkipWithError("shared data absent");
    return;
  }
  const LogLevel level = GetLogLevel();
  SetLogLevel(LogLevel::kError);  // satin's one-line warning, once per iteration otherwise
  for (auto _ : state) benchmark::DoNotOptimize(RglBrdf::Load(file));
  SetLogLevel(level);
  state.SetLabel(file.filename().string());
}
BENCHMARK(BM_LoadRgl)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_Eval)->DenseRange(0, 5);
BENCHMARK(BM_Sample)->DenseRange(0, 5);
BENCHMARK(BM_Pdf)->DenseRange(0, 5);

}  // namespace
}  // namespace mesoscan

BENCHMARK_MAIN();
