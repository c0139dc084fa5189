// mesoscan render: a path-traced preview of a scan's height field with a BRDF (measured or
// analytic) under an environment map. Writes preview.exr (linear RGB) and preview.png, updated
// after every sampling round of a long render (progressive), plus optional turntable frames,
// an animated GIF and a side-by-side comparison.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <future>
#include <optional>
#include <sstream>
#include <string>

#include "app/commands.h"
#include "brdf/brdf.h"
#include "core/budget.h"
#include "core/error.h"
#include "core/fs.h"
#include "core/image_io.h"
#include "core/json.h"
#include "core/log.h"
#include "core/output_dir.h"
#include "core/parallel.h"
#include "core/scan_folder.h"
#include "core/stage_timer.h"
#include "maps/export.h"
#include "maps/maps_fill.h"
#include "render/animation.h"
#include "render/denoise.h"
#include "render/env_map.h"
#include "render/path_tracer.h"
#include "render/ximgproc_module.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

struct RenderArgs {
  std::string scan, out, brdf = "ggx-merl", env = "sky", size = "640x480", camera, albedo = "none";
  std::string compare, compare_scan, turntable_size, fill = "harmonic";
  RenderOptions options;
  double sun_elevation_deg = 25, sun_azimuth_deg = 200, env_scale = 1.0, env_rotation_deg = 0;
  int threads = 0, turntable = 0, turntable_spp = 0;
  bool spp_given = false, min_spp_given = false;
  bool force = false;
  bool denoise = false;  // also write preview_denoised.exr/png (render/denoise.h)
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

// "eye=X,Y,Z:target=X,Y,Z:fov=DEG" (fov optional).
void ParseCamera(const std::string& spec, RenderOptions* o) {
  CameraSpec cam;
  bool have_eye = false, have_target = false;
  std::stringstream ss(spec);
  std::string part;
  while (std::getline(ss, part, ':')) {
    const auto eq = part.find('=');
    const std::string key = part.substr(0, eq),
                      val = eq == std::string::npos ? "" : part.substr(eq + 1);
    double a, b, c;
    char tail;
    if ((key == "eye" || key == "target") &&
        std::sscanf(val.c_str(), "%lf,%lf,%lf%c", &a, &b, &c, &tail) == 3) {
      (key == "eye" ? cam.eye : cam.target) = Vec3(a, b, c);
      (key == "eye" ? have_eye : have_target) = true;
    } else if (key == "fov" && std::sscanf(val.c_str(), "%lf%c", &a, &tail) == 1) {
      if (!(a > 0 && a < 180))
        MESOSCAN_THROW(ErrorKind::kUsage, "--camera: fov must be in (0, 180) degrees, got " << val);
      o->fov_deg = a;
    } else {
      MESOSCAN_THROW(ErrorKind::kUsage,
                     "--camera: expected eye=X,Y,Z:target=X,Y,Z[:fov=DEG] (metres, "
                     "degrees), could not read '"
                         << part << "'");
    }
  }
  if (!have_eye || !have_target)
    MESOSCAN_THROW(ErrorKind::kUsage, "--camera: both eye=X,Y,Z and target=X,Y,Z are required");
  o->camera = cam;
}

EnvironmentMap MakeEnvironment(const RenderArgs& a) {
  if (a.env == "sky") return EnvironmentMap::Sky(a.sun_elevation_deg, a.sun_azimuth_deg);
  if (a.env == "constant") return EnvironmentMap::Constant(Rgb::Constant(a.env_scale));
  for (const auto& name : EnvironmentMap::NamedEnvironments())
    if (a.env == name) {
      const fs::path p = EnvironmentMap::NamedPath(name);
      if (p.empty())
        MESOSCAN_BAD_INPUT("--env " << name
                                    << ": needs Debian's blender-data package "
                                       "(/usr/share/blender/datafiles/studiolights/world/"
                                    << name << ".exr); give a lat-long EXR/HDR file instead");
      return EnvironmentMap::Load(p, a.env_scale);
    }
  if (!fs::exists(a.env)) {
    std::string names;
    for (const auto& n : EnvironmentMap::NamedEnvironments()) names += n + "|";
    MESOSCAN_BAD_INPUT(a.env << ": --env: expected sky|constant|" << names << "FILE.exr|FILE.hdr");
  }
  return EnvironmentMap::Load(a.env, a.env_scale);
}

// The base colour map for --albedo: "none", "R,G,B", or "scan" (albedo.exr/png in the scan
// folder, else the session's white frame named by report.json). A relative albedo is
// normalised to median 1 (a tint of the BRDF's own colour), clamped to [0, 1.4]; holes -> 1.
std::optional<ImageF> MakeAlbedo(const RenderArgs& a, const HeightField& hf) {
  if (a.albedo == "none") return std::nullopt;
  double r, g, b;
  char tail;
  if (std::sscanf(a.albedo.c_str(), "%lf,%lf,%lf%c", &r, &g, &b, &tail) == 3) {
    if (!(r >= 0 && g >= 0 && b >= 0 && r <= 1 && g <= 1 && b <= 1))
      MESOSCAN_THROW(ErrorKind::kUsage, "--albedo: R,G,B must be in [0, 1], got " << a.albedo);
    ImageF im(hf.width(), hf.height(), 3);
    for (size_t i = 0; i < im.pixels(); ++i) {
      im.channel(0)[i] = static_cast<float>(r);
      im.channel(1)[i] = static_cast<float>(g);
      im.channel(2)[i] = static_cast<float>(b);
    }
    return im;
  }
  if (a.albedo != "scan")
    MESOSCAN_THROW(ErrorKind::kUsage,
                   "--albedo: expected scan, none or R,G,B, got '" << a.albedo << "'");
  ImageF alb;
  for (const char* f : {"albedo.exr", "albedo.png"})
    if (alb.pixels() == 0 && fs::exists(fs::path(a.scan) / f))
      alb = ReadImage(fs::path(a.scan) / f);
  if (alb.pixels() == 0) {
    const Json report = ReadJsonFile(fs::path(a.scan) / "report.json");
    if (!report.contains("session") || !report["session"].is_string())
      MESOSCAN_BAD_INPUT(
          a.scan << "/report.json: --albedo scan: no albedo.exr/png and no \"session\" "
                    "whose white frame gives one");
    fs::path session = report["session"].get<std::string>();
    if (session.is_relative() && !fs::exists(session)) session = fs::path(a.scan) / session;
    alb = AlbedoFromSession(hf, session);
  }
  if (alb.width() != hf.width() || alb.height() != hf.height())
    MESOSCAN_BAD_INPUT(a.scan << ": --albedo scan: the albedo is " << alb.width() << "x"
                              << alb.height() << ", the height grid " << hf.width() << "x"
                              << hf.height());
  const int nc = alb.channels() >= 3 ? 3 : 1;
  std::vector<float> lum;
  for (size_t i = 0; i < alb.pixels(); ++i)
    if (std::isfinite(alb.channel(0)[i]) && alb.channel(0)[i] > 0) lum.push_back(alb.channel(0)[i]);
  if (lum.empty())
    MESOSCAN_BAD_INPUT(a.scan << ": --albedo scan: the albedo has no positive sample");
  std::nth_element(lum.begin(), lum.begin() + lum.size() / 2, lum.end());
  const double median = lum[lum.size() / 2];
  ImageF tint(hf.width(), hf.height(), nc);
  for (int c = 0; c < nc; ++c)
    for (size_t i = 0; i < alb.pixels(); ++i) {
      const float v = alb.channel(c)[i];
      tint.channel(c)[i] =
          std::isfinite(v) ? static_cast<float>(std::clamp(v / median, 0.0, 1.4)) : 1.0f;
    }
  return tint;
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
  finite("--noise", o.noise, 1e6);
  finite("--time", o.time_limit_s, 1e7);
  finite("--sun-elevation", a.sun_elevation_deg, 90);
  finite("--sun-azimuth", a.sun_azimuth_deg, 1e6);
  finite("--env-scale", a.env_scale, 1e12);
  if (a.env_scale < 0)
    MESOSCAN_THROW(ErrorKind::kUsage,
                   "render: --env-scale: expected a radiance multiplier >= 0, got " << a.env_scale);
  finite("--env-rotation", a.env_rotation_deg, 1e6);
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
    MESOSCAN_BAD_INPUT(
        file << ": " << kAttrX0 << ", " << kAttrY0 << ", " << kAttrPixelSize
             << " must be finite (|x0|, |y0| <= 1e6 m, 0 < pixel size <= 1e3 m), got " << hf.x0
             << ", " << hf.y0 << ", " << hf.pixel_size);
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

void WritePreview(const fs::path& out, const RenderResult& r) {
  WriteExr(out / "preview.exr", r.radiance, {"R", "G", "B"}, {}, {}, "none");
  WritePng8(out / "preview.png", ToneMapForDisplay(r.radiance, r.tone));
}

// Everything the render writes, into `out` (the temporary folder that is swapped into place).
// Progressive previews land there too while a long render runs.
// The second scan of a side by side (--compare-scan, or --compare naming a scan folder).
struct CompareScan {
  HeightField hf;
  std::optional<ImageF> albedo;
};

// Two tone-mapped images next to each other, 4 white pixels apart.
ImageU8 SideBySide(const ImageU8& left, const ImageU8& right) {
  const int gap = 4, w = left.width(), h = left.height();
  ImageU8 both(2 * w + gap, h, 3, 255);
  for (int c = 0; c < 3; ++c)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        both(x, y, c) = left(x, y, c);
        both(w + gap + x, y, c) = right(x, y, c);
      }
  return both;
}

void RenderFolder(const RenderArgs& a, const HeightField& hf, const EnvironmentMap& env,
                  const RenderOptions& options, const fs::path& out,
                  const CompareScan* other_scan) {
  MESOSCAN_LOG(kInfo) << "render: progressive preview while sampling: "
                      << (out / "preview.png").string();
  const Brdf brdf = MakeBrdf(a.brdf, out);
  RenderOptions o = options;
  // --denoise within --time: the denoiser's share comes out of the budget, measured right before
  // the render (Run() loads the filters' module in the background meanwhile).
  if (a.denoise && o.time_limit_s > 0)
    o.time_limit_s -= MeasureDenoiseTimeReserve(o.width, o.height, o.time_limit_s);
  // The preview, if denoised, spends fewer samples where the denoiser averages many pixels
  // (the turntable's and side by side's frames are not denoised).
  RenderOptions preview = o;
  preview.allocate_for_denoiser = a.denoise;

  // Progressive output: preview.exr/png rewritten (atomically) after a round when at least 2 s
  // have passed since the last write and more than 2 s of a --time budget are left.
  auto last_write = std::chrono::steady_clock::now();
  const RenderResult result = Render(hf, brdf, env, preview, [&](const RenderResult& r) {
    const auto now = std::chrono::steady_clock::now();
    if (std::chrono::duration<double>(now - last_write).count() < 2.0) return;
    // Not when the final preview follows within 2 s anyway (a --time budget about to run out):
    // the write would come out of the budget (~0.05 s at 480 x 360).
    if (o.time_limit_s > 0 && o.time_limit_s - r.summary.seconds < 2.0) return;
    WritePreview(out, r);
    last_write = now;
  });
  WritePreview(out, result);
  MESOSCAN_LOG(kInfo) << "render: " << result.summary.BriefReport();
  if (a.denoise) {
    // The optional denoise stage: biased, so written beside the raw preview, never instead.
    const Stopwatch denoise_time;
    const ImageF dn = DenoisePreview(result);
    WriteExr(out / "preview_denoised.exr", dn, {"R", "G", "B"}, {}, {}, "none");
    WritePng8(out / "preview_denoised.png", ToneMapForDisplay(dn, result.tone));
    MESOSCAN_LOG(kInfo) << "render: denoised in " << denoise_time.Seconds()
                        << " s: preview_denoised.png / .exr (biased: edge-aware smoothing; the raw "
                           "render is preview.png / .exr)";
  }

  if (other_scan) {
    // Side by side: a second scan through the same camera (the first scan's framing), light,
    // BRDF, seed and exposure.
    RenderOptions ob = o;
    ob.albedo = other_scan->albedo ? &*other_scan->albedo : nullptr;
    const RenderResult rb = Render(other_scan->hf, brdf, env, ob);
    WritePng8(out / "side_by_side.png", SideBySide(ToneMapForDisplay(result.radiance, result.tone),
                                                   ToneMapForDisplay(rb.radiance, result.tone)));
    MESOSCAN_LOG(kInfo) << "render: wrote " << (fs::path(a.out) / "side_by_side.png").string()
                        << " (left " << a.scan << ", right " << a.compare_scan
                        << ", one camera and exposure)";
  } else if (!a.compare.empty()) {
    // Side by side: the same scan, camera and light with a second BRDF, one exposure.
    const Brdf other = MakeBrdf(a.compare, out);
    const RenderResult rb = Render(hf, other, env, o);
    WritePng8(out / "side_by_side.png", SideBySide(ToneMapForDisplay(result.radiance, result.tone),
                                                   ToneMapForDisplay(rb.radiance, result.tone)));
    MESOSCAN_LOG(kInfo) << "render: wrote " << (fs::path(a.out) / "side_by_side.png").string()
                        << " (left " << a.brdf << ", right " << a.compare << ")";
  }

  if (a.turntable > 0) {
    // The environment turns around the sample; exposure fixed from the main render so the
    // frames do not flicker.
    const fs::path dir = out / "turntable";
    fs::create_directories(dir);
    RenderOptions ot = o;
    if (!a.turntable_size.empty() &&
        std::sscanf(a.turntable_size.c_str(), "%dx%d", &ot.width, &ot.height) != 2)
      MESOSCAN_THROW(ErrorKind::kUsage,
                     "--turntable-size: expected WxH, got '" << a.turntable_size << "'");
    if (a.turntable_spp > 0) {
      ot.max_spp = a.turntable_spp;
      ot.min_spp = std::min(ot.min_spp, ot.max_spp);
    }
    if (o.time_limit_s > 0) ot.time_limit_s = o.time_limit_s / a.turntable;
    std::vector<ImageU8> frames;
    for (int k = 0; k < a.turntable; ++k) {
      EnvironmentMap e = env;
      e.SetRotation(a.env_rotation_deg + 360.0 * k / a.turntable);
      const RenderResult f = Render(hf, brdf, e, ot);
      frames.push_back(ToneMapForDisplay(f.radiance, result.tone));
      char name[32];
      std::snprintf(name, sizeof(name), "frame_%03d.png", k);
      WritePng8(dir / name, frames.back());
    }
    WriteAnimatedGif(out / "turntable.gif", frames, 12);
    // Named where they end up (`out` is the temporary folder swapped into place).
    MESOSCAN_LOG(kInfo) << "render: wrote " << a.turntable << " frames to "
                        << (fs::path(a.out) / "turntable").string() << " and "
                        << (fs::path(a.out) / "turntable.gif").string();
  }
}

// The scan's height field as the preview shows it: height.exr, validated, bounded holes filled
// unless --fill none.
HeightField PreviewHeightField(const RenderArgs& a, const fs::path& scan, const RenderOptions& o) {
  RestoreInterruptedReplacement(scan);  // core/output_dir.h: a replacement killed half-way
  const fs::path height_file = scan / "height.exr";
  HeightField hf = ReadHeightExr(height_file);
  ValidateHeightField(hf, o, height_file.string());
  FillOptions fill;
  fill.method = ParseFillMethod(a.fill);
  if (fill.method != FillMethod::kNone) {
    FillResult filled = FillHoles(hf, fill);
    MESOSCAN_LOG(kInfo) << "render: " << scan.string() << ": " << filled.BriefReport();
    hf = std::move(filled.field);
  }
  return hf;
}

void Run(const RenderArgs& args) {
  RenderArgs a = args;
  // --compare also takes a scan folder (one with a height.exr): a side by side of two scans.
  if (!a.compare.empty() && fs::is_directory(a.compare)) {
    if (!a.compare_scan.empty())
      MESOSCAN_THROW(ErrorKind::kUsage,
                     "render: --compare "
                         << a.compare
                         << " is a scan folder and "
                            "--compare-scan is given too: compare with one of them");
    a.compare_scan = a.compare;
    a.compare.clear();
  }
  if (!a.compare_scan.empty() && !a.compare.empty())
    MESOSCAN_THROW(ErrorKind::kUsage,
                   "render: --compare (a second BRDF) and --compare-scan (a second "
                   "scan) both make side_by_side.png: give one of them");
  ThreadLimit limit(a.threads);
  RenderOptions o = a.options;
  if (std::sscanf(a.size.c_str(), "%dx%d", &o.width, &o.height) != 2)
    MESOSCAN_THROW(ErrorKind::kUsage, "--size: expected WxH, got '" << a.size << "'");
  if (!a.camera.empty()) ParseCamera(a.camera, &o);
  // A time budget without an explicit sample cap renders until the time is up.
  if (o.time_limit_s > 0 && !a.spp_given) o.max_spp = 1 << 16;
  // --spp below the default --min-spp lowers it (an explicit --min-spp above --spp stays an error).
  if (!a.min_spp_given) o.min_spp = std::min(o.min_spp, o.max_spp);
  if (a.turntable < 0 || a.turntable > 720)
    MESOSCAN_THROW(ErrorKind::kUsage, "--turntable: expected 0..720 frames, got " << a.turntable);
  int tw = 0, th = 0;
  if (!a.turntable_size.empty() &&
      (std::sscanf(a.turntable_size.c_str(), "%dx%d", &tw, &th) != 2 || tw < 1 || th < 1 ||
       static_cast<double>(tw) * th > static_cast<double>(o.width) * o.height * 16))
    MESOSCAN_THROW(ErrorKind::kUsage,
                   "--turntable-size: expected WxH (positive, at most 16x the "
                   "--size area), got '"
                       << a.turntable_size << "'");
  ValidateRenderNumbers(a, o);
  o.Check();
  const bool brdf_file = a.brdf != "lambert" && a.brdf != "ggx" && a.brdf != "ggx-merl";
  const bool compare_file =
      !a.compare.empty() && a.compare != "lambert" && a.compare != "ggx" && a.compare != "ggx-merl";
  const bool env_file = fs::exists(a.env);
  const OutputSpec out_spec{"render",
                            "--out",
                            a.out,
                            {a.scan, brdf_file ? a.brdf : "", compare_file ? a.compare : "",
                             env_file ? a.env : "", a.compare_scan},
                            a.force,
                            {"preview.exr", "preview.png"}};
  CheckOutputFolder(out_spec);
  // --denoise: the filters' module (OpenCV's ximgproc, ~0.12-0.16 s to load) is loaded on
  // another thread while the scan is read and the BRDF tabulated, not inside the time budget.
  std::future<void> denoiser_loaded;
  if (a.denoise) denoiser_loaded = std::async(std::launch::async, [] { (void)Ximgproc(); });
  // The height field to preview: the scan's height.exr with its bounded holes filled
  // (maps/maps_fill.h, as the artist-ready maps fill them) unless --fill none, so a
  // shadowed rim is not previewed as a trench; large holes and the outside stay open.
  const HeightField hf = PreviewHeightField(a, a.scan, o);
  std::optional<CompareScan> other;
  if (!a.compare_scan.empty()) {
    other.emplace();
    other->hf = PreviewHeightField(a, a.compare_scan, o);
    RenderArgs ab = a;
    ab.scan = a.compare_scan;
    other->albedo = MakeAlbedo(ab, other->hf);
    // One camera for both: the first scan's framing, unless --camera gave one.
    o.camera = FramingCamera(hf, o);
  }
  EnvironmentMap env = MakeEnvironment(a);
  env.SetRotation(a.env_rotation_deg);
  const std::optional<ImageF> albedo = MakeAlbedo(a, hf);
  if (albedo) o.albedo = &*albedo;
  WriteOutputFolder(out_spec, [&](const fs::path& out) {
    RenderFolder(a, hf, env, o, out, other ? &*other : nullptr);
  });
  MESOSCAN_LOG(kInfo) << "render: wrote " << (fs::path(a.out) / "preview.png").string()
                      << " (display) and preview.exr (linear RGB)";
}

}  // namespace

