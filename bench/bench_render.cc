// The preview renderer against Blender Cycles 3.4 on the same scenes, in the same run:
//   relief      the procedural coin, hole-free (Lambert 0.7 on a 0.3 mount)
//   coin-holes  the same coin with 8% of its samples NaN (holes down to the mount)
//   slab-hole   a 20 mm slab 1 mm above the mount with a 4 mm square hole
// under a lat-long environment (Blender's studio.exr from blender-data, else the procedural sky
// written as EXR), same camera, box filter, no denoising or clamping, 2 threads.
//
// Per scene and renderer: a reference at MESOSCAN_BENCH_REF_SPP (default 1024) and a test render
// at 128 spp. Reported: bias of mesoscan's reference against Cycles' on the sample and on the
// mount (mean luminance over pixels whose camera rays hit the sample / the mount), the relative
// RMSE of each 128-spp render against its own renderer's reference, the render times and the
// efficiency ratio (1 / (relMSE x time), mesoscan over Cycles). Also raw Embree rays/s (closest
// hit with the double refinement, and occlusion) next to the tracer's paths/s, and what the
// skips save (constant environment, adaptive stopping).
//
// Also `make demo`'s preview against its own 1024-spp reference (relRMSE and CPU s per spp; see
// DemoPreview and bench/demo_preview.sh), and `bench_render --compare REF.exr TEST.exr [MASK]`
// for images another build rendered.
//
// relative RMSE = sqrt(mean over pixels of (Y - Y_ref)^2) / mean(Y_ref), Y = luminance.
// Environment: MESOSCAN_BENCH_RENDER_SIZE=WxH (default 320x240); Blender from PATH (skipped with
// a note if missing). Results: bench-results/render.csv and the images.

#include <sys/resource.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <random>
#include <sstream>

#include "assets/objects.h"
#include "brdf/brdf.h"
#include "core/image_io.h"
#include "core/json.h"
#include "core/parallel.h"
#include "core/progress.h"
#include "core/scan_folder.h"
#include "maps/maps_fill.h"
#include "render/denoise.h"
#include "render/embree_scene.h"
#include "render/env_map.h"
#include "render/path_tracer.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

double Now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

// CPU seconds of this process (all threads): on the shared machine, the figure that does not
// depend on how many other builds run at the same time.
double CpuNow() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

std::string LoadAvg() {
  std::ifstream f("/proc/loadavg");
  std::string a, b, c;
  f >> a >> b >> c;
  return a + " " + b + " " + c;
}

struct SceneDef {
  std::string name;
  HeightField hf;
};

std::vector<SceneDef> MakeScenes() {
  std::vector<SceneDef> s;
  const HeightField coin = MakeCoin(100e-6).height;
  s.push_back({"relief", coin});
  // Holes: 8% of the samples, as blobs (shadowed regions of a real scan) away from the border.
  HeightField holes = coin;
  std::mt19937 rng(3);
  const int w = holes.width(), h = holes.height();
  int64_t nan = 0;
  while (nan < 0.08 * w * h) {
    std::uniform_int_distribution<int> ux(w / 8, w - w / 8), uy(h / 8, h - h / 8), ur(2, 6);
    const int cx = ux(rng), cy = uy(rng), r = ur(rng);
    for (int j = std::max(0, cy - r); j <= std::min(h - 1, cy + r); ++j)
      for (int i = std::max(0, cx - r); i <= std::min(w - 1, cx + r); ++i)
        if ((i - cx) * (i - cx) + (j - cy) * (j - cy) <= r * r && std::isfinite(holes.z(i, j))) {
          holes.z(i, j) = NAN;
          ++nan;
        }
  }
  s.push_back({"coin-holes", holes});
  HeightField slab;
  slab.pixel_size = 100e-6;
  const int n = 201;
  slab.x0 = -100 * slab.pixel_size;
  slab.y0 = 100 * slab.pixel_size;
  slab.z = ImageF(n, n, 1, 1e-3f);
  for (int j = 81; j <= 119; ++j)
    for (int i = 81; i <= 119; ++i) slab.z(i, j) = NAN;  // cells 80..119: 4 mm
  s.push_back({"slab-hole", slab});
  return s;
}

// The camera RenderOptions frames by default (elevation 50, azimuth -90, fov 30), made explicit.
CameraSpec FramingCamera(const HeightField& hf, int width, int height) {
  double zmin = 1e30, zmax = -1e30;
  for (float z : hf.z.data())
    if (std::isfinite(z)) zmin = std::min(zmin, double(z)), zmax = std::max(zmax, double(z));
  const double ex = hf.width() * hf.pixel_size, ey = hf.height() * hf.pixel_size;
  const Vec3 target(hf.X(0.5 * (hf.width() - 1)), hf.Y(0.5 * (hf.height() - 1)),
                    0.5 * (zmin + zmax));
  const double el = 50 * kPi / 180, az = -90 * kPi / 180, aspect = double(width) / height;
  const double half = 0.5 * std::max(ey, ex / aspect) / 0.9;
  const double dist = half / std::tan(15 * kPi / 180) + 0.5 * (zmax - zmin);
  return {
      target + dist * Vec3(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el)),
      target};
}

struct Stats {
  double mean_sample = 0, mean_mount = 0;
};
Stats RegionMeans(const ImageF& im, const ImageF& mask) {
  double s = 0, m = 0;
  int64_t ns = 0, nm = 0;
  for (size_t i = 0; i < im.pixels(); ++i) {
    const double y = Luminance(Rgb(im.channel(0)[i], im.channel(1)[i], im.channel(2)[i]));
    if (mask.channel(0)[i] > 0.99f)
      s += y, ++ns;
    else if (mask.channel(0)[i] < 0.01f)
      m += y, ++nm;
  }
  return {ns ? s / ns : 0, nm ? m / nm : 0};
}

double RelRmse(const ImageF& im, const ImageF& ref) {
  double se = 0, sr = 0;
  for (size_t i = 0; i < im.pixels(); ++i) {
    const double a = Luminance(Rgb(im.channel(0)[i], im.channel(1)[i], im.channel(2)[i]));
    const double b = Luminance(Rgb(ref.channel(0)[i], ref.channel(1)[i], ref.channel(2)[i]));
    se += (a - b) * (a - b);
    sr += b;
  }
  const double n = static_cast<double>(im.pixels());
  return std::sqrt(se / n) / (sr / n);
}

bool HaveBlender() { return std::system("command -v blender > /dev/null 2>&1") == 0; }

