// mesoscan maps SCAN --out DIR: an artist-ready material map set (maps/maps.h): holes
// filled, the sample's shape removed, tileable at a physical size, with AO and curvature.
// The same options on `export` and `reconstruct --export` (AddMapOptions).

#include <cmath>
#include <filesystem>
#include <iostream>
#include <memory>
#include <sstream>

#include "app/commands.h"
#include "app/map_options.h"
#include "app/session_checks.h"
#include "core/error.h"
#include "core/image_io.h"
#include "core/output_dir.h"
#include "core/scan_folder.h"
#include "maps/maps.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

// "X,Y": two integers >= 0.
std::array<int, 2> ParseTileAt(const std::string& text) {
  std::array<int, 2> v{};
  char comma = 0, extra = 0;
  std::istringstream in(text);
  if (!(in >> v[0] >> comma >> v[1]) || comma != ',' || (in >> extra) || v[0] < 0 || v[1] < 0)
    MESOSCAN_BAD_OPTION("TileOptions.at_px",
                        "'" << text << "': expected X,Y (pixels of the height grid, >= 0)");
  return v;
}

}  // namespace

void AddMapOptions(CLI::App* cmd, MapArgs* a, bool standalone) {
  const std::string g =
      standalone ? "" : " (map set: also writes a finished map set into OUT/maps)";
  cmd->add_option("--fill", a->fill, "Hole filling: harmonic, biharmonic or none" + g);
  cmd->add_option("--fill-max-radius-mm", a->fill_max_radius_mm,
                  "Holes wider than this (inscribed radius, mm) stay holes");
  cmd->add_option(
      "--flatten", a->flatten,
      "Remove the sample's shape: none, plane, poly:N or highpass:MM (cutoff wavelength)" + g);
  cmd->add_option("--tile", a->tile_mm, "Make a tileable square of this size in mm" + g);
  cmd->add_option("--tile-method", a->tile_method, "blend (offset-and-blend, default) or mirror");
  cmd->add_option("--tile-at", a->tile_at,
                  "X,Y: the tile's source square at this top-left pixel of the scan's height grid "
                  "(default: chosen on the sample, textured and measured)");
  cmd->add_option("--size", a->size_px,
                  "N: every map resampled to N px, a power of two (a tile N x N, else the longest "
                  "side N; the physical size kept)" +
                      g);
  cmd->add_option("--roughness", a->roughness,
                  "Principled roughness in [0, 1]: written as NAME_roughness.png, linked by the "
                  "Blender add-on" +
                      g);
  cmd->add_option("--maps", a->maps,
                  "Maps to write: any of height,normal,albedo,confidence,ao,curvature" + g);
  cmd->add_option("--ao-radius-mm", a->ao_radius_mm, "Ambient occlusion search radius, mm");
  cmd->add_option("--grey-card", a->grey_card,
                  "X,Y,W,H:R: camera pixels (of the session's white frame) wholly on a neutral "
                  "card of reflectance R on the mount; the albedo is then reflectance per channel "
                  "(else relative brightness)" +
                      g);
}

bool MapArgs::any() const {
  return !fill.empty() || !flatten.empty() || tile_mm > 0 || !maps.empty() ||
         !tile_method.empty() || !tile_at.empty() || size_px != 0 || roughness != -1.0 ||
         !grey_card.empty();
}

MapsOptions MapArgs::ToOptions(const std::string& name, const std::string& crop) const {
  MapsOptions o;
  o.name = name;
  for (const auto& [opt, v] :
       {std::pair{"--fill-max-radius-mm", fill_max_radius_mm}, std::pair{"--tile", tile_mm},
        std::pair{"--ao-radius-mm", ao_radius_mm}})
    if (!std::isfinite(v) || v < 0)
      MESOSCAN_THROW(ErrorKind::kUsage, opt << " " << v << ": expected a finite size in mm >= 0");
  if (!fill.empty()) o.fill.method = ParseFillMethod(fill);
  if (fill_max_radius_mm > 0) o.fill.max_hole_radius_m = fill_max_radius_mm * 1e-3;
  if (!flatten.empty()) o.flatten = ParseFlatten(flatten);
  if (tile_mm < 0)
    MESOSCAN_THROW(ErrorKind::kUsage, "--tile " << tile_mm << ": expected a size in mm > 0");
  if (tile_mm > 0) {
    o.tile = true;
    o.tile_options.size_m = tile_mm * 1e-3;
  }
  if (!tile_method.empty()) {
    if (tile_mm <= 0) MESOSCAN_THROW(ErrorKind::kUsage, "--tile-method needs --tile SIZE_MM");
    o.tile_options.method = ParseTileMethod(tile_method);
  }
  if (!tile_at.empty()) {
    if (tile_mm <= 0) MESOSCAN_THROW(ErrorKind::kUsage, "--tile-at needs --tile SIZE_MM");
    o.tile_options.at_px = ParseTileAt(tile_at);
  }
  o.size_px = size_px;
  o.roughness = roughness;
  if (!grey_card.empty()) o.grey_card = ParseGreyCard(grey_card, "MapsOptions.grey_card");
  if (!maps.empty()) ParseMapSelection(maps, &o);
  if (ao_radius_mm > 0) o.ao.radius_m = ao_radius_mm * 1e-3;
  if (!crop.empty()) o.crop = ParsePixelRect(crop, "MapsOptions.crop");
  o.Check();
  return o;
}

