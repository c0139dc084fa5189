#pragma once
// Tileable crops at a physical size. A square of the (filled, flattened) height field
// is made periodic so that a renderer's Repeat extension shows no seam:
//   blend   offset-and-blend with matched statistics: the square T and its copies shifted by s
//           along x, y and both (whose own seams then lie inside the tile, at N - s) are blended
//           with weights w_x(i) w_y(j), w a sin^2 ramp from 0 at the tile's edges to 1 at N - s;
//           s is half the tile unless a shift in [N/3, 2N/3] correlates clearly better with T
//           (a periodic weave: the copies then blend in phase), moved by up to 2 pixels (as
//           well correlated) to put the blend line where the shading changes typically (see
//           below); the blend's deviation from the mean is divided by the standard deviation
//           of the weighted sum given the copies' gradient correlation (sqrt(sum of squared
//           weights) for independent copies) so the height variance and
//           the gradient statistics are the same at the seams as inside (variance-preserving
//           blending, as in Heitz and Neyret, "High-Performance By-Example Noise using a
//           Histogram-Preserving Blending Operator", HPG 2018, Eq. 2); the periodic result is
//           then rolled cyclically so the wrap seam lies on a column (row) whose height step
//           (RMS) and shading change (the mean change of the gradient vector across the line,
//           what a renderer's normals see; on the line and its neighbours) are nearest their
//           means over all lines: on a weave, neither on a crest nor on a flank's steepest
//           column, nor on the step between them;
//   mirror  the square of half the size mirrored into four quadrants: values continuous, but the
//           slope reverses at the seams (a visible crease on directional textures).
// Albedo and confidence follow the same blend; normals and derived maps are computed afterwards
// on the periodic height (maps_derived.h with periodic = true).
//
// Where the square is taken (unless TileOptions::at_px gives it): on the sample, never the bare
// mount. Among the hole-free squares, those whose share of measured (not filled) pixels standing
// off the mount (height above the mount plane z = 0 over mount_clearance_m) is within
// kTileBandFraction of the best are kept; of these, the textured ones (whose RMS height step
// between measured neighbours of the flattened height is at least kTileTextureFraction of the
// most textured one's: not a blank field of a coin) compete: the one with the most measured
// pixels on the sample is taken, and of equals the one nearest the sample's centre (the centroid
// of its pixels). The bare mount is flat and fully measured, which a
// rule of "fewest filled pixels" alone prefers over a sample whose steep flanks are filled.

#include <array>
#include <cmath>
#include <optional>
#include <string>

#include "core/height_field.h"

namespace mesoscan {

enum class TileMethod { kBlend, kMirror };

// Squares whose measured-on-sample share is at most this far below the best one compete on
// texture (a fraction of the square's pixels).
inline constexpr double kTileBandFraction = 0.05;
// Squares whose RMS height step is at least this fraction of the most textured one's count as
// textured (a stationary texture: all of them, so the choice is not driven by noise).
inline constexpr double kTileTextureFraction = 0.7;

struct TileOptions {
  double size_m = 10e-3;  // tile edge, metres; at least 8 grid pixels
  TileMethod method = TileMethod::kBlend;
  // Where the grid MakeTile gets has its pixel (0, 0) in the scan's height grid (a crop's
  // top-left corner): at_px and the report are in the scan's pixels.
  std::array<int, 2> origin_px = {0, 0};
  // Top-left pixel (column, row) of the source square in the scan's height grid; unset: the
  // square is chosen on the sample (see above). The square must lie in the grid, hole-free.
  std::optional<std::array<int, 2>> at_px;
  // A pixel is on the sample where its (unflattened, filled) height above the mount plane
  // exceeds this, metres, >= 0: well above the height noise of a scan (a few um) and below the
  // thinnest sample (paper, ~90 um).
  double mount_clearance_m = 20e-6;
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
  int origin_x = 0, origin_y = 0;          // TileOptions::origin_px (src + origin: scan pixels)
  bool chosen = true;                      // false: the square was given (TileOptions::at_px)
  // Shares of the source square's pixels: on the sample (measured or filled), measured and on
  // the sample, filled (interpolated) by the hole fill.
  double on_sample_fraction = 0, measured_on_sample_fraction = 0, filled_fraction = 0;
  double texture_rms_m = 0;  // RMS height step between measured neighbours in the square, m
  int size_px = 0;           // output tile edge in pixels
  // blend: offsets of the shifted copies (pixels), counted in the rolled tile: the lines where
  // the copies meet lie at N - shift.
  int shift_x = 0, shift_y = 0;
  HeightField field;                    // periodic height; x0/y0 of the source square
  ImageF albedo;                        // same blend (if given)
  ImageU8 filled;                       // 1 where a filled pixel contributes
  SeamStats seams_before, seams_after;  // the raw square's seams, the tile's
  std::string BriefReport() const;
};

// Picks the square (of size_m, or half for mirror) on the sample as described above, or takes
// options.at_px, and makes it periodic. `albedo`, `filled` (1 = filled by the hole fill) and
// `mount_height` (the unflattened height above the mount plane on the same grid; empty: every
// finite pixel counts as sample) may be empty. Throws Error(kBadInput) if no hole-free square of
// that size exists, Error(kUsage) at TileOptions.at_px if the given square leaves the grid or
// holds a hole.
TileResult MakeTile(const HeightField& hf, const ImageF& albedo, const ImageU8& filled,
                    const TileOptions& options, const ImageF& mount_height = ImageF());

// Which pixels of a height field (heights above the mount plane z = 0) are the sample: the
// finite ones standing more than clearance_m off the plane (the tile's rule above), when the
// field shows both the sample and the bare mount (each at least 1% of its finite pixels);
// otherwise every finite pixel. 1 = sample, 0 = the bare mount or a hole. For the preview's
// materials (render: the mount in its own neutral material).
ImageU8 OnSampleMask(const HeightField& hf, double clearance_m = TileOptions{}.mount_clearance_m);

TileMethod ParseTileMethod(const std::string& text);  // "blend" | "mirror", else Error(kUsage)
const char* TileMethodName(TileMethod method);

}  // namespace mesoscan