// Renders the scene in Cycles; returns the render seconds (NaN on failure).
double RenderCycles(const fs::path& dir, const std::string& tag, const SceneDef& sc,
                    const Json& base, int spp, ImageF* out) {
  Json cfg = base;
  cfg["spp"] = spp;
  cfg["out_exr"] = fs::absolute(dir / ("cycles_" + tag + ".exr")).string();
  const fs::path json = dir / ("cycles_" + tag + ".json");
  std::ofstream(json) << cfg.dump(2);
  const fs::path log = dir / ("cycles_" + tag + ".log");
  const std::string cmd = "blender -b --factory-startup -noaudio --python '" +
                          (fs::path(MESOSCAN_SOURCE_DIR) / "bench" / "cycles_scene.py").string() +
                          "' -- '" + json.string() + "' > '" + log.string() + "' 2>&1";
  if (std::system(cmd.c_str()) != 0) {
    std::cerr << "cycles failed, see " << log << "\n";
    return NAN;
  }
  std::ifstream f(log);
  std::string line;
  double seconds = NAN;
  while (std::getline(f, line))
    if (line.rfind("CYCLES_RENDER_SECONDS ", 0) == 0) seconds = std::stod(line.substr(22));
  *out = ReadImage(cfg["out_exr"].get<std::string>());
  if (out->channels() > 3) {
    ImageF rgb(out->width(), out->height(), 3);
    for (int c = 0; c < 3; ++c)
      std::copy(out->channel(c), out->channel(c) + out->pixels(), rgb.channel(c));
    *out = std::move(rgb);
  }
  return seconds;
}

double RelRmseMasked(const ImageF& im, const ImageF& ref, const ImageF& mask, int region) {
  // region 0: all pixels; 1: the sample (mask > 0.99); 2: the mount (mask < 0.01). Normalised
  // by the whole reference's mean, so the regions' squared errors add up (weighted by area).
  double se = 0, sr = 0;
  int64_t n = 0;
  for (size_t i = 0; i < im.pixels(); ++i) {
    const double b = Luminance(Rgb(ref.channel(0)[i], ref.channel(1)[i], ref.channel(2)[i]));
    sr += b;
    const float m = mask.channel(0)[i];
    if ((region == 1 && !(m > 0.99f)) || (region == 2 && !(m < 0.01f))) continue;
    const double a = Luminance(Rgb(im.channel(0)[i], im.channel(1)[i], im.channel(2)[i]));
    se += (a - b) * (a - b);
    ++n;
  }
  return n ? std::sqrt(se / n) / (sr / im.pixels()) : 0.0;
}

// Display-space error: both images through the reference's tone curve (what one looks at): RMS
// over pixels and channels of the 8-bit sRGB difference (of 255), and the reference's mean.
struct DisplayError {
  double rmse = 0, mean = 0;
  double relative() const { return rmse / mean; }
};
DisplayError DisplayRmse(const ImageF& im, const ImageF& ref, const ToneMapping& tone) {
  const ImageU8 da = ToneMapForDisplay(im, tone), db = ToneMapForDisplay(ref, tone);
  double d2 = 0, dm = 0;
  for (size_t i = 0; i < ref.pixels(); ++i)
    for (int c = 0; c < 3; ++c) {
      const double d = double(da.channel(c)[i]) - double(db.channel(c)[i]);
      d2 += d * d;
      dm += db.channel(c)[i];
    }
  return {std::sqrt(d2 / (3.0 * ref.pixels())), dm / (3.0 * ref.pixels())};
}

// The same, relative to the reference's mean.
double DisplayRelRmse(const ImageF& im, const ImageF& ref, const ToneMapping& tone) {
  return DisplayRmse(im, ref, tone).relative();
}

