// mesoscan export SCAN --out DIR: the scan's DCC exports (heightfield/export.h).

#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>

#include "app/commands.h"
#include "app/map_options.h"
#include "core/error.h"
#include "core/image_io.h"
#include "core/log.h"
#include "core/scan_folder.h"
#include "heightfield/export.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

struct ExportArgs {
  std::string scan, out, formats = "exr,png16,glb,ply", normals = "gl", crop, name, albedo;
  double pixel_size_m = 0.0;
  int64_t max_triangles = ExportOptions().max_triangles;
  double mesh_tolerance_m = 0.0;
  MapArgs maps;  // map-set options: with any of them, a finished map set in OUT/maps
};

std::string DefaultName(const fs::path& scan) {
  fs::path p = scan.lexically_normal();
  if (p.filename().empty()) p = p.parent_path();
  std::string name = p.filename().string();
  if (p.extension() == ".scan") name = p.stem().string();
  return name.empty() || name == "." || name == ".." ? "scan" : name;
}

void RunExport(const ExportArgs& a) {
  ExportOptions o;
  ParseExportFormats(a.formats, &o);
  o.normals = a.normals == "dx" ? NormalConvention::kDirectX : NormalConvention::kOpenGl;
  o.pixel_size_m = a.pixel_size_m;
  if (!a.crop.empty()) o.crop = ParseGridCrop(a.crop);
  o.max_triangles = a.max_triangles;
  o.mesh_tolerance_m = a.mesh_tolerance_m;
  o.name = a.name.empty() ? DefaultName(a.scan) : a.name;
  o.Check();
  std::optional<MapsOptions> maps;
  if (a.maps.any()) maps = a.maps.ToOptions(o.name, a.crop);
  if (maps && !a.maps.fill.empty()) o.fill = maps->fill;
  const Scan scan = ReadScanFolder(a.scan);
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
      MESOSCAN_BAD_INPUT(albedo.string() << ": expected the " << scan.height.width() << "x"
                                         << scan.height.height() << " height grid, got "
                                         << o.albedo.width() << "x" << o.albedo.height());
  }
  const ExportSummary s = ExportScan(scan, o, a.out);
  std::cout << s.BriefReport() << "\n";
  std::cout << "exports in " << fs::absolute(a.out).lexically_normal().string() << ":\n";
  const Json& hints = s.manifest.at("how_to_load");
  for (const auto& f : s.manifest.at("files")) {
    const std::string file = f.at("file");
    if (f.at("role") == "height sidecar") continue;
    std::cout << "  " << file << ": " << hints.at(file).get<std::string>() << "\n";
  }
  std::cout << "  manifest.json: units, conventions, channels and files\n";
  if (maps) {
    maps->albedo = o.albedo;
    const fs::path dir = fs::path(a.out) / "maps";
    PrintMapSet(BuildMapSet(scan, *maps, dir), dir);
  }
}

}  // namespace

void AddExportCommand(CLI::App* app) {
  auto* cmd = app->add_subcommand(
      "export", "Exports a scan for DCC tools: EXR / 16-bit PNG height and normal maps, GLB, PLY");
  auto a = std::make_shared<ExportArgs>();
  cmd->add_option("SCAN", a->scan, "Scan folder (written by reconstruct)")->required();
  cmd->add_option("--out", a->out, "Output folder (created; files of the same names are replaced)")
      ->required();
  cmd->add_option("--format", a->formats, "Comma-separated subset of exr,png16,glb,ply")
      ->capture_default_str();
  cmd->add_option("--normals", a->normals, "Normal-map convention: gl (OpenGL, +Y) or dx (DirectX, -Y)")
      ->check(CLI::IsMember({"gl", "dx"}))
      ->capture_default_str();
  cmd->add_option("--pixel-size", a->pixel_size_m, "Output pixel size in metres (default: the scan's)");
  cmd->add_option("--crop", a->crop, "X,Y,W,H: a rectangle of the scan's height-grid pixels");
  cmd->add_option("--max-triangles", a->max_triangles, "GLB triangle budget (decimates above it)")
      ->capture_default_str();
  cmd->add_option("--mesh-tolerance", a->mesh_tolerance_m,
                  "GLB: never split triangles whose height error is below this (metres)");
  cmd->add_option("--name", a->name, "File name prefix (default: the scan folder's name)");
  cmd->add_option("--albedo", a->albedo,
                  "Linear albedo image on the height grid (default: SCAN/albedo.exr|png, else the "
                  "session's white frame named in report.json)");
  AddMapOptions(cmd, &a->maps, /*standalone=*/false);
  cmd->callback([a] { RunExport(*a); });
}

}  // namespace mesoscan
