#include "heightfield/mixed_pixels.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>

#include "core/error.h"
#include "core/parallel.h"

namespace mesoscan {

void MixedPixelOptions::Check() const {
  if (!(max_sigmas > 0)) MESOSCAN_BAD_INPUT("max_sigmas: expected > 0, got " << max_sigmas);
  if (!(outlier_footprints >= 0))
    MESOSCAN_BAD_INPUT("outlier_footprints: expected >= 0, got " << outlier_footprints);
  if (!(shadow_edge_ratio >= 0 && shadow_edge_ratio <= 1))
    MESOSCAN_BAD_INPUT("shadow_edge_ratio: expected in [0, 1], got " << shadow_edge_ratio);
  if (!(dim_ratio >= 0 && dim_ratio <= 1))
    MESOSCAN_BAD_INPUT("dim_ratio: expected in [0, 1], got " << dim_ratio);
  if (!(dim_sigmas > 0)) MESOSCAN_BAD_INPUT("dim_sigmas: expected > 0, got " << dim_sigmas);
  if (passes < 1) MESOSCAN_BAD_INPUT("passes: expected >= 1, got " << passes);
  if (!(dim_sharpness >= 0))
    MESOSCAN_BAD_INPUT("dim_sharpness: expected >= 0, got " << dim_sharpness);
}

namespace {

// One pass of the four tests over the points of `in`; only the pixels with todo[i] != 0 if
// `todo` is given (the others are left 0).
std::vector<uint8_t> FindMixedPixelsOnce(const MixedPixelInput& in,
                                         const MixedPixelOptions& options,
                                         const std::vector<uint8_t>* todo = nullptr) {
  const int w = in.width, h = in.height;
  std::vector<uint8_t> reject(static_cast<size_t>(w) * h, 0);
  if (w <= 0 || h <= 0) return reject;
  MESOSCAN_CHECK(in.z != nullptr && in.sigma_z != nullptr);
  const bool shadow_test = options.shadow_edge_ratio > 0 && in.white && in.unlit;
  const bool dim_test = options.dim_ratio > 0 && in.white;
  auto inside = [&](int x, int y) { return x >= 0 && y >= 0 && x < w && y < h; };
  auto index = [&](int x, int y) { return static_cast<size_t>(y) * w + x; };
  auto z_at = [&](int x, int y) { return inside(x, y) ? in.z[index(x, y)] : NAN; };
  // Unknown sigma counts as 0: the step test then needs the other terms to be known.
  auto s2_at = [&](int x, int y) {
    const float s = in.sigma_z[index(x, y)];
    return std::isfinite(s) && s > 0 ? static_cast<double>(s) * s : 0.0;
  };
  const double outlier_floor = options.outlier_footprints * in.footprint_m;

  ParallelForRows(h, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y)
      for (int x = 0; x < w; ++x) {
        const size_t i = index(x, y);
        if (todo && !(*todo)[i]) continue;
        const double z = in.z[i];
        if (!std::isfinite(z)) continue;
        const double s2p = s2_at(x, y);
        bool mixed = false;
        for (int axis = 0; axis < 2 && !mixed; ++axis) {
          const int dx = axis == 0, dy = axis == 1;
          int sides = 0, outlier_sides = 0, above = 0, below = 0;
          double worst_sigmas = 0;  // largest |deviation| / sd over the two sides
          // Each side's extrapolation at the point and its own change over one pixel.
          double line[2] = {0, 0}, slope[2] = {0, 0}, deviation[2] = {0, 0};
          bool has[2] = {false, false};
          for (int sgn : {-1, 1}) {
            const int x1 = x + sgn * dx, y1n = y + sgn * dy;
            const int x2 = x + 2 * sgn * dx, y2n = y + 2 * sgn * dy;
            const float z1 = z_at(x1, y1n), z2 = z_at(x2, y2n);
            if (!std::isfinite(z1) || !std::isfinite(z2)) continue;
            ++sides;
            const double d = z - (2.0 * z1 - z2);
            const double sd = std::sqrt(s2p + 4.0 * s2_at(x1, y1n) + s2_at(x2, y2n));
            if (sd > 0 && std::abs(d) > options.max_sigmas * sd) (d > 0 ? above : below) += 1;
            if (sd > 0) worst_sigmas = std::max(worst_sigmas, std::abs(d) / sd);
            const int k = sgn > 0;
            has[k] = true;
            line[k] = 2.0 * z1 - z2;
            slope[k] = std::abs(static_cast<double>(z1) - z2);
            deviation[k] = d;
            if (options.outlier_footprints > 0 &&
                std::abs(d) > std::max(outlier_floor, 8.0 * std::sqrt(s2p)))
              ++outlier_sides;
          }
          // Step: strictly between the two sides' extrapolations, far from both.
          if (above == 1 && below == 1) mixed = true;
          if (sides > 0 && outlier_sides == sides) mixed = true;
          // A sharp jump: the two sides' lines are further apart at the point than the sides
          // change over a pixel, by the factor dim_sharpness (a smooth flank, even a curved one,
          // changes gradually); with one side, the point is further off its line than that
          // side's own change per pixel, by the same factor.
          const bool sharp =
              has[0] && has[1]
                  ? std::abs(line[1] - line[0]) > options.dim_sharpness * (slope[0] + slope[1])
                  : (has[0] && std::abs(deviation[0]) > options.dim_sharpness * slope[0]) ||
                        (has[1] && std::abs(deviation[1]) > options.dim_sharpness * slope[1]);
          // Dimmed step: darker than the brighter neighbour on this axis, off a side's line, at a
          // sharp jump.
          if (dim_test && !mixed && worst_sigmas > options.dim_sigmas && sharp) {
            const float wp = in.white[i];
            float brighter = 0;
            for (int sgn : {-1, 1}) {
              const int xn = x + sgn * dx, yn = y + sgn * dy;
              if (inside(xn, yn) && std::isfinite(in.white[index(xn, yn)]))
                brighter = std::max(brighter, in.white[index(xn, yn)]);
            }
            if (std::isfinite(wp) && wp < options.dim_ratio * brighter) mixed = true;
          }
          if (shadow_test && !mixed) {
            for (int sgn : {-1, 1}) {
              const int xu = x + sgn * dx, yu = y + sgn * dy;  // the unlit side
              const int xo = x - sgn * dx, yo = y - sgn * dy;  // the opposite side
              if (!inside(xu, yu) || !inside(xo, yo) || !in.unlit[index(xu, yu)]) continue;
              const float wp = in.white[i], wo = in.white[index(xo, yo)];
              if (std::isfinite(wp) && std::isfinite(wo) && wp < options.shadow_edge_ratio * wo)
                mixed = true;
            }
          }
        }
        reject[i] = mixed;
      }
  });
  return reject;
}

}  // namespace