// `make demo`'s preview (step 5 of scripts/demo): the demo coin's scan, filled as `render` fills
// it, GGX copper tabulated into the MERL layout, the procedural sky (sun at 25 / 200 degrees),
// 480x360, default framing. Needs the scan folder: MESOSCAN_BENCH_DEMO_SCAN=demo/coin.scan
// (bench/demo_preview.sh makes it). Reference: the mean of two MESOSCAN_BENCH_DEMO_REF_SPP
// (default 1024) spp renders with seeds 1 and 1001, cached as render/demo_ref_<spp>spp_<key>.exr
// and demo_ref_<spp>spp_seed1001_<key>.exr, key = a hash of the filled height field (delete them
// after changing what the renderer converges to).
// Test renders: fixed 8/16/32/64 spp and the demo's own `--time 3`, seeds 2.., each with its
// relative RMSE (whole image; sample; mount), CPU seconds, wall seconds and the load average.
// The reference's own noise adds to each figure (relMSE_measured = relMSE_test + relMSE_ref,
// independent seeds); the "corrected" columns subtract relMSE_ref, estimated from the two
// references' difference.
void DemoPreview(const fs::path& dir) {
  const char* scan = std::getenv("MESOSCAN_BENCH_DEMO_SCAN");
  if (!scan) {
    std::cout << "demo preview: skipped (set MESOSCAN_BENCH_DEMO_SCAN to the demo's coin.scan; "
                 "bench/demo_preview.sh does)\n";
    return;
  }
  const int ref_spp = std::getenv("MESOSCAN_BENCH_DEMO_REF_SPP")
                          ? std::atoi(std::getenv("MESOSCAN_BENCH_DEMO_REF_SPP"))
                          : 1024;
  double c0 = CpuNow(), t0 = Now();
  HeightField hf = ReadHeightExr(fs::path(scan) / "height.exr");
  hf = FillHoles(hf, FillOptions{}).field;
  const auto ggx = GgxBrdf<double>::Conductor(0.25, Rgb(0.27, 0.68, 1.22), Rgb(3.61, 2.63, 2.29));
  const fs::path merl = dir / "demo_ggx_copper_merl.binary";
  MerlBrdf::Tabulate([&](const Vec3& wo, const Vec3& wi) { return ggx.f(wo, wi); })->Write(merl);
  const Brdf brdf = LoadBrdf(merl);
  const EnvironmentMap env = EnvironmentMap::Sky(25, 200);
  std::printf(
      "demo preview: set-up (read + fill + tabulate/write/load the MERL table + sky) %.2f s "
      "wall, %.2f CPU s\n",
      Now() - t0, CpuNow() - c0);
  RenderOptions o;
  o.width = 480;
  o.height = 360;
  o.noise = 0;
  o.seed = 1;
  o.min_spp = o.max_spp = ref_spp;
  // Two independent references (seeds 1 and 1001, ref_spp each), cached; the test renders are
  // measured against their mean, and the mean's own noise is estimated from their difference
  // (per pixel, var(mean) = (Y_a - Y_b)^2 / 4 in expectation), so the "corrected" figure is
  // sqrt(relMSE_measured - relMSE_ref) with no assumption about the sampler's convergence rate.
  // The cache is keyed by the height field (FNV-1a of its floats): a re-made demo scan differs
  // bit for bit, and a reference of another scan would be measured as error.
  uint64_t key = 1469598103934665603ull;
  for (const float z : hf.z.data()) {
    uint32_t b;
    std::memcpy(&b, &z, 4);
    for (int i = 0; i < 4; ++i) key = (key ^ ((b >> (8 * i)) & 0xFF)) * 1099511628211ull;
  }
  char tag[24];
  std::snprintf(tag, sizeof tag, "_%016llx", static_cast<unsigned long long>(key));
  const fs::path mask_file = dir / ("demo_ref_mask" + std::string(tag) + ".exr");
  std::printf("demo preview: height field key %s\n", tag + 1);
  ImageF refs[2], mask;
  for (int k = 0; k < 2; ++k) {
    const fs::path ref_file = dir / ("demo_ref_" + std::to_string(ref_spp) + "spp" +
                                     (k ? "_seed1001" : "") + tag + ".exr");
    if (fs::exists(ref_file) && fs::exists(mask_file)) {
      refs[k] = ReadImage(ref_file);
      if (k == 0) mask = ReadImage(mask_file);
      std::printf("demo preview: reference %s (cached)\n", ref_file.c_str());
      continue;
    }
    o.seed = k ? 1001 : 1;
    c0 = CpuNow(), t0 = Now();
    RenderResult r = Render(hf, brdf, env, o);
    std::printf("demo preview: reference %d spp, seed %d in %.1f s wall, %.1f CPU s (load %s)\n",
                ref_spp, static_cast<int>(o.seed), Now() - t0, CpuNow() - c0, LoadAvg().c_str());
    refs[k] = std::move(r.radiance);
    WriteExr(ref_file, refs[k], {"R", "G", "B"});
    if (k == 0) {
      mask = std::move(r.sample_mask);
      WriteExr(mask_file, mask, {"Y"});
    }
  }
  ImageF ref = refs[0];
  double ref_var = 0, ref_sum = 0;  // sum over pixels of var(mean reference); of its luminance
  for (size_t i = 0; i < ref.pixels(); ++i) {
    const double a =
        Luminance(Rgb(refs[0].channel(0)[i], refs[0].channel(1)[i], refs[0].channel(2)[i]));
    const double b =
        Luminance(Rgb(refs[1].channel(0)[i], refs[1].channel(1)[i], refs[1].channel(2)[i]));
    ref_var += 0.25 * (a - b) * (a - b);
    ref_sum += 0.5 * (a + b);
    for (int c = 0; c < 3; ++c)
      ref.channel(c)[i] = 0.5f * (refs[0].channel(c)[i] + refs[1].channel(c)[i]);
  }
  // relMSE of the mean reference (whole image), and of one reference alone (twice that).
  const double ref_mse =
      ref_var / ref.pixels() / ((ref_sum / ref.pixels()) * (ref_sum / ref.pixels()));
  std::printf(
      "demo preview: reference = mean of the two: its own relRMSE %.4f (one reference "
      "alone %.4f; the two differ by relRMSE %.4f)\n",
      std::sqrt(ref_mse), std::sqrt(2 * ref_mse), RelRmse(refs[0], refs[1]));
  std::ofstream csv(dir / "demo_preview.csv");
  csv << "run,spp,relrmse,relrmse_sample,relrmse_mount,relrmse_corrected,display_relrmse,cpu_s,"
         "wall_s,cpu_s_per_spp,load,denoised_relrmse,denoised_relrmse_corrected,denoised_display_"
         "relrmse,"
         "denoise_wall_s\n";
  const ToneMapping ref_tone = MeterExposure(ref, &mask);
  struct Run {
    std::string name;
    int spp;
    double time_s;
  };
  // "no-guide": the same spp with BRDF sampling alone (without the mirrored-environment
  // sampler, render/mirror_guide.h), same seed as the fixed run before it: the before/after.
  // "alloc": the same mean spp with the samples allocated by the error (RenderOptions::
  // allocate_spp: a uniform 8 spp pilot, then by the neighbourhood's deviation), same seed as
  // the fixed run of that spp: the before/after at equal cost, independent of the load.
  // "uniform": as "denoise" with uniform rounds (allocate_pilot_spp = 0), the before.
  // "no-resample": the fixed 16 spp run (same seed) without the resampled first continuation
  // (RenderOptions::resample_candidates): the before/after.
  std::vector<Run> runs = {{"fixed", 64, 0},    {"fixed", 8, 0},        {"fixed", 16, 0},
                           {"alloc", 16, 0},    {"no-resample", 16, 0}, {"fixed", 32, 0},
                           {"alloc", 32, 0},    {"no-guide", 32, 0},    {"time 3 s", 0, 3.0},
                           {"uniform", 0, 3.0}, {"denoise", 0, 3.0}};
  // "denoise": as `render --time 3 --denoise` (the denoiser's time comes out of the budget;
  // its wall time is the render's plus the denoiser's). Every run also reports the denoised
  // figure (render/denoise.h) next to its raw one.
  // MESOSCAN_BENCH_DEMO_RUNS="32,time" keeps only the runs named (spp of the fixed runs,
  // "no-guide", "no-resample", "time", "denoise"): a quicker loop while tuning (the corrected
  // column needs the 64 spp run).
  if (const char* keep = std::getenv("MESOSCAN_BENCH_DEMO_RUNS")) {
    std::vector<Run> kept;
    std::string list = std::string(",") + keep + ",";
    for (const Run& r : runs) {
      const std::string key = r.name == "denoise" || r.name == "uniform" ? r.name
                              : r.time_s > 0                             ? "time"
                              : r.name == "alloc" ? "alloc" + std::to_string(r.spp)
                              : r.name != "fixed" ? r.name
                                                  : std::to_string(r.spp);
      if (list.find("," + key + ",") != std::string::npos) kept.push_back(r);
    }
    // "allocN": an alloc run at N spp not in the list above (e.g. alloc8).
    for (size_t a = list.find(",alloc"); a != std::string::npos; a = list.find(",alloc", a + 1)) {
      const int n = std::atoi(list.c_str() + a + 6);
      bool listed = false;
      for (const Run& r : runs) listed = listed || (r.name == "alloc" && r.spp == n);
      if (n > 0 && !listed) kept.push_back({"alloc", n, 0});
    }
    runs = kept;
  }
  uint64_t seed = 2;
  // MESOSCAN_BENCH_DEMO_ALLOC="pilot,radius,floor,by_cost" overrides the allocation's settings
  // (for tuning).
  if (const char* a = std::getenv("MESOSCAN_BENCH_DEMO_ALLOC")) {
    int by_cost = 1;
    std::sscanf(a, "%d,%d,%lf,%d", &o.allocate_pilot_spp, &o.allocate_radius, &o.allocate_floor,
                &by_cost);
    o.allocate_by_cost = by_cost != 0;
    std::printf("demo preview: allocation pilot %d spp, radius %d, floor %g, by cost %d\n",
                o.allocate_pilot_spp, o.allocate_radius, o.allocate_floor, by_cost);
  }
  // MESOSCAN_BENCH_DEMO_DENOISE_ALLOC="tau,max": the denoiser-aware share
  // (RenderOptions::allocate_for_denoiser, allocate_denoise_*) in every allocated run (for
  // tuning; the "denoise" run, as `render --denoise`, always has it).
  if (const char* a = std::getenv("MESOSCAN_BENCH_DEMO_DENOISE_ALLOC")) {
    o.allocate_for_denoiser = true;
    std::sscanf(a, "%lf,%lf", &o.allocate_denoise_tau, &o.allocate_denoise_max);
    std::printf("demo preview: denoiser-aware allocation tau %g, max %g\n", o.allocate_denoise_tau,
                o.allocate_denoise_max);
  }
  const int default_pilot = o.allocate_pilot_spp;
  const bool denoiser_alloc = o.allocate_for_denoiser;
  // MESOSCAN_BENCH_DEMO_SPLIT=N: where the error of the demo's budget is. Two renders with
  // independent seeds at N spp allocated as under `--time` (reproducible, the load does not
  // enter), each denoised; per region (the mount; the height field by its first-hit normal's
  // tilt: the flat faces, the slopes, the coin's rim), the share of the image's relMSE of the
  // raw and of the denoised render, the denoised render's variance (from the two seeds'
  // difference) and its squared bias (the rest), and the raw variance the half-buffers predict.
  if (const char* split = std::getenv("MESOSCAN_BENCH_DEMO_SPLIT")) {
    RenderOptions so = o;
    so.time_limit_s = 0;
    so.noise = 0;
    so.allocate_spp = std::atof(split);

    so.min_spp = 1;
    so.max_spp = 1 << 16;
    RenderResult rr[2];
    for (int k = 0; k < 2; ++k) {
      so.seed = 500 + k;
      c0 = CpuNow(), t0 = Now();
      rr[k] = Render(hf, brdf, env, so);
      std::printf("demo split: seed %d, %.1f spp, render %.2f s wall, %.2f CPU s, load %s\n",
                  static_cast<int>(so.seed), rr[k].summary.mean_spp, Now() - t0, CpuNow() - c0,
                  LoadAvg().c_str());
    }
    auto lum = [](const ImageF& im, size_t i) {
      return Luminance(Rgb(im.channel(0)[i], im.channel(1)[i], im.channel(2)[i]));
    };
    double mean_ref = 0;
    for (size_t i = 0; i < ref.pixels(); ++i) mean_ref += lum(ref, i) / ref.pixels();
    const double norm = 1.0 / (mean_ref * mean_ref * ref.pixels());
    const char* names[] = {"mount", "tilt <5", "tilt 5-15", "tilt 15-30", "tilt 30-60", "tilt >60"};
    constexpr int kRegions = 6;
    std::vector<int> region(ref.pixels(), 0);
    for (size_t i = 0; i < ref.pixels(); ++i) {
      if (!(mask.data()[i] > 0.5f)) continue;
      const ImageF& nrm = rr[0].normal;
      const double nx = nrm.channel(0)[i], ny = nrm.channel(1)[i], nz = nrm.channel(2)[i];
      const double t =
          std::acos(std::clamp(
              std::abs(nz) / std::max(1e-12, std::sqrt(nx * nx + ny * ny + nz * nz)), 0.0, 1.0)) *
          180 / M_PI;
      region[i] = t < 5 ? 1 : t < 15 ? 2 : t < 30 ? 3 : t < 60 ? 4 : 5;
    }
    double npx[kRegions] = {}, raw[kRegions] = {}, hvar[kRegions] = {};
    for (size_t i = 0; i < ref.pixels(); ++i) {
      const int g = region[i];
      const double yr = lum(ref, i);
      const double rv = 0.25 * std::pow(lum(refs[0], i) - lum(refs[1], i), 2);
      npx[g] += 1;
      for (int k = 0; k < 2; ++k) {
        raw[g] += 0.5 * (std::pow(lum(rr[k].radiance, i) - yr, 2) - rv) * norm;
        hvar[g] += 0.5 * 0.25 * std::pow(lum(rr[k].half[0], i) - lum(rr[k].half[1], i), 2) * norm;
      }
    }
    double traw = 0;
    for (int g = 0; g < kRegions; ++g) traw += raw[g];
    std::printf(
        "demo split: raw relRMSE (corrected) %.4f; per region: pixels, raw relMSE x 1e4 "
        "(share), the half-buffers' variance estimate x 1e4\n",
        std::sqrt(std::max(0.0, traw)));
    for (int g = 0; g < kRegions; ++g)
      std::printf("demo split:   %-11s %6.2f%% raw %8.2f (%5.1f%%) half-var %8.2f\n", names[g],
                  100 * npx[g] / ref.pixels(), 1e4 * raw[g], 100 * raw[g] / traw, 1e4 * hvar[g]);
    // Denoiser variants: MESOSCAN_BENCH_DENOISE_VARIANTS="radius=16,window=3,eps=0.01;..."
    std::vector<std::string> variants = {""};
    if (const char* v = std::getenv("MESOSCAN_BENCH_DENOISE_VARIANTS")) {
      variants.clear();
      std::stringstream ss(v);
      for (std::string item; std::getline(ss, item, ';');) variants.push_back(item);
    }
    for (const std::string& var : variants) {
      DenoiseOptions dopt;
      std::stringstream ss(var);
      for (std::string kv; std::getline(ss, kv, ',');) {
        const size_t eq = kv.find('=');
        if (eq == std::string::npos) continue;
        const std::string k = kv.substr(0, eq);
        const double val = std::atof(kv.c_str() + eq + 1);
        if (k == "radius")
          dopt.max_radius = static_cast<int>(val);
        else if (k == "window")
          dopt.window = static_cast<int>(val);
        else if (k == "eps")
          dopt.eps = val;
        else if (k == "blend")
          dopt.blend = static_cast<int>(val);
        else if (k == "jbf")
          dopt.bilateral = static_cast<int>(val);
        else if (k == "jbfsigma")
          dopt.bilateral_sigma = val;
        else if (k == "correct")
          dopt.half_variance_correction = val != 0;
        else if (k == "c")
          dopt.correction = val;
        else
          std::printf("demo split: unknown denoiser option %s\n", k.c_str());
      }
      ImageF dd[2];
      double ts = 1e30, cs = 0;
      for (int k = 0; k < 2; ++k) {
        t0 = Now(), c0 = CpuNow();
        dd[k] = DenoisePreview(rr[k], dopt);
        ts = std::min(ts, Now() - t0);
        cs += 0.5 * (CpuNow() - c0);
      }
      double dn[kRegions] = {}, dvar[kRegions] = {};
      for (size_t i = 0; i < ref.pixels(); ++i) {
        const int g = region[i];
        const double yr = lum(ref, i);
        const double rv = 0.25 * std::pow(lum(refs[0], i) - lum(refs[1], i), 2);
        for (int k = 0; k < 2; ++k) dn[g] += 0.5 * (std::pow(lum(dd[k], i) - yr, 2) - rv) * norm;
        dvar[g] += 0.5 * std::pow(lum(dd[0], i) - lum(dd[1], i), 2) * norm;
      }
      double tdn = 0, tvar = 0;
      for (int g = 0; g < kRegions; ++g) tdn += dn[g], tvar += dvar[g];
      std::printf(
          "demo split: denoiser [%s] %.3f s wall (the faster of two), %.3f CPU s: relRMSE "
          "(corrected) %.4f = variance %.2f + "
          "bias^2 %.2f (x 1e4); per region dn (var, bias^2):",
          var.c_str(), ts, cs, std::sqrt(std::max(0.0, tdn)), 1e4 * tvar, 1e4 * (tdn - tvar));
      for (int g = 0; g < kRegions; ++g)
        std::printf(" %s %.2f (%.2f, %.2f);", names[g], 1e4 * dn[g], 1e4 * dvar[g],
                    1e4 * (dn[g] - dvar[g]));
      std::printf("\n");
    }
  }
  for (const Run& run : runs) {
    o.mirror_guide = run.name != "no-guide";
    o.resample_candidates = run.name == "no-resample" ? 0 : RenderOptions{}.resample_candidates;
    if (o.mirror_guide && run.name != "alloc" && run.name != "no-resample") o.seed = seed++;
    o.allocate_spp = run.name == "alloc" ? run.spp : 0;
    o.allocate_pilot_spp = run.name == "uniform" ? 0 : default_pilot;
    o.allocate_for_denoiser = denoiser_alloc || run.name == "denoise";  // as render --denoise
    double reserve_wall = 0;  // measuring the denoiser's reserve (part of the run's wall time)
    if (run.time_s > 0) {     // as `render --time 3`: adaptive, no sample cap
      o.time_limit_s = run.time_s;
      if (run.name == "denoise" || run.name == "uniform") {
        const double tr = Now();
        const double reserve = MeasureDenoiseTimeReserve(o.width, o.height, run.time_s);
        o.time_limit_s -= reserve;
        std::printf(
            "demo preview: %-8s denoiser's reserve measured %.3f s (the fixed figure %.3f s)\n",
            run.name.c_str(), reserve, DenoiseTimeReserve(o.width, o.height, run.time_s));
        reserve_wall = Now() - tr;
      }
      o.noise = 0.01;
      o.min_spp = 16;
      o.max_spp = 1 << 16;
    } else {
      o.time_limit_s = 0;
      o.noise = 0;
      o.min_spp = o.max_spp = run.spp;
      if (run.name == "alloc") o.min_spp = 1, o.max_spp = 1 << 16;
    }
    c0 = CpuNow(), t0 = Now();
    const RenderResult r = Render(hf, brdf, env, o);
    const double wall = Now() - t0 + reserve_wall, cpu = CpuNow() - c0;
    const double e = RelRmseMasked(r.radiance, ref, mask, 0);
    const double es = RelRmseMasked(r.radiance, ref, mask, 1);
    const double em = RelRmseMasked(r.radiance, ref, mask, 2);
    const double corrected = std::sqrt(std::max(0.0, e * e - ref_mse));
    const double spp = r.summary.mean_spp;
    const double ed = DisplayRelRmse(r.radiance, ref, ref_tone);
    std::printf(
        "demo preview: %-8s %6.1f spp: relRMSE %.4f (sample %.4f, mount %.4f; %.4f without "
        "the reference's noise), display %.4f, in %.2f s wall, %.2f CPU s (%.3f CPU s/spp), "
        "load %s\n",
        run.name.c_str(), spp, e, es, em, corrected, ed, wall, cpu, cpu / spp, LoadAvg().c_str());
    const std::string png_stem =
        "demo_" + std::to_string(static_cast<int>(std::lround(spp))) + "spp" +
        (o.mirror_guide ? "" : "_noguide") +
        (run.name == "alloc" || run.name == "uniform" ? "_" + run.name : "");
    // The optional denoise stage (render/denoise.h, `render --denoise`): its error against the
    // same reference, bias included, next to the raw figure above. Never in the Cycles tables.
    double dn_e = 0, dn_ed = 0, dn_s = 0, dn_corrected = 0;
    {
      const double c1 = CpuNow(), t1 = Now();
      const ImageF dn = DenoisePreview(r);
      dn_s = Now() - t1;
      dn_e = RelRmseMasked(dn, ref, mask, 0);
      dn_corrected = std::sqrt(std::max(0.0, dn_e * dn_e - ref_mse));
      dn_ed = DisplayRelRmse(dn, ref, ref_tone);
      std::printf(
          "demo preview: %-8s %6.1f spp: denoised relRMSE %.4f (%.4f without the "
          "reference's noise; sample %.4f, mount %.4f; raw %.4f), display %.4f; denoise %.3f s "
          "wall, %.3f CPU s; render + denoise "
          "%.2f s wall\n",
          run.name.c_str(), spp, dn_e, dn_corrected, RelRmseMasked(dn, ref, mask, 1),
          RelRmseMasked(dn, ref, mask, 2), e, dn_ed, dn_s, CpuNow() - c1, wall + dn_s);
      if (std::getenv("MESOSCAN_BENCH_DEMO_EXR")) {  // for a look at the error maps
        const std::string stem = "demo_" + std::to_string(static_cast<int>(std::lround(spp))) +
                                 "spp_" + (run.name == "fixed" ? std::string("") : run.name + "_");
        WriteExr(dir / (stem + "denoised.exr"), dn, {"R", "G", "B"});
        WriteExr(dir / (stem + "raw.exr"), r.radiance, {"R", "G", "B"});
      }
      WritePng8(dir / (png_stem + "_denoised.png"), ToneMapForDisplay(dn, r.tone));
    }
    csv << run.name << "," << spp << "," << e << "," << es << "," << em << "," << corrected << ","
        << ed << "," << cpu << "," << wall << "," << cpu / spp << "," << LoadAvg() << "," << dn_e
        << "," << dn_corrected << "," << dn_ed << "," << dn_s << "\n";
    WritePng8(dir / (png_stem + ".png"), ToneMapForDisplay(r.radiance, r.tone));
  }
  // "cli": what `make demo` shows, measured as it runs: scripts/demo's render command (without the
  // turntable) as a process of its own, seed 2 (seed 1 is a reference's: its first samples are
  // the reference's own), preview.exr and preview_denoised.exr read back and measured against
  // the reference; the process's wall and CPU time (scan read, hole filling, the MERL table,
  // module loads, the denoiser's reserve, render, denoise, writing) and the render's own figures
  // from its log. In MESOSCAN_BENCH_DEMO_RUNS as "cli" (on by default); MESOSCAN_BENCH_DEMO_CLI
  // names another build's binary.
  const char* keep = std::getenv("MESOSCAN_BENCH_DEMO_RUNS");
  if (!keep || (std::string(",") + keep + ",").find(",cli,") != std::string::npos) {
    // MESOSCAN_BENCH_DEMO_CLI: another build's mesoscan (an A/B in one run).
    const char* other = std::getenv("MESOSCAN_BENCH_DEMO_CLI");
    const fs::path mesoscan =
        other ? fs::path(other)
              : fs::read_symlink("/proc/self/exe").parent_path().parent_path() / "app" / "mesoscan";
    const fs::path out = dir / "demo_cli_render", log = dir / "demo_cli_render.log";
    const std::string cmd = "'" + mesoscan.string() + "' render '" + scan + "' --out '" +
                            out.string() + "' --brdf ggx-merl --env sky --size 480x360 --time 3 " +
                            "--denoise --seed 2 --mount sample --albedo none > '" + log.string() +
                            "' 2>&1";
    struct rusage ru0, ru1;
    getrusage(RUSAGE_CHILDREN, &ru0);
    t0 = Now();
    const int status = std::system(cmd.c_str());
    const double wall = Now() - t0;
    getrusage(RUSAGE_CHILDREN, &ru1);
    auto secs = [](const timeval& a, const timeval& b) {
      return (b.tv_sec - a.tv_sec) + 1e-6 * (b.tv_usec - a.tv_usec);
    };
    const double cpu = secs(ru0.ru_utime, ru1.ru_utime) + secs(ru0.ru_stime, ru1.ru_stime);
    if (status != 0) {
      std::printf("demo preview: cli      failed (status %d), see %s\n", status, log.c_str());
      return;
    }
    // The render's own line: "render: N paths in S s (M spp on average, ...", and the denoiser's.
    std::ifstream in(log);
    std::string line;
    double spp = 0, render_s = 0, denoise_s = 0;
    while (std::getline(in, line)) {
      size_t at = line.find(" paths in ");
      if (line.rfind("render: ", 0) == 0 && at != std::string::npos)
        std::sscanf(line.c_str() + at, " paths in %lf s (%lf spp", &render_s, &spp);
      at = line.find("render: denoised in ");
      if (at != std::string::npos)
        std::sscanf(line.c_str() + at, "render: denoised in %lf", &denoise_s);
    }
    const ImageF raw = ReadImage(out / "preview.exr"), dn = ReadImage(out / "preview_denoised.exr");
    const double e = RelRmseMasked(raw, ref, mask, 0), dn_e = RelRmseMasked(dn, ref, mask, 0);
    const double corrected = std::sqrt(std::max(0.0, e * e - ref_mse));
    const double dn_corrected = std::sqrt(std::max(0.0, dn_e * dn_e - ref_mse));
    std::printf(
        "demo preview: cli      %6.1f spp: denoised relRMSE %.4f (%.4f without the "
        "reference's noise; sample %.4f, mount %.4f), raw %.4f (%.4f), display %.4f / %.4f; "
        "render %.2f s + denoise and its writes %.2f s; the process %.2f s wall, %.2f CPU s, "
        "load %s\n",
        spp, dn_e, dn_corrected, RelRmseMasked(dn, ref, mask, 1), RelRmseMasked(dn, ref, mask, 2),
        e, corrected, DisplayRelRmse(raw, ref, ref_tone), DisplayRelRmse(dn, ref, ref_tone),
        render_s, denoise_s, wall, cpu, LoadAvg().c_str());
    csv << "cli," << spp << "," << e << "," << RelRmseMasked(raw, ref, mask, 1) << ","
        << RelRmseMasked(raw, ref, mask, 2) << "," << corrected << ","
        << DisplayRelRmse(raw, ref, ref_tone) << "," << cpu << "," << wall << ","
        << cpu / std::max(spp, 1e-9) << "," << LoadAvg() << "," << dn_e << "," << dn_corrected
        << "," << DisplayRelRmse(dn, ref, ref_tone) << "," << denoise_s << "\n";
  }
}

