#pragma once
// Exports of a scan for DCC tools (Blender, Substance, Maya/Arnold, Houdini, Unreal, Unity)
// and point-cloud tools (MeshLab, CloudCompare), at physical scale with stated conventions:
//
//   <name>_height.exr        float32, one channel "Y", metres above the mount plane (z = 0):
//                            displacement midlevel 0, scale 1. Holes filled (see manifest).
//   <name>_height.png        16-bit grey; metres = (value/65535 - midlevel) * scale, with
//   <name>_height.json       the sidecar giving min, max, midlevel, scale (Blender Displacement
//                            Midlevel/Scale, Arnold zero_value/height), units and sizes.
//   <name>_normal_gl|dx.png  tangent-space normal map, 16-bit RGB, rgb = 0.5 + 0.5 n
//   <name>_normal_gl|dx.exr  the same in float32 (channels R, G, B)
//   <name>_confidence.png    8-bit grey, confidence in [0, 1]
//   <name>_albedo.png        8-bit sRGB, relative albedo (when a white frame is available)
//   <name>.glb               the height field as geometry in metres (glTF +Y up), normals,
//                            UVs, tangents, a material with normal and base colour textures
//   <name>.ply               binary point cloud: x y z nx ny nz confidence
//   manifest.json            units, conventions, channels, files (written last)
//
// The maps share one grid: pixel (i, j) is the height-field sample at world
// (x0 + i * pixel_size, y0 - j * pixel_size); row 0 is the +y edge, so image "up" is world +y.
// Every file is written to a temporary name and renamed.

#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "core/json.h"
#include "core/rect.h"
#include "core/scan_folder.h"
#include "maps/maps_derived.h"
#include "maps/maps_fill.h"
#include "session/session.h"

namespace mesoscan {

enum class NormalConvention { kOpenGl, kDirectX };

struct ExportOptions {
  // Formats to write. Confidence and albedo PNGs come with any of exr / png16 / glb.
  bool exr = true;    // <name>_height.exr, <name>_normal_*.exr
  bool png16 = true;  // <name>_height.png + .json sidecar, <name>_normal_*.png
  bool glb = true;    // <name>.glb
  bool ply = true;    // <name>.ply
  // Tangent-space normal map convention of the PNG/EXR normal maps: OpenGL (+Y, green up;
  // Blender, Maya, Houdini, Unity) or DirectX (-Y; Unreal, Substance's DirectX preset). The
  // GLB always embeds OpenGL (the glTF convention).
  NormalConvention normals = NormalConvention::kOpenGl;
  // Output pixel size, metres, > 0; 0 keeps the scan's grid. Larger: area-weighted average of
  // the valid samples (a hole where under half the footprint is valid); smaller: bilinear.
  double pixel_size_m = 0.0;
  // Region of the scan's height grid to export (scan grid pixels, applied before resampling);
  // whole() = everything.
  PixelRect crop;
  // GLB: at most this many triangles, > 0 (see maps/export_mesh.h).
  int64_t max_triangles = 1'000'000;
  // The GLB's material beyond its normal and base-colour textures, as the map set has them
  // (export with map-set options): an ambient-occlusion texture on the export grid
  // (occlusionTexture, maps_derived.h AmbientOcclusion with glb_ao) and the roughness
  // (roughnessFactor, < 0: the default 0.6).
  bool glb_occlusion = false;
  AoOptions glb_ao;
  double glb_roughness = -1.0;
  // GLB: triangles whose RTIN error is <= this are never split (metres, >= 0).
  double mesh_tolerance_m = 0.0;
  // File name prefix, non-empty, no path separators.
  std::string name = "scan";
  // Optional linear albedo on the scan's height grid (1 or 3 channels, values >= 0; scaled so
  // its 99th percentile is 1). Empty: the session's white frame named by report.json
  // ("session") is projected onto the grid, if readable; else no albedo is written.
  ImageF albedo;
  // Look for the session's white frame when `albedo` is empty.
  bool albedo_from_session = true;
  // Hole filling of the height and normal maps (maps/maps_fill.h): holes bounded by
  // surface are filled harmonically from their border (no trench at a shadowed wall); the
  // others get the lowest height (hole_value_m). PLY and GLB keep only measured samples.
  FillOptions fill;