void AddRenderCommand(CLI::App* app) {
  auto args = std::make_shared<RenderArgs>();
  auto* cmd = app->add_subcommand(
      "render", "Path-traced preview of a scan with a BRDF under an environment map");
  cmd->add_option("scan", args->scan, "Scan folder (reads height.exr)")->required();
  cmd->add_option("--out", args->out, "Output folder for preview.png / preview.exr")->required();
  cmd->add_option(
         "--brdf", args->brdf,
         "lambert | ggx | ggx-merl (GGX tabulated in MERL layout) | FILE.binary | FILE.bsdf")
      ->capture_default_str();
  cmd->add_option(
         "--env", args->env,
         "sky (procedural sun and sky) | constant | studio|forest|city|courtyard|interior|"
         "night|sunrise|sunset (Blender's, Debian blender-data) | FILE.exr/.hdr (lat-long)")
      ->capture_default_str();
  cmd->add_option("--env-scale", args->env_scale, "Radiance multiplier of the environment")
      ->capture_default_str();
  cmd->add_option("--env-rotation", args->env_rotation_deg,
                  "Turns the environment about the vertical axis, degrees")
      ->capture_default_str();
  cmd->add_option("--sun-elevation", args->sun_elevation_deg,
                  "Procedural sky: sun elevation, degrees")
      ->capture_default_str();
  cmd->add_option("--sun-azimuth", args->sun_azimuth_deg, "Procedural sky: sun azimuth, degrees")
      ->capture_default_str();
  cmd->add_option("--size", args->size, "Image size WxH")->capture_default_str();
  cmd->add_option_function<int>(
      "--spp",
      [args](int n) {
        args->options.max_spp = n;
        args->spp_given = true;
      },
      "Maximum samples per pixel (default 256; 65536 with --time)");
  cmd->add_option_function<int>(
      "--min-spp",
      [args](int n) {
        args->options.min_spp = n;
        args->min_spp_given = true;
      },
      "Samples before a pixel may stop early (default 16, at most --spp)");
  cmd->add_option("--noise", args->options.noise,
                  "Adaptive sampling: a pixel stops when its standard error is below this fraction "
                  "of the display range (0 = every pixel gets --spp)")
      ->capture_default_str();
  cmd->add_option("--time", args->options.time_limit_s,
                  "Stop after about this many seconds (0 = no limit; a timed render is not "
                  "bit-for-bit reproducible)")
      ->capture_default_str();
  cmd->add_option("--seed", args->options.seed,
                  "Sampler seed: the same seed reproduces the image bit for bit, different seeds "
                  "give independent noise")
      ->capture_default_str();
  cmd->add_option("--camera", args->camera,
                  "Explicit camera eye=X,Y,Z:target=X,Y,Z[:fov=DEG] in world metres (z up, "
                  "vertical field of view, default 30); overrides --elevation/--azimuth");
  cmd->add_option("--fov", args->options.fov_deg, "Vertical field of view, degrees (0 = 30)")
      ->capture_default_str();
  cmd->add_option("--elevation", args->options.elevation_deg, "Camera elevation, degrees")
      ->capture_default_str();
  cmd->add_option("--azimuth", args->options.azimuth_deg, "Camera azimuth, degrees")
      ->capture_default_str();
  cmd->add_option("--relief", args->options.relief_scale, "Height exaggeration factor")
      ->capture_default_str();
  cmd->add_option("--max-depth", args->options.max_depth, "Path vertices on the surface")
      ->capture_default_str();
  cmd->add_option("--albedo", args->albedo,
                  "Base colour: none | scan (the scan's albedo as a tint) | R,G,B")
      ->capture_default_str();
  cmd->add_option("--turntable", args->turntable,
                  "Also render N frames of the environment turning once around the sample "
                  "(turntable/frame_NNN.png and turntable.gif)");
  cmd->add_option("--turntable-spp", args->turntable_spp,
                  "Samples per pixel of each turntable frame (default: as --spp)");
  cmd->add_option("--turntable-size", args->turntable_size,
                  "Turntable frame size WxH (default: as --size)");
  cmd->add_option("--compare", args->compare,
                  "Also render a second BRDF, or a second scan (a scan folder), and write "
                  "side_by_side.png (left this scan / --brdf, right the other) with one camera, "
                  "light and exposure");
  cmd->add_option("--compare-scan", args->compare_scan,
                  "Also render a second scan folder through the same camera, light, BRDF and "
                  "exposure and write side_by_side.png (left SCAN, right this)");
  cmd->add_option("--fill", args->fill,
                  "Hole filling of the previewed height field: harmonic | biharmonic | none")
      ->capture_default_str();
  cmd->add_flag(
      "!--no-mirror-guide", args->options.mirror_guide,
      "Sample continuation rays by BRDF alone (default: glossy BRDFs under an environment "
      "map also aim at the environment mirrored in the field's plane; same image, less "
      "noise on reliefs lit by the field's reflection)");
  cmd->add_option("--resample", args->options.resample_candidates,
                  "Candidate directions resampled towards the BRDF x the field's reflection at "
                  "vertices that aim at it (0 or 1: off)")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "Worker threads (0 = all cores)")
      ->check(CLI::Range(0, 4096));
  cmd->add_flag("--denoise", args->denoise,
                "Also write preview_denoised.png / .exr: the render smoothed by an edge-aware "
                "filter guided by normal and depth buffers (biased; the raw preview is still "
                "written; with --time its cost comes out of the budget)");
  cmd->add_flag("--force", args->force,
                "Replace an existing --out that is not an earlier output of `mesoscan render`");
  cmd->callback([args] { Run(*args); });
}

}  // namespace mesoscan
