#pragma once
// Procedural demo objects for the virtual rig (assets/README.md): each is a height field lying on
// the mount plane z = 0 (+z up, towards the rig) plus a smooth, spatially varying Lambert albedo.
// The generators are compiled into mesoscan_sim (assets/ holds the generators of the demo assets,
// architecture.md); nothing here is downloaded or read at run time except a user's FILE.exr.
//
// Every generated grid has a margin of zero-height cells around the object, so the height field
// meets the mount plane without a gap and the object's sides appear as steep one-cell slopes.

#include <array>
#include <filesystem>
#include <optional>
#include <string>

#include "core/height_field.h"

namespace mesoscan {

struct SceneObject {
  std::string name;    // "coin", "ramp", "plane", "leaf" or the EXR file name
  HeightField height;  // metres above the mount; NaN = hole (rays pass to the mount below)
  ImageF albedo;       // same grid as height, Lambert albedo in [0, 1] (a coloured object: the
                       // BT.709 luminance of `colour`)
  // Optional: the same grid, 3 channels, the Lambert albedo (reflectance) per channel R, G, B in
  // [0, 1]; empty for a grey object (every channel = albedo).
  ImageF colour;
  // Optional: a neutral grey card of known reflectance lying on the mount (under the object where
  // they overlap: the object's grid wins).
  struct Card {
    double x0 = 0, y0 = 0, x1 = 0, y1 = 0;  // world rectangle, metres
    double reflectance = 0.18;
  };
  std::optional<Card> card;

  // Lambert albedo at world (x, y): bilinear in the object's grid, the card or MountAlbedo outside
  // it.
  double Albedo(double x, double y) const;
  // Per channel R, G, B (a grey object, the card and the mount: the same value thrice).
  std::array<double, 3> ColourAlbedo(double x, double y) const;
  // True surface height at world (x, y): height.Sample inside the grid where finite, else 0 (the
  // mount, also seen through holes).
  double SurfaceZ(double x, double y) const;
};

// Albedo of the mount board: 0.30 +- 0.04, smooth (periods of a few cm).
double MountAlbedo(double x, double y);

// Coin: 19 mm diameter, 1.3 mm thick at its rim; a 1.2 mm field with a raised rim (0.1 mm), a
// smooth portrait-like bump (up to 90 um), lettering around the edge from a 5x7 bitmap font
// (40 um relief, 0.2 mm font pixels) and a bead ring (20 um). Centred on the origin.
SceneObject MakeCoin(double pixel_size_m = 10e-6);

// Paper ramp (Ritz et al. 2012, Fig. 12): kRampSheets stacked sheets, each kRampSheetM thick,
// sheet k covering x in [kRampX0 + k * kRampStepWidthM, kRampX1], |y| <= kRampHalfWidthM.
inline constexpr int kRampSheets = 10;
inline constexpr double kRampSheetM = 93e-6;
inline constexpr double kRampStepWidthM = 3e-3;
inline constexpr double kRampX0 = -15e-3, kRampX1 = 15e-3, kRampHalfWidthM = 10e-3;
SceneObject MakePaperRamp(double pixel_size_m = 20e-6);

// Tilted plane (steel bar test): z = (x - kBarX0) * tan(kBarAngleRad) for x in [kBarX0, kBarX1],
// |y| <= kBarHalfWidthM. A bilinear grid represents a plane exactly.
inline constexpr double kBarX0 = -20e-3, kBarX1 = 20e-3, kBarHalfWidthM = 8e-3;
inline constexpr double kBarAngleRad = 7.0 * 3.14159265358979323846 / 180.0;
SceneObject MakeTiltedPlane(double pixel_size_m = 50e-6);

// Leaf: 40 mm x 18 mm, lying about 1.0-1.3 mm above the mount (curled), with a midrib 60 um
// deep and lateral veins 45 um deep.
SceneObject MakeLeaf(double pixel_size_m = 20e-6);

// Material samples (a material, not an object: scanned into tileable maps): a square
// of 2 * kMaterialHalfM lying on the mount with a slight tilt (1.0% along x, 0.6% along y) and a
// 0.15 mm sag towards its corners.
inline constexpr double kMaterialHalfM = 15e-3;
// Woven fabric: a plain weave of threads kFabricPitchM apart (0.34 mm wide, 0.16 mm thick,
// passing over and under with +-70 um), fine twist ridges of 6 um; about 0.3-0.7 mm thick.
inline constexpr double kFabricPitchM = 0.8e-3;
SceneObject MakeFabric(double pixel_size_m = 20e-6);
// Hammered metal: a 0.8 mm plate with overlapping spherical hammer dents (15-35 um deep,
// 1.1-1.6 cells across, on a jittered grid of kHammerCellM) and 1.5 um brushing marks.
inline constexpr double kHammerCellM = 1.6e-3;
SceneObject MakeHammeredMetal(double pixel_size_m = 20e-6);

// Impasto painting: a canvas of 2 * half_x_m by 2 * half_y_m (default 200 x 150 mm) on a 0.4 mm
// stretcher-flat ground with a slow 40 um undulation and a fine canvas weave (8 um, 0.6 mm
// pitch), covered by overlapping brush strokes on a jittered 7 mm grid (two layers): each 6-14
// mm long and 1.6-3.2 mm wide, 80-420 um high at its spine, tapering at both ends, with bristle
// ridges (+-12 um, 0.9 mm apart) along it; each stroke has its own paint albedo (0.15-0.85).
// Larger than one camera field: the ground truth of a stitched mosaic (`simulate
// --field-offset`).
inline constexpr double kImpastoHalfXM = 100e-3, kImpastoHalfYM = 75e-3;
SceneObject MakeImpasto(double pixel_size_m = 100e-6, double half_x_m = kImpastoHalfXM,
                        double half_y_m = kImpastoHalfYM);

// A height EXR in the scan-outputs.md layout (channel Z, grid attributes), placed as given; a
// smooth albedo 0.5 +- 0.1 is made up. Throws Error naming the file if unreadable.
SceneObject LoadHeightExrObject(const std::filesystem::path& path);

// BT.709 luminance of a linear R, G, B triple: 0.2126 R + 0.7152 G + 0.0722 B.
double Luminance(const std::array<double, 3>& rgb);

// Gives the object its natural colour (`colour`, and `albedo` its luminance) if it has one: the
// fabric is dyed (a madder red, the thread's own brightness variations kept), the coin is a
// patinated copper (a warm brown with patches of green verdigris). Returns false (the object
// unchanged) for the grey objects.
bool ColourObject(SceneObject* object);

// "coin" | "plane" | "ramp" | "leaf" | "fabric" | "metal" | "impasto" | "impasto:WxH" (the
// canvas W x H mm) | "mount" (the empty mount) | a path ending in .exr. pixel_size_m <= 0: the
// object's default grid spacing. Throws Error(kBadInput) for anything else, at the options field
// `option` (the caller's, e.g. "SimulateOptions.object").
SceneObject MakeObject(const std::string& spec, double pixel_size_m = 0.0,
                       const std::string& option = "");

}  // namespace mesoscan
