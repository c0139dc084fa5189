#include "core/height_field.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "core/parallel.h"
#include "core/simd_clones.h"

namespace mesoscan {

double HeightField::Sample(double x, double y) const {
  const double fi = I(x), fj = J(y);
  const int i0 = static_cast<int>(std::floor(fi)), j0 = static_cast<int>(std::floor(fj));
  if (i0 < 0 || j0 < 0 || i0 + 1 >= width() || j0 + 1 >= height()) {
    // Exactly on the last row/column: allow degenerate interpolation.
    if (i0 >= 0 && j0 >= 0 && i0 < width() && j0 < height() && fi == i0 && fj == j0)
      return z(i0, j0);
    return std::numeric_limits<double>::quiet_NaN();
  }
  const double a = fi - i0, b = fj - j0;
  return (1 - a) * (1 - b) * z(i0, j0) + a * (1 - b) * z(i0 + 1, j0) + (1 - a) * b * z(i0, j0 + 1) +
         a * b * z(i0 + 1, j0 + 1);
}

namespace {

// One row of HeightField::Normals: z of the row, its left and right neighbours (the row
// shifted by one, NaN beyond the ends) and the rows above and below (NaN outside the field);
// the three normal planes' rows out. Branch-free, so the compiler makes vector lanes of the
// columns; per
// pixel the same operations in the same order as the former per-pixel code (central difference
// where both neighbours are finite, else one-sided, else 0; Eigen's normalized(): the squared
// norm (x^2 + y^2) + 1, one square root, three divisions).
// (This file is built with -fno-math-errno and -fno-trapping-math, see core/CMakeLists.txt:
// otherwise the square root's errno branch and the differences sunk into branches keep the
// loop scalar. Same values.)
MESOSCAN_SIMD_CLONES
void NormalsRow(const float* __restrict left, const float* __restrict row,
                const float* __restrict right, const float* __restrict up,
                const float* __restrict down, int n, double inv, float* __restrict nx,
                float* __restrict ny, float* __restrict nz) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int i = 0; i < n; ++i) {
    const float c = row[i];
    const float l = left[i], r = right[i], u = up[i], d = down[i];
    const bool lf = std::isfinite(l), rf = std::isfinite(r);
    const bool uf = std::isfinite(u), df = std::isfinite(d);
    // dz/dx: central where both neighbours exist, else one-sided, else 0.
    const double dx_c = static_cast<double>(r - l) * 0.5 * inv;
    const double dx_r = static_cast<double>(r - c) * inv;
    const double dx_l = static_cast<double>(c - l) * inv;
    const double dx_1 = lf ? dx_l : 0.0, dx_2 = rf ? dx_r : dx_1;
    const double dzdx = (lf & rf) ? dx_c : dx_2;
    // Rows go towards -y: dz/dy = (z(j-1) - z(j+1)) / (2 px).
    const double dy_c = static_cast<double>(u - d) * 0.5 * inv;
    const double dy_u = static_cast<double>(u - c) * inv;
    const double dy_d = static_cast<double>(c - d) * inv;
    const double dy_1 = df ? dy_d : 0.0, dy_2 = uf ? dy_u : dy_1;
    const double dzdy = (uf & df) ? dy_c : dy_2;
    const double vx = -dzdx, vy = -dzdy;
    const double s = std::sqrt(vx * vx + vy * vy + 1.0 * 1.0);
    const bool cf = std::isfinite(c);
    const float ox = static_cast<float>(vx / s), oy = static_cast<float>(vy / s);
    const float oz = static_cast<float>(1.0 / s);
    nx[i] = cf ? ox : nan;
    ny[i] = cf ? oy : nan;
    nz[i] = cf ? oz : nan;
  }
}

}  // namespace

ImageF HeightField::Normals() const {
  const int w = width(), h = height();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  ImageF n(w, h, 3, nan);
  if (w <= 0 || h <= 0) return n;
  const double inv = 1.0 / pixel_size;
  const std::vector<float> nan_row(static_cast<size_t>(w) + 2, nan);
  ParallelForRows(h, [&](int y0r, int y1r) {
    // The row padded by one NaN each side, so left / right are plain offsets.
    std::vector<float> padded(static_cast<size_t>(w) + 2, nan);
    for (int j = y0r; j < y1r; ++j) {
      const float* row = z.row(j);
      const float* up = j > 0 ? z.row(j - 1) : nan_row.data();
      const float* down = j + 1 < h ? z.row(j + 1) : nan_row.data();
      std::copy(row, row + w, padded.begin() + 1);
      NormalsRow(padded.data(), row, padded.data() + 2, up, down, w, inv, n.row(j, 0), n.row(j, 1),
                 n.row(j, 2));
    }
  });
  return n;
}

}  // namespace mesoscan
