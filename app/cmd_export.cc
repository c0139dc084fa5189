// mesoscan export SCAN --out DIR: the scan's DCC exports (maps/export.h).

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <sstream>

#include "app/commands.h"
#include "app/map_options.h"
#include "app/session_checks.h"
#include "core/budget.h"
#include "core/error.h"
#include "core/image_io.h"
#include "core/json.h"
#include "core/log.h"
#include "core/output_dir.h"
#include "core/scan_folder.h"
#include "maps/export.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

struct ExportArgs {
  std::string scan, out, formats = ExportFormatList(), normals = "gl", crop, name, albedo;
  double pixel_size_m = 0.0;
  int64_t max_triangles = ExportOptions().max_triangles;
  double mesh_tolerance_m = 0.0;
  MapArgs maps;  // map-set options: with any of them, a finished map set in OUT/maps
  bool force = false;
};

// Sizes a user or the scan controls, checked before ExportScan allocates anything: the crop
// (in 64 bits: X + W may overflow an int), the output grid against the memory budget, and a
// height field with no valid sample at all.
void ValidateExportSizes(const Scan& scan, const ExportOptions& o, const std::string& scan_dir) {
  const HeightField& hf = scan.height;
  int64_t w = hf.width(), h = hf.height();
  if (!o.crop.whole()) {
    const PixelRect& c = o.crop;
    if (int64_t{c.x} + c.w > w || int64_t{c.y} + c.h > h)
      MESOSCAN_THROW(ErrorKind::kUsage, "export: --crop "
                                            << c.x << "," << c.y << "," << c.w << "," << c.h
                                            << ": expected a rectangle inside the " << w << "x" << h
                                            << " height grid");
    w = c.w;
    h = c.h;
  }
  if (!std::isfinite(o.pixel_size_m) || o.pixel_size_m < 0)
    MESOSCAN_THROW(ErrorKind::kUsage, "export: --pixel-size: expected a finite value >= 0 (m), got "
                                          << o.pixel_size_m);
  double gw = static_cast<double>(w), gh = static_cast<double>(h);
  if (o.pixel_size_m > 0) {
    if (!(hf.pixel_size > 0) || !std::isfinite(hf.pixel_size))
      MESOSCAN_BAD_INPUT(scan_dir << "/height.exr: " << kAttrPixelSize << " must be > 0, got "
                                  << hf.pixel_size);
    gw *= hf.pixel_size / o.pixel_size_m;
    gh *= hf.pixel_size / o.pixel_size_m;
  }
  // Export keeps ~160 bytes per output pixel alive at its peak (height, normals, their filled and
  // encoded copies, 16-bit quantisations, writers' interleaved buffers, the mesh).
  std::ostringstream what;
  what << "export: a " << std::llround(std::min(gw, 1e15)) << "x"
       << std::llround(std::min(gh, 1e15)) << " output grid";
  CheckMemoryBudget(
      what.str(), gw * gh * 160.0,
      o.pixel_size_m > 0 || !o.crop.whole() ? ErrorKind::kUsage : ErrorKind::kBadInput);
  bool any = false;
  for (const float z : hf.z.data())
    if (std::isfinite(z)) {
      any = true;
      break;
    }
  if (!any) MESOSCAN_BAD_INPUT(scan_dir << "/height.exr: no valid (finite) height sample");
}

