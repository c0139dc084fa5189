// mesoscan render: a path-traced preview of a scan's height field with a BRDF (measured or
// analytic) under an environment map. Writes preview.exr (linear RGB) and preview.png.

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>

#include "app/commands.h"
#include "brdf/brdf.h"
#include "core/budget.h"
#include "core/error.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/output_dir.h"
#include "core/parallel.h"
#include "core/scan_folder.h"
#include "render/env_map.h"
#include "render/path_tracer.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

struct RenderArgs {
  std::string scan, out, brdf = "ggx-merl", env = "sky", size = "640x480";
  RenderOptions options;
  double sun_elevation_deg = 25, sun_azimuth_deg = 200, env_scale = 1.0;
  int threads = 0;
  bool force = false;
};

// "lambert", "ggx", "ggx-merl" (GGX tabulated into the MERL layout, written next to the
// preview and read back: the measured path with no external data), or a measured file.
Brdf MakeBrdf(const std::string& spec, const fs::path& tmp_dir) {
  if (spec == "lambert") return Brdf(LambertBrdf(Rgb::Constant(0.7)));
  // Warm copper-like conductor: a material whose highlights show relief clearly.
  const auto ggx = GgxBrdf<double>::Conductor(0.25, Rgb(0.27, 0.68, 1.22), Rgb(3.61, 2.63, 2.29));
  if (spec == "ggx") return Brdf(ggx);
  if (spec == "ggx-merl") {
    const fs::path file = tmp_dir / "ggx_copper_merl.binary";
    MerlBrdf::Tabulate([&](const Vec3& wo, const Vec3& wi) { return ggx.f(wo, wi); })->Write(file);
    return LoadBrdf(file);
  }
  if (!fs::exists(spec))
    MESOSCAN_BAD_INPUT(spec << ": --brdf: expected lambert, ggx, ggx-merl or a .binary/.bsdf file");
  return LoadBrdf(spec);
}

// Numbers Embree would assert on (NaN, inf, or magnitudes beyond float precision) are refused
// here with one line, before a scene is built.
void ValidateRenderNumbers(const RenderArgs& a, const RenderOptions& o) {
  const auto finite = [](const char* opt, double v, double limit) {
    if (!std::isfinite(v) || std::abs(v) > limit)
      MESOSCAN_THROW(ErrorKind::kUsage, "render: " << opt << ": expected a finite value of at most "
                                                   << limit << " in magnitude, got " << v);
  };
  finite("--azimuth", o.azimuth_deg, 1e6);
  finite("--elevation", o.elevation_deg, 90);
  finite("--relief", o.relief_scale, 1e6);
  finite("--rel-error", o.relative_error, 1e6);
  finite("--sun-elevation", a.sun_elevation_deg, 90);
  finite("--sun-azimuth", a.sun_azimuth_deg, 1e6);
  finite("--env-scale", a.env_scale, 1e12);
  // Budget before allocation: radiance, sums and variance per pixel (~64 bytes).
  CheckMemoryBudget("render: --size " + std::to_string(o.width) + "x" + std::to_string(o.height),
                    static_cast<double>(o.width) * o.height * 64.0, ErrorKind::kUsage);
}

void ValidateHeightField(const HeightField& hf, const RenderOptions& o, const std::string& file) {
  if (hf.width() < 2 || hf.height() < 2)
    MESOSCAN_BAD_INPUT(file << ": a " << hf.width() << "x" << hf.height()
                            << " height grid; rendering needs at least 2x2 samples");
  if (!std::isfinite(hf.x0) || !std::isfinite(hf.y0) || !(hf.pixel_size > 0) ||
      !std::isfinite(hf.pixel_size) || std::abs(hf.x0) > 1e6 || std::abs(hf.y0) > 1e6 ||
      hf.pixel_size > 1e3)
    MESOSCAN_BAD_INPUT(file << ": " << kAttrX0 << ", " << kAttrY0 << ", " << kAttrPixelSize
                            << " must be finite (|x0|, |y0| <= 1e6 m, 0 < pixel size <= 1e3 m), got "
                            << hf.x0 << ", " << hf.y0 << ", " << hf.pixel_size);
  // Relief-scaled heights stay within a float-friendly multiple of the field's extent.
  const double extent = std::max(hf.width(), hf.height()) * hf.pixel_size;
  double zmax = 0;
  for (const float z : hf.z.data())
    if (std::isfinite(z)) zmax = std::max(zmax, std::abs(static_cast<double>(z)));
  const double scaled = zmax * o.relief_scale;
  if (!std::isfinite(scaled) || scaled > 1e4 * extent)
    MESOSCAN_BAD_INPUT(file << ": heights up to " << zmax << " m times --relief " << o.relief_scale
                            << " exceed 1e4 times the field's " << extent << " m extent");
}

