#include "heightfield/mixed_pixels.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <limits>

#include "core/error.h"

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

// What every pixel's tests share: the input, the options, the squared sigmas and the derived
// thresholds.
struct MixedPixelJudge {
  const MixedPixelInput& in;
  const MixedPixelOptions& options;
  const double* s2;  // sigma_z squared per pixel; unknown sigma counts as 0 (see SquaredSigmas)
  bool shadow_test, dim_test;
  double outlier_floor;
  // 0.99 times the square of the smaller sigma limit that a side's deviation is compared with
  // (max_sigmas, and dim_sigmas with the dim test): below it neither comparison holds.
  double near_limit2;

  // The four tests of pixel (x, y) (index i, finite z). kInterior: (x, y) is at least 2 pixels
  // from every edge, so no neighbour needs a bounds check (same arithmetic, same verdict).
  template <bool kInterior>
  bool Mixed(int x, int y, size_t i) const {
    const int w = in.width, h = in.height;
    auto inside = [&](int xx, int yy) {
      return kInterior || (xx >= 0 && yy >= 0 && xx < w && yy < h);
    };
    const double z = in.z[i];
    const double s2p = s2[i];
    // The outlier test's threshold, the same for every side (one square root per pixel).
    const double outlier_at = std::max(outlier_floor, 8.0 * std::sqrt(s2p));
    bool mixed = false;
    for (int axis = 0; axis < 2 && !mixed; ++axis) {
      const int dx = axis == 0, dy = axis == 1;
      const ptrdiff_t step = axis == 0 ? 1 : static_cast<ptrdiff_t>(w);
      int sides = 0, outlier_sides = 0, above = 0, below = 0;
      double worst_sigmas = 0;  // largest |deviation| / sd over the two sides
      // Each side's extrapolation at the point and its own change over one pixel.
      double line[2] = {0, 0}, slope[2] = {0, 0}, deviation[2] = {0, 0};
      bool has[2] = {false, false};
      for (int sgn : {-1, 1}) {
        const size_t i1 = i + sgn * step, i2 = i + 2 * sgn * step;
        const float z1 = inside(x + sgn * dx, y + sgn * dy) ? in.z[i1] : NAN;
        const float z2 = inside(x + 2 * sgn * dx, y + 2 * sgn * dy) ? in.z[i2] : NAN;
        if (!std::isfinite(z1) || !std::isfinite(z2)) continue;
        ++sides;
        const double d = z - (2.0 * z1 - z2);
        const double v = s2p + 4.0 * s2[i1] + s2[i2];
        // Most sides lie well within both sigma limits: d^2 below 0.99 times the smaller limit
        // squared times v decides that without the square root (rounding is ~1e-16 of it), so
        // the counts and the dim test's comparison come out as below.
        if (!(d * d < near_limit2 * v)) {
          const double sd = std::sqrt(v);
          if (sd > 0 && std::abs(d) > options.max_sigmas * sd) (d > 0 ? above : below) += 1;
          if (sd > 0) worst_sigmas = std::max(worst_sigmas, std::abs(d) / sd);
        }
        const int k = sgn > 0;
        has[k] = true;
        line[k] = 2.0 * z1 - z2;
        slope[k] = std::abs(static_cast<double>(z1) - z2);
        deviation[k] = d;
        if (options.outlier_footprints > 0 && std::abs(d) > outlier_at) ++outlier_sides;
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
          const size_t n = i + sgn * step;
          if (inside(x + sgn * dx, y + sgn * dy) && std::isfinite(in.white[n]))
            brighter = std::max(brighter, in.white[n]);
        }
        if (std::isfinite(wp) && wp < options.dim_ratio * brighter) mixed = true;
      }
      if (shadow_test && !mixed) {
        for (int sgn : {-1, 1}) {
          const size_t iu = i + sgn * step;  // the unlit side
          const size_t io = i - sgn * step;  // the opposite side
          if (!inside(x + sgn * dx, y + sgn * dy) || !inside(x - sgn * dx, y - sgn * dy) ||
              !in.unlit[iu])
            continue;
          const float wp = in.white[i], wo = in.white[io];
          if (std::isfinite(wp) && std::isfinite(wo) && wp < options.shadow_edge_ratio * wo)
            mixed = true;
        }
      }
    }
    return mixed;
  }
};

// MixedPixelJudge::near_limit2.
double NearLimit2(const MixedPixelInput& in, const MixedPixelOptions& options) {
  const bool dim_test = options.dim_ratio > 0 && in.white;
  const double k = dim_test ? std::min(options.max_sigmas, options.dim_sigmas) : options.max_sigmas;
  return 0.99 * k * k;
}

// sigma_z squared per pixel, as the tests use it: unknown (NaN) or <= 0 counts as 0, so the step
// test then needs the other terms to be known.
std::vector<double> SquaredSigmas(const MixedPixelInput& in) {
  std::vector<double> s2(static_cast<size_t>(in.width) * in.height);
  tbb::parallel_for(tbb::blocked_range<int>(0, in.height, 8), [&](const auto& range) {
    const int y0 = range.begin(), y1 = range.end();
    for (size_t i = static_cast<size_t>(y0) * in.width; i < static_cast<size_t>(y1) * in.width;
         ++i) {
      const float s = in.sigma_z[i];
      s2[i] = std::isfinite(s) && s > 0 ? static_cast<double>(s) * s : 0.0;
    }
  });
  return s2;
}

MixedPixelJudge MakeJudge(const MixedPixelInput& in, const MixedPixelOptions& options,
                          const std::vector<double>& s2) {
  return {in,
          options,
          s2.data(),
          options.shadow_edge_ratio > 0 && in.white && in.unlit,
          options.dim_ratio > 0 && in.white,
          options.outlier_footprints * in.footprint_m,
          NearLimit2(in, options)};
}

