// mesoscan render: a path-traced preview of a scan's height field with a BRDF (measured or
// analytic) under an environment map: the sample in the BRDF (tinted by the scan's albedo when it
// has one), the bare mount around it in a neutral diffuse material. Writes preview.exr (linear
// RGB) and preview.png; while a long render runs, its progressive preview is rewritten at a
// stable path beside the output (OUT.progress.png). Optional: turntable frames of the object
// turning (or of the light turning) with an animated GIF, a labelled side-by-side comparison,
// a scale bar.

#include <unistd.h>

#include <algorithm>
#include <atomic>
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
#include "maps/maps_tile.h"
#include "render/animation.h"
#include "render/denoise.h"
#include "render/env_map.h"
#include "render/overlay.h"
#include "render/path_tracer.h"
#include "render/ximgproc_module.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

struct RenderArgs {
  std::string scan, out, brdf = "ggx-merl", env = "sky", size = "640x480", camera, albedo = "auto";
  std::string compare, compare_scan, turntable_size, fill = "harmonic", mount = "neutral";
  RenderOptions options;
  double sun_elevation_deg = 25, sun_azimuth_deg = 200, env_scale = 1.0, env_rotation_deg = 0;
  int threads = 0, turntable = 0, turntable_light = 0, turntable_spp = 0;
  bool scale_bar = false;
  bool spp_given = false, min_spp_given = false;
  bool force = false;
  bool denoise = false;  // also write preview_denoised.exr/png (render/denoise.h)
};