void PrintMapSet(const MapsSummary& s, const fs::path& dir) {
  std::cout << s.BriefReport() << "\n";
  const fs::path abs = fs::absolute(dir).lexically_normal();
  std::cout << "map set in " << abs.string() << " (manifest.json; contact sheet "
            << s.manifest.at("name").get<std::string>() << "_contact_sheet.png)\n";
  std::cout << "load in Blender: " << BlenderLoadLine(abs / "manifest.json") << "\n";
}

std::string ScanName(const fs::path& scan) {
  fs::path p = scan.lexically_normal();
  if (p.filename().empty()) p = p.parent_path();
  std::string name = p.filename().string();
  if (p.extension() == ".scan") name = p.stem().string();
  return name.empty() || name == "." || name == ".." ? "scan" : name;
}

std::string BlenderLoadLine(const fs::path& manifest) {
  const fs::path addon = MESOSCAN_ADDON_ZIP;  // written by the build (app/CMakeLists.txt)
  return "blender --python-expr \"import bpy; bpy.ops.preferences.addon_install(filepath='" +
         addon.string() +
         "'); bpy.ops.preferences.addon_enable(module='mesoscan_maps'); "
         "bpy.ops.import_scene.mesoscan_maps(filepath='" +
         manifest.string() + "')\"";
}

namespace {

struct MapsCmdArgs {
  std::string scan, out, crop, name, albedo, normals = "gl";
  MapArgs maps;
  bool force = false;
};

void RunMaps(const MapsCmdArgs& a) {
  MapsOptions o = a.maps.ToOptions(a.name.empty() ? ScanName(a.scan) : a.name, a.crop);
  o.normals = a.normals == "dx" ? NormalConvention::kDirectX : NormalConvention::kOpenGl;
  // --out must not be, contain or lie inside the scan or the albedo (core/output_dir.h).
  const OutputSpec out_spec{"maps", "--out", a.out, {a.scan, a.albedo}, a.force, {"manifest.json"}};
  CheckOutputFolder(out_spec);
  const Scan scan = ReadScanFolder(a.scan);
  CheckScanUsable(scan, a.scan);  // as `check` does: a damaged sample is refused
  if (!a.albedo.empty()) {
    o.albedo = ReadImage(a.albedo);
    if (o.albedo.width() != scan.height.width() || o.albedo.height() != scan.height.height())
      MESOSCAN_BAD_INPUT(a.albedo << ": expected the " << scan.height.width() << "x"
                                  << scan.height.height() << " height grid");
    if (o.albedo.channels() == 2 || o.albedo.channels() == 4) {
      ImageF rgb(o.albedo.width(), o.albedo.height(), o.albedo.channels() - 1);
      std::copy(o.albedo.data().begin(), o.albedo.data().begin() + rgb.data().size(),
                rgb.data().begin());
      o.albedo = std::move(rgb);
    }
  }
  MapsSummary s;
  WriteOutputFolder(out_spec, [&](const fs::path& tmp) { s = BuildMapSet(scan, o, tmp); });
  PrintMapSet(s, a.out);
}

}  // namespace

void AddMapsCommand(CLI::App* app) {
  auto* cmd = app->add_subcommand(
      "maps",
      "Artist-ready material maps: holes filled, shape removed, tileable at a physical size");
  auto a = std::make_shared<MapsCmdArgs>();
  cmd->add_option("SCAN", a->scan, "Scan folder (written by reconstruct)")->required();
  cmd->add_option("--out", a->out, "Map-set folder (replaced atomically)")->required();
  cmd->add_option("--crop", a->crop, "X,Y,W,H: a rectangle of the scan's height-grid pixels");
  cmd->add_option("--name", a->name, "File name prefix (default: the scan folder's name)");
  cmd->add_option("--albedo", a->albedo,
                  "Linear albedo image on the height grid (default: the "
                  "session's white frame with the projector falloff divided out)");
  cmd->add_option("--normals", a->normals, "Normal-map convention: gl or dx")
      ->check(CLI::IsMember({"gl", "dx"}))
      ->capture_default_str();
  AddMapOptions(cmd, &a->maps, /*standalone=*/true);
  cmd->add_flag("--force", a->force,
                "Replace an existing --out that is not an earlier output of `mesoscan maps`");
  cmd->callback([a] { RunMaps(*a); });
}

}  // namespace mesoscan