// The verdict on pixel i (0 where its z is not finite).
bool Judge(const MixedPixelJudge& judge, size_t i, int w, int h) {
  if (!std::isfinite(judge.in.z[i])) return false;
  const int x = static_cast<int>(i % w), y = static_cast<int>(i / w);
  return y >= 2 && y + 2 < h && x >= 2 && x + 2 < w ? judge.Mixed<true>(x, y, i)
                                                    : judge.Mixed<false>(x, y, i);
}

// The pixels with reject[i] != 0, in increasing order (gathered per band of rows on the pool).
std::vector<size_t> RejectedPixels(const std::vector<uint8_t>& reject, int w, int h) {
  constexpr int kRows = 64;
  const int bands = (h + kRows - 1) / kRows;
  std::vector<std::vector<size_t>> per_band(std::max(bands, 0));
  tbb::parallel_for<int64_t>(0, bands, [&](int64_t b) {
    const size_t end = static_cast<size_t>(std::min(h, static_cast<int>(b + 1) * kRows)) * w;
    for (size_t i = static_cast<size_t>(b) * kRows * w; i < end; ++i)
      if (reject[i]) per_band[b].push_back(i);
  });
  std::vector<size_t> out;
  for (const std::vector<size_t>& p : per_band) out.insert(out.end(), p.begin(), p.end());
  return out;
}

// One pass of the four tests over the points of `in`. s2: SquaredSigmas(in).
std::vector<uint8_t> FindMixedPixelsOnce(const MixedPixelInput& in,
                                         const MixedPixelOptions& options,
                                         const std::vector<double>& s2) {
  const int w = in.width, h = in.height;
  std::vector<uint8_t> reject(static_cast<size_t>(w) * h, 0);
  if (w <= 0 || h <= 0) return reject;
  MESOSCAN_CHECK(in.z != nullptr && in.sigma_z != nullptr);
  const MixedPixelJudge judge = MakeJudge(in, options, s2);
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const auto& range) {
    const int y0 = range.begin(), y1 = range.end();
    for (int y = y0; y < y1; ++y) {
      const bool interior_row = y >= 2 && y + 2 < h;
      for (int x = 0; x < w; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        if (!std::isfinite(in.z[i])) continue;
        reject[i] = interior_row && x >= 2 && x + 2 < w ? judge.Mixed<true>(x, y, i)
                                                        : judge.Mixed<false>(x, y, i);
      }
    }
  });
  return reject;
}

}  // namespace

std::vector<uint8_t> FindMixedPixels(const MixedPixelInput& in, const MixedPixelOptions& options) {
  options.Check();
  if (in.width <= 0 || in.height <= 0) return {};
  MESOSCAN_CHECK(in.z != nullptr && in.sigma_z != nullptr);
  const std::vector<double> s2 = SquaredSigmas(in);
  std::vector<uint8_t> reject = FindMixedPixelsOnce(in, options, s2);
  if (options.passes < 2 || in.width <= 0 || in.height <= 0) return reject;
  // Later passes judge the points again without the ones rejected so far: a mixed neighbour
  // bends a side's extrapolation, its hole leaves the clean side to judge by.
  std::vector<float> z(in.z, in.z + static_cast<size_t>(in.width) * in.height);
  MixedPixelInput cleaned = in;
  cleaned.z = z.data();
  const MixedPixelJudge judge = MakeJudge(cleaned, options, s2);
  // A pixel's tests read z within 2 pixels along its row and column only: a later pass needs to
  // judge again only the pixels that close to a point rejected by the pass before (the others
  // would repeat their verdict, already in `reject`). Those rejections are few: the pass works
  // on their list, not on the image.
  const int w = in.width, h = in.height;
  std::vector<size_t> fresh = RejectedPixels(reject, w, h);
  std::vector<uint8_t> marked(z.size(), 0);
  std::vector<size_t> todo;
  std::vector<uint8_t> verdict;
  for (int pass = 1; pass < options.passes && !fresh.empty(); ++pass) {
    // The fresh rejections leave z; the pixels within 2 of one along its row or column, once
    // each, in increasing order.
    todo.clear();
    for (size_t i : fresh) z[i] = std::numeric_limits<float>::quiet_NaN();
    for (size_t i : fresh) {
      const int x = static_cast<int>(i % w), y = static_cast<int>(i / w);
      for (int d = -2; d <= 2; ++d) {
        if (x + d >= 0 && x + d < w && !marked[i + d]) marked[i + d] = 1, todo.push_back(i + d);
        const ptrdiff_t n = static_cast<ptrdiff_t>(i) + static_cast<ptrdiff_t>(d) * w;
        if (y + d >= 0 && y + d < h && !marked[n]) marked[n] = 1, todo.push_back(n);
      }
    }
    std::sort(todo.begin(), todo.end());
    for (size_t i : todo) marked[i] = 0;
    verdict.assign(todo.size(), 0);
    tbb::parallel_for(tbb::blocked_range<int>(0, static_cast<int>(todo.size()), 1024),
                      [&](const auto& range) {
                        const int q0 = range.begin(), q1 = range.end();
                        for (int q = q0; q < q1; ++q) verdict[q] = Judge(judge, todo[q], w, h);
                      });
    fresh.clear();
    for (size_t q = 0; q < todo.size(); ++q)
      if (verdict[q] && !reject[todo[q]]) {
        reject[todo[q]] = 1;
        fresh.push_back(todo[q]);
      }
  }
  return reject;
}

}  // namespace mesoscan
