#pragma once
// Artist-ready material map sets: `mesoscan maps SCAN --out DIR` and the map options
// of `export` / `reconstruct --export`. The pipeline, in order:
//   1. crop     a rectangle of the scan's height grid (ExportOptions' --crop);
//   2. fill     holes bounded by surface (maps/maps_fill.h); big holes and the outside
//               stay holes;
//   3. albedo   the session's white frame on the grid, divided by the projector's falloff
//               cos(i) / r^2 on the filled (true, unflattened) surface, filled where the height
//               was;
//   4. flatten  plane / poly:N / highpass:MM (maps/maps_flatten.h); the removed part is
//               its own map;
//   5. tile     a periodic square of a physical size (maps/maps_tile.h), seams measured;
//   5b. size    with size_px, every map resampled to N (a tile on its period, in Fourier);
//   6. derived  normals, ambient occlusion, curvature, on the final (periodic) height;
//   7. files    named as `export` names them, a manifest.json and a contact sheet, written into
//               a temporary folder that replaces DIR on success.
//
// Files (NAME = MapsOptions::name), each optional per --maps:
//   NAME_height.exr            float32 "Y", metres (flattened: relative to the removed shape);
//                              Blender Displacement Midlevel 0, Scale 1
//   NAME_height.png/.json      16-bit with midlevel/scale, as export writes it
//   NAME_height_removed.exr    the removed low-frequency part on the (cropped) source grid
//   NAME_normal_gl|dx.png/.exr tangent-space normal map from the final height
//   NAME_albedo.png            sRGB, RGB if the frames are: reflectance with a grey card (the
//                              projector's irradiance divided out), else relative (falloff
//                              divided out; 99th percentile 1)
//   NAME_albedo.exr            the same, linear float (channels R, G, B or Y)
//   NAME_confidence.png        8-bit, 0 at filled and hole pixels
//   NAME_mask.png              8-bit: 255 measured, 128 filled, 0 hole (value = hole_value_m)
//   NAME_ao.png                8-bit linear ambient occlusion (1 = open)
//   NAME_roughness.png         8-bit Principled roughness (with MapsOptions::roughness)
//   NAME_curvature.exr         float32 mean curvature, 1/m (+ on bumps)
//   NAME_cavity.png            8-bit: 0.5 flat, brighter convex, darker concave
//   NAME_contact_sheet.png     every map side by side with a scale bar
//   manifest.json              units, sizes, how each map was made, the figures, the files

#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "core/json.h"
#include "core/scan_folder.h"
#include "core/stage_timer.h"
#include "maps/export.h"
#include "maps/maps_derived.h"
#include "maps/maps_fill.h"
#include "maps/maps_flatten.h"
#include "maps/maps_tile.h"

namespace mesoscan {

struct MapSelection {
  bool height = true, normal = true, albedo = true, confidence = true, ao = true, curvature = true;
};

struct MapsOptions {
  PixelRect crop;          // region of the scan's height grid; whole() = everything
  FillOptions fill;        // hole filling (default harmonic)
  FlattenOptions flatten;  // default none
  bool tile = false;       // make a tileable square of tile_options.size_m
  TileOptions tile_options;
  AoOptions ao;
  double curvature_sigma_px = 1.0;  // Gaussian before the curvature, pixels, >= 0
  // Every map of the set resampled to this power of two, 8..16384 (a tile: N x N, band-limited
  // on its period, its physical size kept; otherwise the longest side N, the span of its pixel
  // centres kept); 0: the height grid's own pixels.
  int size_px = 0;
  // Principled roughness in [0, 1] written as NAME_roughness.png (a uniform map the Blender
  // add-on links to the BSDF's Roughness); < 0: no roughness map.
  double roughness = -1.0;
  MapSelection maps;
  NormalConvention normals = NormalConvention::kOpenGl;
  std::string name = "scan";  // file name prefix, no path separators
  // Optional linear albedo on the scan's height grid (as ExportOptions::albedo); empty: the
  // session's white frame (report.json "session") when readable.
  ImageF albedo;
  bool albedo_from_session = true;
  // A reference of known reflectance for the session's albedo (maps/export.h): given, the albedo
  // is reflectance per channel in [0, 1]; else relative (99th percentile 1), as the manifest says.
  GreyCard grey_card;
  bool contact_sheet = true;
  void Check() const;
};

struct MapsSummary {
  std::vector<std::filesystem::path> files;  // final paths, manifest last
  Json manifest;
  FillResult fill;  // stats only (field and masks cleared)
  std::string flatten;
  std::string tile;  // TileResult::BriefReport or ""
  SeamStats seams;
  double seconds = 0.0;
  StageTimings seconds_per_stage;  // wall time per stage, in order (crop, fill, ... write)
  std::string BriefReport() const;
};

// Builds the map set of `scan` into `dir` (replaced atomically). Throws Error on bad input.
MapsSummary BuildMapSet(const Scan& scan, const MapsOptions& options,
                        const std::filesystem::path& dir);

// "height,normal,albedo,confidence,ao,curvature" (any subset) into options->maps;
// Error(kUsage) at MapsOptions.maps for an unknown entry.
void ParseMapSelection(const std::string& list, MapsOptions* options);

}  // namespace mesoscan