std::vector<uint8_t> FindMixedPixels(const MixedPixelInput& in, const MixedPixelOptions& options) {
  options.Check();
  std::vector<uint8_t> reject = FindMixedPixelsOnce(in, options);
  if (options.passes < 2 || in.width <= 0 || in.height <= 0) return reject;
  // Later passes judge the points again without the ones rejected so far: a mixed neighbour
  // bends a side's extrapolation, its hole leaves the clean side to judge by.
  std::vector<float> z(in.z, in.z + static_cast<size_t>(in.width) * in.height);
  MixedPixelInput cleaned = in;
  cleaned.z = z.data();
  // A pixel's tests read z within 2 pixels along its row and column only: a later pass needs to
  // judge again only the pixels that close to a point rejected by the pass before (the others
  // would repeat their verdict, already in `reject`).
  const int w = in.width, h = in.height;
  std::vector<uint8_t> fresh = reject, todo(z.size());
  for (int pass = 1; pass < options.passes; ++pass) {
    std::fill(todo.begin(), todo.end(), 0);
    ParallelForRows(h, [&](int y0, int y1) {
      for (int y = y0; y < y1; ++y)
        for (int x = 0; x < w; ++x) {
          const size_t i = static_cast<size_t>(y) * w + x;
          if (!fresh[i]) continue;
          z[i] = std::numeric_limits<float>::quiet_NaN();
          for (int d = -2; d <= 2; ++d) {
            if (x + d >= 0 && x + d < w) todo[i + d] = 1;  // same row: this task's rows only
          }
        }
    });
    for (int y = 0; y < h; ++y)  // the column neighbours may be in another task's rows
      for (int x = 0; x < w; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        if (!fresh[i]) continue;
        for (int d = -2; d <= 2; ++d)
          if (y + d >= 0 && y + d < h) todo[i + static_cast<ptrdiff_t>(d) * w] = 1;
      }
    const std::vector<uint8_t> more = FindMixedPixelsOnce(cleaned, options, &todo);
    bool changed = false;
    for (size_t i = 0; i < z.size(); ++i) {
      fresh[i] = more[i] && !reject[i];
      changed |= fresh[i];
      reject[i] |= more[i];
    }
    if (!changed) break;
  }
  return reject;
}

}  // namespace mesoscan