// bench_render --compare REF.exr TEST.exr [MASK.exr]: the relative RMSE of TEST against REF
// (luminance, whole image), for renders made by another build (e.g. main's `mesoscan render`).
int CompareExr(const char* ref_path, const char* test_path, const char* mask_path) {
  const ImageF ref = ReadImage(ref_path), test = ReadImage(test_path);
  if (mask_path) {  // the reference's sample mask (demo_ref_mask.exr): sample / mount split
    const ImageF mask = ReadImage(mask_path);
    std::printf("relRMSE sample %.5f mount %.5f\n", RelRmseMasked(test, ref, mask, 1),
                RelRmseMasked(test, ref, mask, 2));
    const Stats a = RegionMeans(test, mask), b = RegionMeans(ref, mask);
    std::printf("mean luminance test / reference - 1: sample %+.3f%%, mount %+.3f%%\n",
                100 * (a.mean_sample / b.mean_sample - 1), 100 * (a.mean_mount / b.mean_mount - 1));
  }
  if (ref.width() != test.width() || ref.height() != test.height()) {
    std::cerr << "bench_render --compare: sizes differ\n";
    return 2;
  }
  std::printf("relRMSE %.5f\n", RelRmse(test, ref));
  // Where the error is: MESOSCAN_BENCH_COMPARE_MAP=FILE.png writes |Y - Y_ref| per pixel,
  // log-scaled from 1e-3 (black) to 10 (white) times the reference's mean luminance.
  if (const char* map = std::getenv("MESOSCAN_BENCH_COMPARE_MAP")) {
    double m = 0;
    for (size_t i = 0; i < ref.pixels(); ++i)
      m += Luminance(Rgb(ref.channel(0)[i], ref.channel(1)[i], ref.channel(2)[i])) / ref.pixels();
    ImageF e(ref.width(), ref.height(), 1);
    for (size_t i = 0; i < ref.pixels(); ++i) {
      const double a = Luminance(Rgb(test.channel(0)[i], test.channel(1)[i], test.channel(2)[i]));
      const double b = Luminance(Rgb(ref.channel(0)[i], ref.channel(1)[i], ref.channel(2)[i]));
      const double r = std::abs(a - b) / std::max(m, 1e-30);
      e.channel(0)[i] =
          static_cast<float>(std::clamp((std::log10(std::max(r, 1e-3)) + 3) / 4, 0.0, 1.0));
    }
    WritePng8(map, QuantizeU8(e));
    std::printf("error map (|dY| / mean Y_ref, log 1e-3..10): %s\n", map);
  }
  // Where the squared error sits: the share of the worst 0.1% / 1% / 10% of the pixels.
  std::vector<double> se(ref.pixels());
  double total = 0, mean_ref = 0;
  for (size_t i = 0; i < ref.pixels(); ++i) {
    const double a = Luminance(Rgb(test.channel(0)[i], test.channel(1)[i], test.channel(2)[i]));
    const double b = Luminance(Rgb(ref.channel(0)[i], ref.channel(1)[i], ref.channel(2)[i]));
    se[i] = (a - b) * (a - b);
    total += se[i];
    mean_ref += b / ref.pixels();
  }
  double mean_test = 0;
  for (size_t i = 0; i < ref.pixels(); ++i)
    mean_test +=
        Luminance(Rgb(test.channel(0)[i], test.channel(1)[i], test.channel(2)[i])) / ref.pixels();
  std::printf("mean luminance: reference %.6g, test %.6g\n", mean_ref, mean_test);
  if (std::getenv("MESOSCAN_BENCH_COMPARE_WORST")) {
    std::vector<size_t> idx(se.size());
    for (size_t i = 0; i < idx.size(); ++i) idx[i] = i;
    std::partial_sort(idx.begin(), idx.begin() + 30, idx.end(),
                      [&](size_t a, size_t b) { return se[a] > se[b]; });
    for (int k = 0; k < 30; ++k) {
      const size_t i = idx[k];
      std::printf(
          "  x %zu y %zu: test %.4g ref %.4g (mean ref %.4g)\n", i % ref.width(), i / ref.width(),
          Luminance(Rgb(test.channel(0)[i], test.channel(1)[i], test.channel(2)[i])),
          Luminance(Rgb(ref.channel(0)[i], ref.channel(1)[i], ref.channel(2)[i])), mean_ref);
    }
  }
  std::sort(se.begin(), se.end(), std::greater<double>());
  for (const double f : {0.001, 0.01, 0.1}) {
    double part = 0;
    for (size_t i = 0; i < static_cast<size_t>(f * se.size()); ++i) part += se[i];
    std::printf("worst %.1f%% of the pixels: %.1f%% of the squared error\n", 100 * f,
                100 * part / total);
  }
  // Display-space error: both images through the reference's tone curve (what one sees).
  const DisplayError display = DisplayRmse(test, ref, MeterExposure(ref));
  std::printf(
      "display (sRGB 8-bit, reference tone curve): RMSE %.2f of 255, relative to the mean %.4f\n",
      display.rmse, display.relative());
  return 0;
}