void Run(const RenderArgs& a) {
  ThreadLimit limit(a.threads);
  RenderOptions o = a.options;
  if (std::sscanf(a.size.c_str(), "%dx%d", &o.width, &o.height) != 2)
    MESOSCAN_THROW(ErrorKind::kUsage, "--size: expected WxH, got '" << a.size << "'");
  ValidateRenderNumbers(a, o);
  o.Check();
  const bool brdf_file = a.brdf != "lambert" && a.brdf != "ggx" && a.brdf != "ggx-merl";
  const bool env_file = a.env != "sky" && a.env != "constant";
  const OutputSpec out_spec{"render", "--out", a.out,
                            {a.scan, brdf_file ? a.brdf : "", env_file ? a.env : ""}, a.force,
                            {"preview.exr", "preview.png"}};
  CheckOutputFolder(out_spec);
  const HeightField hf = ReadHeightExr(fs::path(a.scan) / "height.exr");
  ValidateHeightField(hf, o, (fs::path(a.scan) / "height.exr").string());
  EnvironmentMap env = a.env == "sky" ? EnvironmentMap::Sky(a.sun_elevation_deg, a.sun_azimuth_deg)
                       : a.env == "constant" ? EnvironmentMap::Constant(Rgb::Constant(a.env_scale))
                                             : EnvironmentMap::Load(a.env, a.env_scale);
  RenderSummary summary;
  WriteOutputFolder(out_spec, [&](const fs::path& tmp) {
    const Brdf brdf = MakeBrdf(a.brdf, tmp);
    const ImageF radiance = RenderHeightField(hf, brdf, env, o, &summary);
    WriteExr(tmp / "preview.exr", radiance, {"R", "G", "B"});
    WritePng8(tmp / "preview.png", ToneMapForDisplay(radiance));
  });
  MESOSCAN_LOG(kInfo) << "render: " << summary.BriefReport();
  MESOSCAN_LOG(kInfo) << "render: wrote " << (fs::path(a.out) / "preview.png").string()
                      << " (display) and preview.exr (linear RGB)";
}

}  // namespace

void AddRenderCommand(CLI::App* app) {
  auto args = std::make_shared<RenderArgs>();
  auto* cmd = app->add_subcommand("render", "Path-traced preview of a scan with a BRDF under an environment map");
  cmd->add_option("scan", args->scan, "Scan folder (reads height.exr)")->required();
  cmd->add_option("--out", args->out, "Output folder for preview.png / preview.exr")->required();
  cmd->add_option("--brdf", args->brdf,
                  "lambert | ggx | ggx-merl (GGX tabulated in MERL layout) | FILE.binary | FILE.bsdf")
      ->capture_default_str();
  cmd->add_option("--env", args->env, "sky (procedural sun and sky) | constant | FILE.exr (lat-long)")
      ->capture_default_str();
  cmd->add_option("--env-scale", args->env_scale, "Radiance multiplier of the environment")
      ->capture_default_str();
  cmd->add_option("--sun-elevation", args->sun_elevation_deg, "Procedural sky: sun elevation, degrees")
      ->capture_default_str();
  cmd->add_option("--sun-azimuth", args->sun_azimuth_deg, "Procedural sky: sun azimuth, degrees")
      ->capture_default_str();
  cmd->add_option("--size", args->size, "Image size WxH")->capture_default_str();
  cmd->add_option("--spp", args->options.max_spp, "Maximum samples per pixel")->capture_default_str();
  cmd->add_option("--min-spp", args->options.min_spp, "Samples before a pixel may stop early")
      ->capture_default_str();
  cmd->add_option("--rel-error", args->options.relative_error,
                  "A pixel stops when its relative standard error is below this")
      ->capture_default_str();
  cmd->add_option("--elevation", args->options.elevation_deg, "Camera elevation, degrees")
      ->capture_default_str();
  cmd->add_option("--azimuth", args->options.azimuth_deg, "Camera azimuth, degrees")
      ->capture_default_str();
  cmd->add_option("--relief", args->options.relief_scale, "Height exaggeration factor")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "Worker threads (0 = all cores)");
  cmd->add_flag("--force", args->force,
                "Replace an existing --out that is not an earlier output of `mesoscan render`");
  cmd->callback([args] { Run(*args); });
}

}  // namespace mesoscan
