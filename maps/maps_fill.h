#pragma once
// Hole filling of a height field for displacement maps: holes bounded by measured
// surface are filled smoothly from their border by solving Laplace's equation (harmonic) or the
// thin-plate / biharmonic equation on the grid with a sparse Cholesky factorisation (Eigen);
// large holes (inscribed radius above a limit: the outside of the sample, a missing region) stay
// NaN. Holes reaching the grid's border are filled only when narrow too (a crack or the shadowed
// gaps of a fabric that run to the edge of the field of view), with no constraint at the border.
// Filled pixels are marked in `filled` and get confidence 0.
//
// Harmonic fill error bound (discrete maximum principle): inside a hole contained in a disc of
// radius R centred at c, |z_fill - z_true| <= max|lap z_true| / 4 * (R^2 - |x - c|^2) + max
// |boundary noise|, lap the 5-point Laplacian in metres / pixel^2 (so R in pixels). The filled
// surface is continuous at the border (the border pixels are its boundary values) and stays
// within the range of its border (no trench, no overshoot).

#include <cstdint>
#include <string>

#include "core/height_field.h"

namespace mesoscan {

enum class FillMethod {
  kNone,        // leave every hole NaN
  kHarmonic,    // lap z = 0 in the hole, z = measured on its border: no overshoot (default)
  kBiharmonic,  // lap^2 z = 0: least-squares curvature continuity with the 1-ring around it
};

struct FillOptions {
  FillMethod method = FillMethod::kHarmonic;
  // Holes whose largest inscribed radius (distance from the farthest hole pixel to the nearest
  // measured pixel) exceeds this stay holes. Metres, > 0.
  double max_hole_radius_m = 1.0e-3;
  // Fill narrow holes touching the grid's border too (Neumann condition there); false leaves
  // every hole that reaches the border.
  bool fill_border_holes = true;
  void Check() const;
};

struct FillResult {
  HeightField field;  // z filled where it was safe to; confidence 0 at filled pixels
  ImageU8 filled;     // 1 where the pixel was filled, else 0
  int64_t filled_pixels = 0, holes_filled = 0;
  int64_t holes_left = 0, pixels_left = 0;  // too large or reaching the border
  double seconds = 0.0;
  std::string BriefReport() const;
};

// Fills the holes (NaN) of `hf`. Never throws for any input grid; NaN-free output where filled.
FillResult FillHoles(const HeightField& hf, const FillOptions& options);

// An image on the grid (an albedo, any channel count) given wherever `want` is non-zero (the
// height is known there, measured or filled): its NaN gaps are filled per channel as FillHoles
// fills heights (`options`, harmonic when its method is none), and what that leaves (a gap wider
// than the limit, one that runs into a hole of the height or to the border) is inpainted from
// the nearest known values (OpenCV's Telea, Telea 2004). The image's finite values are kept
// everywhere; a gap stays NaN where `want` is 0, and everywhere if the channel has no finite
// value.
// pixel_size_m: the grid's spacing (for options.max_hole_radius_m).
ImageF FillImageWhere(const ImageF& image, const ImageU8& want, double pixel_size_m,
                      const FillOptions& options);

// "harmonic" | "biharmonic" | "none"; throws Error(kUsage) at FillOptions.method otherwise.
FillMethod ParseFillMethod(const std::string& text);
const char* FillMethodName(FillMethod method);

}  // namespace mesoscan