void Run() {
  std::setvbuf(stdout, nullptr, _IOLBF, 0);
  Progress::SetEnabled(false);
  ThreadLimit limit(2);
  const fs::path dir =
      fs::path(std::getenv("MESOSCAN_BENCH_OUT") ? std::getenv("MESOSCAN_BENCH_OUT") : ".") /
      "render";
  fs::create_directories(dir);
  int W = 320, H = 240;
  if (const char* s = std::getenv("MESOSCAN_BENCH_RENDER_SIZE")) std::sscanf(s, "%dx%d", &W, &H);
  const int ref_spp = std::getenv("MESOSCAN_BENCH_REF_SPP")
                          ? std::atoi(std::getenv("MESOSCAN_BENCH_REF_SPP"))
                          : 1024;
  const int test_spp = 128;
  const char* only = std::getenv("MESOSCAN_BENCH_RENDER_SCENES");  // e.g. "relief,slab-hole,demo"
  if (!only || std::string(only).find("demo") != std::string::npos) DemoPreview(dir);

  // Environment.
  fs::path env_path = EnvironmentMap::NamedPath("studio");
  std::string env_name = "studio.exr (blender-data)";
  if (env_path.empty()) {
    const EnvironmentMap sky = EnvironmentMap::Sky();
    env_path = dir / "sky.exr";
    WriteExr(env_path, sky.image(), {"R", "G", "B"});
    env_name = "procedural sky";
  }
  const EnvironmentMap env = EnvironmentMap::Load(env_path);
  const Brdf lambert(LambertBrdf(Rgb::Constant(0.7)));
  const bool blender = HaveBlender();
  std::cout << "bench_render: " << W << "x" << H << ", Lambert 0.7 on a 0.3 mount, " << env_name
            << ", reference " << ref_spp << " spp, test " << test_spp << " spp, 2 threads, load "
            << LoadAvg() << (blender ? "" : "; blender not found: Cycles columns skipped") << "\n";
  std::ofstream csv(dir / "render.csv");
  csv << "scene,bias_sample_pct,bias_mount_pct,mesoscan_relrmse,mesoscan_s,cycles_relrmse,cycles_s,"
         "efficiency_ratio,mesoscan_paths_per_s,cycles_paths_per_s,load\n";

  for (const SceneDef& sc : MakeScenes()) {
    if (only && std::string(only).find(sc.name) == std::string::npos) continue;
    RenderOptions o;
    o.width = W;
    o.height = H;
    o.noise = 0;
    o.camera = FramingCamera(sc.hf, W, H);
    o.fov_deg = 30;
    o.seed = 1;
    // mesoscan reference and test.
    o.min_spp = o.max_spp = ref_spp;
    const RenderResult mref = Render(sc.hf, lambert, env, o);
    o.min_spp = o.max_spp = test_spp;
    o.seed = 2;
    const double t0 = Now();
    const RenderResult mtest = Render(sc.hf, lambert, env, o);
    const double m_s = Now() - t0;
    WriteExr(dir / (sc.name + "_mesoscan_ref.exr"), mref.radiance, {"R", "G", "B"});
    WritePng8(dir / (sc.name + "_mesoscan_" + std::to_string(test_spp) + ".png"),
              ToneMapForDisplay(mtest.radiance, mref.tone));
    const double m_err = RelRmse(mtest.radiance, mref.radiance);
    const Stats ms = RegionMeans(mref.radiance, mref.sample_mask);
    std::printf(
        "%-11s mesoscan: %d spp relRMSE %.4f in %.2f s (%.2f M paths/s); ref sample %.5g mount "
        "%.5g\n",
        sc.name.c_str(), test_spp, m_err, m_s, double(W) * H * test_spp / m_s / 1e6, ms.mean_sample,
        ms.mean_mount);
    double c_err = NAN, c_s = NAN, bias_s = NAN, bias_m = NAN;
    if (blender) {
      // The scene for Blender: raw float32 heights + JSON.
      const fs::path raw = dir / (sc.name + "_height.f32");
      {
        std::ofstream f(raw, std::ios::binary);
        f.write(reinterpret_cast<const char*>(sc.hf.z.data().data()),
                sc.hf.z.pixels() * sizeof(float));
      }
      double zmin = 1e30;
      for (float z : sc.hf.z.data())
        if (std::isfinite(z)) zmin = std::min(zmin, double(z));
      const double extent = std::max(sc.hf.width(), sc.hf.height()) * sc.hf.pixel_size;
      Json base = {{"grid_width", sc.hf.width()},
                   {"grid_height", sc.hf.height()},
                   {"height_raw", fs::absolute(raw).string()},
                   {"x0", sc.hf.x0},
                   {"y0", sc.hf.y0},
                   {"pixel_size", sc.hf.pixel_size},
                   {"albedo", {0.7, 0.7, 0.7}},
                   {"mount_albedo", {0.3, 0.3, 0.3}},
                   {"plane_z", std::min(0.0, zmin) - 1e-6},
                   {"plane_half_size", 10 * extent + 1.0},
                   {"eye", {o.camera->eye.x(), o.camera->eye.y(), o.camera->eye.z()}},
                   {"target", {o.camera->target.x(), o.camera->target.y(), o.camera->target.z()}},
                   {"fov_deg", 30.0},
                   {"env_exr", fs::absolute(env_path).string()},
                   {"env_rotation_deg", 0.0},
                   {"max_depth", o.max_depth},
                   {"threads", 2},
                   {"width", W},
                   {"height", H},
                   {"seed", 1}};
      ImageF cref, ctest;
      const double cr = RenderCycles(dir, sc.name + "_ref", sc, base, ref_spp, &cref);
      base["seed"] = 2;
      c_s = RenderCycles(dir, sc.name + "_" + std::to_string(test_spp), sc, base, test_spp, &ctest);
      if (std::isfinite(cr) && std::isfinite(c_s)) {
        c_err = RelRmse(ctest, cref);
        const Stats cs = RegionMeans(cref, mref.sample_mask);
        bias_s = 100 * (ms.mean_sample / cs.mean_sample - 1);
        bias_m = 100 * (ms.mean_mount / cs.mean_mount - 1);
        WritePng8(dir / (sc.name + "_cycles_" + std::to_string(test_spp) + ".png"),
                  ToneMapForDisplay(ctest, mref.tone));
        // Signed difference image of the references (grey = 0, +-10% of the sample mean = full).
        ImageF diff(W, H, 3);
        for (size_t i = 0; i < diff.pixels(); ++i) {
          const double d =
              (Luminance(Rgb(mref.radiance.channel(0)[i], mref.radiance.channel(1)[i],
                             mref.radiance.channel(2)[i])) -
               Luminance(Rgb(cref.channel(0)[i], cref.channel(1)[i], cref.channel(2)[i]))) /
              (0.1 * ms.mean_sample);
          diff.channel(0)[i] = static_cast<float>(std::clamp(0.5 + 0.5 * d, 0.0, 1.0));
          diff.channel(1)[i] = 0.5f;
          diff.channel(2)[i] = static_cast<float>(std::clamp(0.5 - 0.5 * d, 0.0, 1.0));
        }
        WritePng8(dir / (sc.name + "_ref_difference.png"), QuantizeU8(diff));
        std::printf(
            "%-11s cycles:   %d spp relRMSE %.4f in %.2f s (%.2f M paths/s); ref sample %.5g mount "
            "%.5g\n",
            sc.name.c_str(), test_spp, c_err, c_s, double(W) * H * test_spp / c_s / 1e6,
            cs.mean_sample, cs.mean_mount);
      }
    }
    const double ratio = (c_err * c_err * c_s) / (m_err * m_err * m_s);
    std::printf(
        "%-11s bias vs Cycles: sample %+.2f%%, mount %+.2f%%; efficiency ratio %.2f (load %s)\n",
        sc.name.c_str(), bias_s, bias_m, ratio, LoadAvg().c_str());
    csv << sc.name << "," << bias_s << "," << bias_m << "," << m_err << "," << m_s << "," << c_err
        << "," << c_s << "," << ratio << "," << double(W) * H * test_spp / m_s << ","
        << double(W) * H * test_spp / c_s << "," << LoadAvg() << "\n";
  }

  // Raw Embree throughput on the coin next to the tracer's paths/s.
  if (!only || std::string(only).find("embree") != std::string::npos) {
    const HeightField hf = MakeScenes()[0].hf;
    EmbreeScene scene;
    scene.AddHeightField(hf);
    scene.AddPlane(-1e-6, 10.0);
    scene.Commit();
    const CameraSpec cam = FramingCamera(hf, W, H);
    const int n = 2000000;
    std::vector<Vec3> dirs(4096);
    std::mt19937 rng(1);
    std::uniform_real_distribution<double> u(-0.15, 0.15);
    const Vec3 fwd = (cam.target - cam.eye).normalized();
    for (auto& d : dirs) d = (fwd + Vec3(u(rng), u(rng), u(rng))).normalized();
    std::atomic<int64_t> hits{0};
    double t = Now();
    ParallelFor(
        n / 1000,
        [&](int64_t b) {
          int64_t local = 0;
          for (int k = 0; k < 1000; ++k)
            local += scene.Intersect(cam.eye, dirs[(b * 1000 + k) & 4095]).has_value();
          hits += local;
        },
        16);
    const double t_hit = Now() - t;
    t = Now();
    ParallelFor(
        n / 1000,
        [&](int64_t b) {
          int64_t local = 0;
          for (int k = 0; k < 1000; ++k)
            local += scene.Occluded(cam.eye, dirs[(b * 1000 + k) & 4095], 0, 1e30);
          hits += local;
        },
        16);
    const double t_occ = Now() - t;
    std::printf(
        "embree on the coin (2 threads): closest hit + double refinement %.2f M rays/s, occlusion "
        "%.2f M rays/s (load %s)\n",
        n / t_hit / 1e6, n / t_occ / 1e6, LoadAvg().c_str());
  }

  // What the skips save: a constant environment (no NEE, no shadow rays) against the same
  // radiance as a 64x32 image (importance-sampled); adaptive stopping against fixed spp.
  if (!only || std::string(only).find("skips") != std::string::npos) {
    const HeightField hf = MakeScenes()[0].hf;
    RenderOptions o;
    o.width = W / 2;
    o.height = H / 2;
    o.noise = 0;
    o.min_spp = o.max_spp = 64;
    const EnvironmentMap cst = EnvironmentMap::Constant(Rgb::Constant(1.0));
    ImageF flat(64, 32, 3, 1.0f);
    const EnvironmentMap img = EnvironmentMap::FromImage(flat);
    double t = Now();
    const RenderResult a = Render(hf, lambert, cst, o);
    const double ta = Now() - t;
    t = Now();
    const RenderResult b = Render(hf, lambert, img, o);
    const double tb = Now() - t;
    std::printf(
        "constant environment: %.2f s (not importance-sampled) vs %.2f s as an image map; "
        "relRMSE between them %.4f\n",
        ta, tb, RelRmse(a.radiance, b.radiance));
    // Adaptive: reference 1024 spp; fixed 256 spp vs adaptive (noise 0.01, cap 256).
    o.min_spp = o.max_spp = 1024;
    const RenderResult ref = Render(hf, lambert, env, o);
    o.min_spp = o.max_spp = 256;
    o.seed = 5;
    t = Now();
    const RenderResult fixed = Render(hf, lambert, env, o);
    const double tf = Now() - t;
    o.min_spp = 16;
    o.noise = 0.01;
    t = Now();
    const RenderResult adapt = Render(hf, lambert, env, o);
    const double tad = Now() - t;
    std::printf(
        "adaptive (noise 0.01 of the display range, 16..256 spp): %.2f s, %.1f spp mean, %lld of "
        "%d "
        "pixels stopped early, relRMSE %.4f; fixed 256 spp: %.2f s, relRMSE %.4f (load %s)\n",
        tad, adapt.summary.mean_spp, static_cast<long long>(adapt.summary.pixels_converged),
        o.width * o.height, RelRmse(adapt.radiance, ref.radiance), tf,
        RelRmse(fixed.radiance, ref.radiance), LoadAvg().c_str());
    // The mount the camera cannot see: a close-up inside the hole-free coin (camera rays skip
    // the plane) against the same render tracing it; the images must be identical. CPU time.
    RenderOptions oc;
    oc.width = W / 2;
    oc.height = H / 2;
    oc.noise = 0;
    oc.min_spp = oc.max_spp = 64;
    const Vec3 centre(hf.X(0.5 * (hf.width() - 1)), hf.Y(0.5 * (hf.height() - 1)), 0);
    oc.camera = CameraSpec{centre + Vec3(0, -4e-3, 8e-3), centre};
    oc.fov_deg = 20;
    double c0 = CpuNow();
    RenderSummary skipped, traced;
    const ImageF ia = RenderHeightField(hf, lambert, env, oc, &skipped);
    const double ca = CpuNow() - c0;
    oc.skip_invisible_mount = false;
    c0 = CpuNow();
    const ImageF ib = RenderHeightField(hf, lambert, env, oc, &traced);
    const double cb = CpuNow() - c0;
    bool same = true;
    for (int c = 0; c < 3; ++c)
      same = same && std::equal(ia.channel(c), ia.channel(c) + ia.pixels(), ib.channel(c));
    std::printf(
        "invisible mount (close-up inside the coin, 64 spp): %s; %.2f CPU s skipping the plane "
        "for camera rays vs %.2f CPU s tracing it, images %s (load %s)\n",
        skipped.mount_visible ? "NOT detected" : "detected", ca, cb, same ? "identical" : "DIFFER",
        LoadAvg().c_str());
  }
}

}  // namespace
}  // namespace mesoscan

int main(int argc, char** argv) {
  try {
    if ((argc == 4 || argc == 5) && std::string(argv[1]) == "--compare")
      return mesoscan::CompareExr(argv[2], argv[3], argc == 5 ? argv[4] : nullptr);
    mesoscan::Run();
  } catch (const std::exception& e) {
    std::cerr << "bench_render: " << e.what() << "\n";
    return 70;
  }
  return 0;
}