  void Check() const;
};

struct ExportSummary {
  std::vector<std::filesystem::path> files;  // every file written, manifest last
  Json manifest;
  int64_t triangles = 0, vertices = 0;             // GLB mesh (0 if not written)
  double max_height_error_m = 0.0;                 // GLB mesh vs the height samples
  double seconds = 0.0;                            // the whole export, wall time
  std::map<std::string, double> seconds_per_file;  // each writer's wall time (run in parallel)
  std::string BriefReport() const;
};

// Writes the exports of `scan` into `dir` (created if missing; existing files of the same
// names are replaced, other files are left alone). Throws Error naming the file on failure.
ExportSummary ExportScan(const Scan& scan, const ExportOptions& options,
                         const std::filesystem::path& dir);

// Every export format, comma-separated: "exr,png16,glb,ply".
std::string ExportFormatList();

// A subset of ExportFormatList() (any order; "png" for png16, "gltf" for glb) into the format
// flags of `options`. Throws Error(kUsage) at ExportOptions.formats naming the unknown entry.
void ParseExportFormats(const std::string& list, ExportOptions* options);

// The export grid: `crop` of `hf`, then resampled to `pixel_size_m` (0: unchanged). Also
// applies the same crop/resampling to an image on the scan grid (any channel count; NaN-aware).
HeightField CropAndResample(const HeightField& hf, const PixelRect& crop, double pixel_size_m);
ImageF CropAndResampleImage(const ImageF& image, const HeightField& hf, const PixelRect& crop,
                            double pixel_size_m);

// Relative albedo on the grid of `hf` from a session's white frame (minus its black frame if
// present), linearised per the session's camera response, sampled where each height sample
// projects into the camera. Without a white frame, twice the mean of the sine set (shift 0) whose
// phases are spread most evenly (>= 3, mean phasor < 0.05) stands in for it (the spec's texture of
// a session without white). Channels as the frame (1 or 3). Unscaled; NaN in holes or outside the
// frame. `source` (optional) receives which frames were used. Throws Error if neither exists.
ImageF AlbedoFromSession(const HeightField& hf, const std::filesystem::path& session_dir,
                         std::string* source = nullptr);

// The texture of a session on its camera grid: the white frame minus the black frame (or the
// stand-in above), linear, >= 0, its colour channels (1 or 3; a camera raw frame's R, G, B on the
// half-size grid, session/raw_frame.h).
ImageF SessionTexture(const Session& session, std::string* source = nullptr);

// The projector's irradiance on a surface point p with normal n, relative to a surface facing it
// at the reference distance r0 = |projector centre| (the world origin's distance): cos(i) *
// (r0 / r)^2 times the rig's falloff at p's projector pixel (rig.projector.falloff). NaN where the
// surface faces away or lies outside the projector's model.
double ProjectorIrradianceAt(const Rig& rig, const Vec3d& p, const Vec3d& n);

// The projector's irradiance over the footprint of height sample (i, j) of `hf`: the mean over its
// four quadrant facets (the plane through the sample and its horizontal and vertical neighbour on
// that side) of ProjectorIrradianceAt at the sample, a facet facing away counting 0. A facet needs
// both neighbours usable (`usable`: hf's grid, != 0 for a measured sample); NaN if none is, or if
// the sample lies outside the projector's model. cos(i) is concave in the slope, so the
// central-difference normal (the facets' mean slope) overstates the light on relief that changes
// within two samples; the facets keep the slopes the samples hold.
double ProjectorIrradianceOverFacets(const Rig& rig, const HeightField& hf, const ImageU8& usable,
                                     int i, int j);

// A reference of known reflectance: a neutral grey card on the mount, a rectangle of camera
// pixels wholly on it.
struct GreyCard {
  PixelRect camera_px;  // w = 0: none
  double reflectance = 0;
  bool given() const { return camera_px.w > 0 && camera_px.h > 0; }
};
// "X,Y,W,H:REFLECTANCE"; Error(kUsage) at `option` otherwise.
GreyCard ParseGreyCard(const std::string& text, const std::string& option);

// The card's texture per channel divided by the projector's irradiance on the mount plane
// (ProjectorIrradianceAt with n = +z): its median per channel is the level of reflectance 1 is
// `level / reflectance`; `spread` the largest (p90 - p10) / median over the channels (a card
// that is not uniformly lit or not where it was said shows a large spread). Throws Error
// (kBadInput) if the rectangle leaves the frame or holds fewer than 16 lit pixels.
struct CardLevel {
  std::vector<double> level;  // per channel of the texture
  double spread = 0;
  int pixels = 0;
};
CardLevel MeasureGreyCard(const Session& session, const ImageF& texture, const GreyCard& card);

// The tangent-space normal map of world normals `n` (3 channels, NaN in holes -> flat), encoded
// rgb = 0.5 + 0.5 * n, with the convention's sign of green.
ImageF EncodeNormalMap(const ImageF& n, NormalConvention convention);

// The session folder a scan's report.json names ("session", or the older "session_dir" /
// "session_path", a string or an object with "path"/"dir"/"root"); "" if none.
std::string SessionPathFromReport(const Json& report);

}  // namespace mesoscan