// "lambert", "ggx", "ggx-merl" (GGX tabulated into the MERL layout, written and read back: the
// measured path with no external data), or a measured file (read in place). The tabulated table
// goes through a scratch file in the system's temporary folder, removed once read: no 35 MB copy
// in every render folder.
Brdf MakeBrdf(const std::string& spec) {
  if (spec == "lambert") return Brdf(LambertBrdf(Rgb::Constant(0.7)));
  // Warm copper-like conductor: a material whose highlights show relief clearly.
  const auto ggx = GgxBrdf<double>::Conductor(0.25, Rgb(0.27, 0.68, 1.22), Rgb(3.61, 2.63, 2.29));
  if (spec == "ggx") return Brdf(ggx);
  if (spec == "ggx-merl") {
    static std::atomic<int> serial{0};
    const fs::path file =
        fs::temp_directory_path() / ("mesoscan_ggx_copper_merl_" + std::to_string(getpid()) + "_" +
                                     std::to_string(serial++) + ".binary");
    struct Remove {
      fs::path f;
      ~Remove() {
        std::error_code ec;
        fs::remove(f, ec);
      }
    } remove{file};
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

// The base colour map for --albedo: "none", "R,G,B", "scan" (albedo.exr/png in the scan
// folder, else the session's white frame named by report.json; an error if neither), or "auto"
// (the default: the scan's albedo when it has one, else none). Colour when the albedo has
// colour. A relative albedo is normalised to median 1 over the sample's pixels (`on_sample`,
// all when null) (a tint of the BRDF's own colour), clamped to [0, 1.4]; holes -> 1.
std::optional<ImageF> MakeAlbedo(const RenderArgs& a, const HeightField& hf,
                                 const ImageU8* on_sample) {
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
  if (a.albedo != "scan" && a.albedo != "auto")
    MESOSCAN_THROW(ErrorKind::kUsage,
                   "--albedo: expected auto, scan, none or R,G,B, got '" << a.albedo << "'");
  ImageF alb;
  std::string source;
  for (const char* f : {"albedo.exr", "albedo.png"})
    if (alb.pixels() == 0 && fs::exists(fs::path(a.scan) / f)) {
      alb = ReadImage(fs::path(a.scan) / f);
      source = (fs::path(a.scan) / f).string();
    }
  if (alb.pixels() == 0 && a.albedo == "auto") {
    // The session's white frame when the scan names a session that is still there; else none.
    fs::path session;
    if (fs::exists(fs::path(a.scan) / "report.json")) {
      const Json report = ReadJsonFile(fs::path(a.scan) / "report.json");
      if (report.contains("session") && report["session"].is_string())
        session = report["session"].get<std::string>();
      if (!session.empty() && session.is_relative() && !fs::exists(session))
        session = fs::path(a.scan) / session;
    }
    if (session.empty() || !fs::is_directory(session)) {
      MESOSCAN_LOG(kInfo) << "render: " << a.scan
                          << " has no albedo (no albedo.exr/png, no session with a white "
                             "frame): the BRDF's own colour";
      return std::nullopt;
    }
    try {
      alb = AlbedoFromSession(hf, session, &source);
      source = session.string() + " (" + source + ")";
    } catch (const Error& e) {
      MESOSCAN_LOG(kWarning) << "render: " << a.scan << ": no albedo from the session (" << e.what()
                             << "): the BRDF's own colour";
      return std::nullopt;
    }
  }
  if (alb.pixels() == 0) {
    const Json report = ReadJsonFile(fs::path(a.scan) / "report.json");
    if (!report.contains("session") || !report["session"].is_string())
      MESOSCAN_BAD_INPUT(
          a.scan << "/report.json: --albedo scan: no albedo.exr/png and no \"session\" "
                    "whose white frame gives one");
    fs::path session = report["session"].get<std::string>();
    if (session.is_relative() && !fs::exists(session)) session = fs::path(a.scan) / session;
    alb = AlbedoFromSession(hf, session);
    source = session.string();
  }
  if (alb.width() != hf.width() || alb.height() != hf.height())
    MESOSCAN_BAD_INPUT(a.scan << ": --albedo scan: the albedo is " << alb.width() << "x"
                              << alb.height() << ", the height grid " << hf.width() << "x"
                              << hf.height());
  const int nc = alb.channels() >= 3 ? 3 : 1;
  std::vector<float> lum;
  for (int pass = 0; pass < 2 && lum.empty(); ++pass)
    for (size_t i = 0; i < alb.pixels(); ++i)
      if (std::isfinite(alb.channel(0)[i]) && alb.channel(0)[i] > 0 &&
          (pass == 1 || !on_sample || on_sample->data()[i]))
        lum.push_back(alb.channel(0)[i]);
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
  MESOSCAN_LOG(kInfo) << "render: albedo from " << source << " (" << (nc == 3 ? "colour" : "grey")
                      << ", a tint of the BRDF: median 1 on the sample)";
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

// The display images: tone-mapped, with the scale bar when asked (pixels_per_metre > 0: the
// image scale at the sample's centre).
struct Display {
  double pixels_per_metre = 0;
  ImageU8 operator()(const ImageF& radiance, const ToneMapping& tone) const {
    ImageU8 im = ToneMapForDisplay(radiance, tone);
    if (pixels_per_metre > 0) DrawScaleBar(&im, pixels_per_metre * radiance.height());
    return im;
  }
};

void WritePreview(const fs::path& out, const RenderResult& r, const Display& display) {
  WriteExr(out / "preview.exr", r.radiance, {"R", "G", "B"}, {}, {}, "none");
  WritePng8(out / "preview.png", display(r.radiance, r.tone));
}

// The progressive preview's stable path: beside the output folder (whose contents are written
// into a temporary folder and swapped into place at the end), OUT.progress.png.
fs::path ProgressPath(const std::string& out) {
  fs::path p = fs::absolute(out).lexically_normal();
  if (p.filename().empty()) p = p.parent_path();
  return p.parent_path() / (p.filename().string() + ".progress.png");
}

// The second scan of a side by side (--compare-scan, or --compare naming a scan folder).
struct CompareScan {
  HeightField hf;
  std::optional<ImageF> albedo;
  ImageU8 on_sample;  // empty: all sample (--mount sample)
};

// The centre of the height field (its grid's centre, at its median height, relief scaled).
Vec3 FieldCentre(const HeightField& hf, const RenderOptions& o) {
  std::vector<float> z;
  for (const float v : hf.z.data())
    if (std::isfinite(v)) z.push_back(v);
  double zc = 0;
  if (!z.empty()) {
    std::nth_element(z.begin(), z.begin() + z.size() / 2, z.end());
    zc = z[z.size() / 2] * o.relief_scale;
  }
  return Vec3(hf.X(0.5 * (hf.width() - 1)), hf.Y(0.5 * (hf.height() - 1)), zc);
}

// Image pixels per metre at the sample's centre, per pixel of image height (the framing
// camera's focal length over the centre's depth).
double PixelsPerMetrePerRow(const HeightField& hf, const RenderOptions& o) {
  const CameraSpec cam = FramingCamera(hf, o);
  const Vec3 fwd = (cam.target - cam.eye).normalized();
  const double depth = (FieldCentre(hf, o) - cam.eye).dot(fwd);
  const double tan_half = std::tan(0.5 * (o.fov_deg > 0 ? o.fov_deg : 30.0) * kPi / 180);
  return depth > 0 ? 0.5 / tan_half / depth : 0.0;
}

// The camera turned by `degrees` about the vertical axis through `centre`.
CameraSpec TurnCamera(const CameraSpec& cam, const Vec3& centre, double degrees) {
  const double t = degrees * kPi / 180, c = std::cos(t), s = std::sin(t);
  const auto turn = [&](const Vec3& p) {
    const Vec3 d = p - centre;
    return Vec3(centre.x() + c * d.x() - s * d.y(), centre.y() + s * d.x() + c * d.y(), p.z());
  };
  return CameraSpec{turn(cam.eye), turn(cam.target)};
}

// Turntable frames: `object` true turns the object (the camera and the light turn the other way
// about its centre: the same images), false turns the light around the still object. Exposure
// fixed from the still so the frames do not flicker. Each frame is sampled to the still's noise
// (render/path_tracer.h DisplayNoise: the still's --noise, or what the still reached under
// --time when that is more), with adaptive stopping, and denoised with --denoise; under --time a
// frame takes at most the still's seconds per pixel.
void RenderTurntable(const RenderArgs& a, const HeightField& hf, const Brdf& brdf,
                     const EnvironmentMap& env, const RenderOptions& o, const RenderResult& still,
                     const Display& display, bool object, const fs::path& out) {
  const int n = object ? a.turntable : a.turntable_light;
  const std::string name = object ? "turntable" : "turntable_light";
  const fs::path dir = out / name;
  fs::create_directories(dir);
  RenderOptions ot = o;
  if (!a.turntable_size.empty() &&
      std::sscanf(a.turntable_size.c_str(), "%dx%d", &ot.width, &ot.height) != 2)
    MESOSCAN_THROW(ErrorKind::kUsage,
                   "--turntable-size: expected WxH, got '" << a.turntable_size << "'");
  const double still_noise = DisplayNoise(still);
  ot.noise = std::max(o.noise, still_noise);
  // The noise target decides (uniform rounds, adaptive stopping); under --time each frame may
  // also take at most the still's seconds per pixel.
  ot.time_limit_s =
      o.time_limit_s > 0
          ? std::max(0.05, still.summary.seconds * (static_cast<double>(ot.width) * ot.height) /
                               (static_cast<double>(o.width) * o.height))
          : 0;
  ot.allocate_pilot_spp = 0;
  ot.allocate_for_denoiser = false;
  // Under --time the still has no sample cap (65536): the frames stop at 1024.
  ot.max_spp = o.time_limit_s > 0 ? std::min(o.max_spp, 1024) : o.max_spp;
  if (a.turntable_spp > 0) ot.max_spp = a.turntable_spp;
  ot.min_spp = std::min(o.min_spp, ot.max_spp);
  const CameraSpec base = FramingCamera(hf, o);
  const Vec3 centre = FieldCentre(hf, o);
  std::vector<ImageU8> frames;
  double spp = 0;
  for (int k = 0; k < n; ++k) {
    const double turn = 360.0 * k / n;
    EnvironmentMap e = env;
    if (object) {
      // The object turns by +turn: camera and light by -turn about its centre.
      ot.camera = TurnCamera(base, centre, -turn);
      e.SetRotation(a.env_rotation_deg - turn);
    } else {
      e.SetRotation(a.env_rotation_deg + turn);
    }
    RenderOptions of = ot;
    of.seed = o.seed + 1 + k;
    const RenderResult f = Render(hf, brdf, e, of);
    spp += f.summary.mean_spp / n;
    frames.push_back(display(a.denoise ? DenoisePreview(f) : f.radiance, still.tone));
    char file[32];
    std::snprintf(file, sizeof(file), "frame_%03d.png", k);
    WritePng8(dir / file, frames.back());
  }
  WriteAnimatedGif(out / (name + ".gif"), frames, 12);
  // Named where they end up (`out` is the temporary folder swapped into place).
  MESOSCAN_LOG(kInfo) << "render: wrote " << n << " frames of the " << (object ? "object" : "light")
                      << " turning to " << (fs::path(a.out) / name).string() << " and "
                      << (fs::path(a.out) / (name + ".gif")).string() << " ("
                      << (a.denoise ? "denoised, " : "") << spp
                      << " spp on average to the still's noise " << ot.noise << ")";
}

// Everything the render writes, into `out` (the temporary folder that is swapped into place).
void RenderFolder(const RenderArgs& a, const HeightField& hf, const EnvironmentMap& env,
                  const RenderOptions& options, const fs::path& out,
                  const CompareScan* other_scan) {
  const fs::path progress = ProgressPath(a.out);
  MESOSCAN_LOG(kInfo) << "render: progressive preview while sampling: " << progress.string();
  const Brdf brdf = MakeBrdf(a.brdf);
  RenderOptions o = options;
  Display display;
  if (a.scale_bar) display.pixels_per_metre = PixelsPerMetrePerRow(hf, o);
  // --denoise within --time: the denoiser's share comes out of the budget, measured right before
  // the render (Run() loads the filters' module in the background meanwhile).
  if (a.denoise && o.time_limit_s > 0)
    o.time_limit_s -= MeasureDenoiseTimeReserve(o.width, o.height, o.time_limit_s);
  // The preview, if denoised, spends fewer samples where the denoiser averages many pixels
  // (the side by side's renders are not denoised).
  RenderOptions preview = o;
  preview.allocate_for_denoiser = a.denoise;

  // Progressive output: OUT.progress.png rewritten (atomically) after a round when at least 2 s
  // have passed since the last write and more than 2 s of a --time budget are left.
  auto last_write = std::chrono::steady_clock::now();
  const RenderResult result = Render(hf, brdf, env, preview, [&](const RenderResult& r) {
    const auto now = std::chrono::steady_clock::now();
    if (std::chrono::duration<double>(now - last_write).count() < 2.0) return;
    // Not when the final preview follows within 2 s anyway (a --time budget about to run out):
    // the write would come out of the budget (~0.05 s at 480 x 360).
    if (o.time_limit_s > 0 && o.time_limit_s - r.summary.seconds < 2.0) return;
    WritePng8(progress, display(r.radiance, r.tone));
    last_write = now;
  });
  WritePreview(out, result, display);
  MESOSCAN_LOG(kInfo) << "render: " << result.summary.BriefReport();
  if (a.denoise) {
    // The optional denoise stage: biased, so written beside the raw preview, never instead.
    const Stopwatch denoise_time;
    const ImageF dn = DenoisePreview(result);
    WriteExr(out / "preview_denoised.exr", dn, {"R", "G", "B"}, {}, {}, "none");
    WritePng8(out / "preview_denoised.png", display(dn, result.tone));
    MESOSCAN_LOG(kInfo) << "render: denoised in " << denoise_time.Seconds()
                        << " s: preview_denoised.png / .exr (biased: edge-aware smoothing; the raw "
                           "render is preview.png / .exr)";
  }

  if (other_scan) {
    // Side by side: a second scan through the same camera (the first scan's framing), light,
    // BRDF, seed and exposure.
    RenderOptions ob = o;
    ob.albedo = other_scan->albedo ? &*other_scan->albedo : nullptr;
    ob.sample_material = other_scan->on_sample.empty() ? nullptr : &other_scan->on_sample;
    const RenderResult rb = Render(other_scan->hf, brdf, env, ob);
    WritePng8(
        out / "side_by_side.png",
        LabelledSideBySide(display(result.radiance, result.tone), display(rb.radiance, result.tone),
                           fs::path(a.scan).lexically_normal().filename().string(),
                           fs::path(a.compare_scan).lexically_normal().filename().string()));
    MESOSCAN_LOG(kInfo) << "render: wrote " << (fs::path(a.out) / "side_by_side.png").string()
                        << " (left " << a.scan << ", right " << a.compare_scan
                        << ", one camera and exposure, labelled)";
  } else if (!a.compare.empty()) {
    // Side by side: the same scan, camera and light with a second BRDF, one exposure.
    const Brdf other = MakeBrdf(a.compare);
    const RenderResult rb = Render(hf, other, env, o);
    const auto label = [](const std::string& spec) {
      return fs::exists(spec) ? fs::path(spec).filename().string() : spec;
    };
    WritePng8(out / "side_by_side.png", LabelledSideBySide(display(result.radiance, result.tone),
                                                           display(rb.radiance, result.tone),
                                                           label(a.brdf), label(a.compare)));
    MESOSCAN_LOG(kInfo) << "render: wrote " << (fs::path(a.out) / "side_by_side.png").string()
                        << " (left " << a.brdf << ", right " << a.compare << ", labelled)";
  }

  if (a.turntable > 0) RenderTurntable(a, hf, brdf, env, o, result, display, true, out);
  if (a.turntable_light > 0) RenderTurntable(a, hf, brdf, env, o, result, display, false, out);
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
  if (a.turntable_light < 0 || a.turntable_light > 720)
    MESOSCAN_THROW(ErrorKind::kUsage,
                   "--turntable-light: expected 0..720 frames, got " << a.turntable_light);
  if (a.mount != "neutral" && a.mount != "sample")
    MESOSCAN_THROW(ErrorKind::kUsage,
                   "--mount: expected neutral or sample, got '" << a.mount << "'");
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
  // The sample and the bare mount it sits on (maps/maps_tile.h OnSampleMask: > 20 um above the
  // mount plane, the maps' rule): the mount in a neutral diffuse material unless --mount sample.
  const bool neutral_mount = a.mount == "neutral";
  const ImageU8 on_sample = neutral_mount ? OnSampleMask(hf) : ImageU8();
  if (neutral_mount) {
    int64_t n = 0, finite = 0;
    for (size_t i = 0; i < on_sample.pixels(); ++i) {
      n += on_sample.data()[i] != 0;
      finite += std::isfinite(hf.z.data()[i]);
    }
    MESOSCAN_LOG(kInfo) << "render: the sample is "
                        << std::lround(100.0 * n / std::max<int64_t>(1, finite))
                        << "% of the height field (standing > "
                        << TileOptions{}.mount_clearance_m * 1e6
                        << " um off the mount plane); the rest is the mount, neutral diffuse "
                           "(albedo "
                        << o.mount_albedo[1] << ")";
    o.sample_material = &on_sample;
  }
  std::optional<CompareScan> other;
  if (!a.compare_scan.empty()) {
    other.emplace();
    other->hf = PreviewHeightField(a, a.compare_scan, o);
    if (neutral_mount) other->on_sample = OnSampleMask(other->hf);
    RenderArgs ab = a;
    ab.scan = a.compare_scan;
    other->albedo =
        MakeAlbedo(ab, other->hf, other->on_sample.empty() ? nullptr : &other->on_sample);
    // One camera for both: the first scan's framing, unless --camera gave one.
    o.camera = FramingCamera(hf, o);
  }
  EnvironmentMap env = MakeEnvironment(a);
  env.SetRotation(a.env_rotation_deg);
  const std::optional<ImageF> albedo = MakeAlbedo(a, hf, neutral_mount ? &on_sample : nullptr);
  if (albedo) o.albedo = &*albedo;
  // The progressive preview beside the output is removed once the final one is in place (or
  // the render failed).
  struct RemoveProgress {
    fs::path f;
    ~RemoveProgress() {
      std::error_code ec;
      fs::remove(f, ec);
    }
  } remove_progress{ProgressPath(a.out)};
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
                  "Base colour: auto (the scan's albedo as a tint when it has one: albedo.exr/png "
                  "or its session's white frame; colour if the albedo has colour) | scan (the "
                  "same, an error without one) | none | R,G,B")
      ->capture_default_str();
  cmd->add_option("--mount", args->mount,
                  "The bare mount around the sample (height field samples under 20 um above the "
                  "mount plane): neutral (diffuse grey) | sample (the sample's BRDF and albedo)")
      ->capture_default_str();
  cmd->add_option("--turntable", args->turntable,
                  "Also render N frames of the object turning once under the still light and "
                  "camera (turntable/frame_NNN.png and turntable.gif), each sampled to the "
                  "still's noise (denoised with --denoise)");
  cmd->add_option("--turntable-light", args->turntable_light,
                  "Also render N frames of the light (the environment) turning once around the "
                  "still object (turntable_light/frame_NNN.png and turntable_light.gif)");
  cmd->add_option("--turntable-spp", args->turntable_spp,
                  "Sample cap per pixel of each turntable frame (default: as --spp; 1024 with "
                  "--time)");
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
  cmd->add_flag("--scale-bar", args->scale_bar,
                "Draw a scale bar (a round length at the sample's centre) on the display images");
  cmd->add_flag("--force", args->force,
                "Replace an existing --out that is not an earlier output of `mesoscan render`");
  cmd->callback([args] { Run(*args); });
}

}  // namespace mesoscan
