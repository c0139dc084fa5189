#pragma once
// Tileable crops at a physical size. A square of the (filled, flattened) height field
// is made periodic so that a renderer's Repeat extension shows no seam:
//   blend   offset-and-blend with matched statistics: the square T and its copies shifted by s
//           along x, y and both (whose own seams then lie inside the tile, at N - s) are blended
//           with weights w_x(i) w_y(j), w a sin^2 ramp from 0 at the tile's edges to 1 at N - s;
//           s is half the tile unless a shift in [N/3, 2N/3] correlates clearly better with T
//           (a periodic weave: the copies then blend in phase); the blend's deviation from the
//           mean is divided by
//           sqrt(sum of squared weights) so the height variance (hence the gradient statistics)
//           is the same at the seams as inside (variance-preserving blending, as in Heitz and
//           Neyret, "High-Performance By-Example Noise using a Histogram-Preserving Blending
//           Operator", HPG 2018, Eq. 2);
//   mirror  the square of half the size mirrored into four quadrants: values continuous, but the
//           slope reverses at the seams (a visible crease on directional textures).
// Albedo and confidence follow the same blend; normals and derived maps are computed afterwards
// on the periodic height (maps_derived.h with periodic = true).

#include <cmath>
#include <string>

#include "core/height_field.h"

namespace mesoscan {

enum class TileMethod { kBlend, kMirror };

struct TileOptions {
  double size_m = 10e-3;  // tile edge, metres; at least 8 grid pixels
  TileMethod method = TileMethod::kBlend;
  void Check() const;
};

// Gradient statistics across the wrap-around seams of a periodic map against its interior:
// RMS of z(0, y) - z(N-1, y) (the seam's step) over RMS of z(i+1, y) - z(i, y) inside, per axis.
struct SeamStats {
  double seam_rms_x = 0, interior_rms_x = 0, seam_rms_y = 0, interior_rms_y = 0;
  // How much single interior columns (rows) scatter: the standard deviation of each column's
  // gradient RMS over interior_rms_x (rows: _y). A seam is one such column; with features
  // much wider than a pixel its ratio scatters by this much even on a perfect tile.
  double column_spread_x = 0, row_spread_y = 0;
  // Both seams pooled: the RMS of the two ratios (each seam against its own axis' interior,
  // since an anisotropic texture has different gradients along x and y).
  double pooled_ratio() const {
    return std::sqrt(0.5 * (ratio_x() * ratio_x() + ratio_y() * ratio_y()));
  }
  double ratio_x() const { return interior_rms_x > 0 ? seam_rms_x / interior_rms_x : 0; }
  double ratio_y() const { return interior_rms_y > 0 ? seam_rms_y / interior_rms_y : 0; }
};
SeamStats MeasureSeams(const ImageF& z);

struct TileResult {
  int src_x = 0, src_y = 0, src_size = 0;  // the square taken from the input (grid pixels)
  int size_px = 0;                         // output tile edge in pixels
  int shift_x = 0, shift_y = 0;            // blend: offsets of the shifted copies (pixels)
  HeightField field;                       // periodic height; x0/y0 of the source square
  ImageF albedo;                           // same blend (if given)
  ImageU8 filled;                          // 1 where a filled pixel contributes
  SeamStats seams_before, seams_after;     // the raw square's seams, the tile's
  std::string BriefReport() const;
};

// Picks the hole-free square (of size_m, or half for mirror) with the fewest filled pixels,
// nearest to the grid's centre, and makes it periodic. `albedo` and `filled` may be empty.
// Throws Error(kBadInput) if no hole-free square of that size exists.
TileResult MakeTile(const HeightField& hf, const ImageF& albedo, const ImageU8& filled,
                    const TileOptions& options);

TileMethod ParseTileMethod(const std::string& text);  // "blend" | "mirror", else Error(kUsage)
const char* TileMethodName(TileMethod method);

}  // namespace mesoscan