void RunExport(const ExportArgs& a) {
  ExportOptions o;
  ParseExportFormats(a.formats, &o);
  o.normals = a.normals == "dx" ? NormalConvention::kDirectX : NormalConvention::kOpenGl;
  o.pixel_size_m = a.pixel_size_m;
  if (!a.crop.empty()) o.crop = ParsePixelRect(a.crop, "ExportOptions.crop");
  o.max_triangles = a.max_triangles;
  o.mesh_tolerance_m = a.mesh_tolerance_m;
  o.name = a.name.empty() ? ScanName(a.scan) : a.name;
  o.Check();
  std::optional<MapsOptions> maps;
  if (a.maps.any()) maps = a.maps.ToOptions(o.name, a.crop);
  if (maps && !a.maps.fill.empty()) o.fill = maps->fill;
  // The GLB's material as the map set's: its ambient occlusion and roughness.
  if (maps) {
    o.glb_occlusion = maps->maps.ao;
    o.glb_ao = maps->ao;
    o.glb_roughness = maps->roughness;
  }
  // Inputs: the scan, the albedo, and the session the scan came from (its white frame).
  OutputSpec out_spec{"export", "--out", a.out, {a.scan, a.albedo}, a.force, {"manifest.json"}};
  const fs::path report = fs::path(a.scan) / "report.json";
  if (fs::is_regular_file(report)) {
    try {
      const Json r = ReadJsonFile(report);
      if (r.is_object() && r.contains("session") && r["session"].is_string())
        out_spec.inputs.push_back(r["session"].get<std::string>());
    } catch (const Error&) {
      // ReadScanFolder below names the file
    }
  }
  CheckOutputFolder(out_spec);
  const Scan scan = ReadScanFolder(a.scan);
  ValidateExportSizes(scan, o, a.scan);
  CheckScanUsable(scan, a.scan);  // as `check` does: a damaged sample is refused, not exported
  // Albedo: --albedo, else an albedo the reconstruction wrote into the scan folder, else
  // ExportScan looks for the session's white frame (report.json "session").
  fs::path albedo = a.albedo;
  if (albedo.empty()) {
    for (const char* f : {"albedo.exr", "albedo.png"})
      if (fs::exists(fs::path(a.scan) / f)) albedo = fs::path(a.scan) / f;
  }
  if (!albedo.empty()) {
    o.albedo = ReadImage(albedo);
    if (o.albedo.channels() == 2 || o.albedo.channels() == 4) {
      ImageF rgb(o.albedo.width(), o.albedo.height(), o.albedo.channels() - 1);
      for (int c = 0; c < rgb.channels(); ++c)
        std::copy(o.albedo.channel(c), o.albedo.channel(c) + o.albedo.pixels(), rgb.channel(c));
      o.albedo = std::move(rgb);
    }
    if (o.albedo.width() != scan.height.width() || o.albedo.height() != scan.height.height())
      MESOSCAN_BAD_INPUT(albedo.string()
                         << ": expected the " << scan.height.width() << "x" << scan.height.height()
                         << " height grid, got " << o.albedo.width() << "x" << o.albedo.height());
  }
  ExportSummary s;
  std::optional<MapsSummary> maps_summary;
  WriteOutputFolder(out_spec, [&](const fs::path& tmp) {
    s = ExportScan(scan, o, tmp);
    if (maps) {
      maps->albedo = o.albedo;
      maps_summary = BuildMapSet(scan, *maps, tmp / "maps");
    }
  });
  std::cout << s.BriefReport() << "\n";
  std::cout << "exports in " << fs::absolute(a.out).lexically_normal().string() << ":\n";
  const Json& hints = s.manifest.at("how_to_load");
  for (const auto& f : s.manifest.at("files")) {
    const std::string file = f.at("file");
    if (f.at("role") == "height sidecar") continue;
    std::cout << "  " << file << ": " << hints.at(file).get<std::string>() << "\n";
  }
  std::cout << "  manifest.json: units, conventions, channels and files\n";
  if (maps_summary) PrintMapSet(*maps_summary, fs::path(a.out) / "maps");
}

}  // namespace

void AddExportCommand(CLI::App* app) {
  auto* cmd = app->add_subcommand(
      "export", "Exports a scan for DCC tools: EXR / 16-bit PNG height and normal maps, GLB, PLY");
  auto a = std::make_shared<ExportArgs>();
  cmd->add_option("SCAN", a->scan, "Scan folder (written by reconstruct)")->required();
  cmd->add_option("--out", a->out, "Output folder (written atomically; replaces an earlier export)")
      ->required();
  cmd->add_option("--format", a->formats, "Comma-separated subset of " + ExportFormatList())
      ->capture_default_str();
  cmd->add_option("--normals", a->normals,
                  "Normal-map convention: gl (OpenGL, +Y) or dx (DirectX, -Y)")
      ->check(CLI::IsMember({"gl", "dx"}))
      ->capture_default_str();
  cmd->add_option("--pixel-size", a->pixel_size_m,
                  "Output pixel size in metres (default: the scan's)");
  cmd->add_option("--crop", a->crop, "X,Y,W,H: a rectangle of the scan's height-grid pixels");
  cmd->add_option("--max-triangles", a->max_triangles, "GLB triangle budget (decimates above it)")
      ->capture_default_str();
  auto* tolerance =
      cmd->add_option("--mesh-tolerance", a->mesh_tolerance_m,
                      "GLB: never split triangles whose height error is below this (metres)");
  cmd->add_option_function<double>(
         "--max-error-um", [a](double um) { a->mesh_tolerance_m = um * 1e-6; },
         "GLB: decimate to this maximum height error (micrometres; --mesh-tolerance in um)")
      ->excludes(tolerance);
  cmd->add_option("--name", a->name, "File name prefix (default: the scan folder's name)");
  cmd->add_option("--albedo", a->albedo,
                  "Linear albedo image on the height grid (default: SCAN/albedo.exr|png, else the "
                  "session's white frame named in report.json)");
  AddMapOptions(cmd, &a->maps, /*standalone=*/false);
  cmd->add_flag("--force", a->force,
                "Replace an existing --out that is not an earlier output of `mesoscan export`");
  cmd->callback([a] { RunExport(*a); });
}

}  // namespace mesoscan
