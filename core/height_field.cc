#include "core/height_field.h"

#include "core/parallel.h"

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

ImageF HeightField::Normals() const {
  const int w = width(), h = height();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  ImageF n(w, h, 3, nan);
  const double inv = 1.0 / pixel_size;
  ParallelForRows(h, [&](int y0r, int y1r) {
    for (int j = y0r; j < y1r; ++j) {
      for (int i = 0; i < w; ++i) {
        const float c = z(i, j);
        if (!std::isfinite(c)) continue;
        auto at = [&](int ii, int jj) -> float {
          return (ii >= 0 && jj >= 0 && ii < w && jj < h) ? z(ii, jj) : nan;
        };
        // dz/dx: central where both neighbours exist, else one-sided, else 0.
        const float l = at(i - 1, j), r = at(i + 1, j);
        double dzdx = 0;
        if (std::isfinite(l) && std::isfinite(r)) dzdx = (r - l) * 0.5 * inv;
        else if (std::isfinite(r)) dzdx = (r - c) * inv;
        else if (std::isfinite(l)) dzdx = (c - l) * inv;
        // Rows go towards -y: dz/dy = (z(j-1) - z(j+1)) / (2 px).
        const float u = at(i, j - 1), d = at(i, j + 1);
        double dzdy = 0;
        if (std::isfinite(u) && std::isfinite(d)) dzdy = (u - d) * 0.5 * inv;
        else if (std::isfinite(u)) dzdy = (u - c) * inv;
        else if (std::isfinite(d)) dzdy = (c - d) * inv;
        const Vec3d v = Vec3d(-dzdx, -dzdy, 1.0).normalized();
        n(i, j, 0) = static_cast<float>(v.x());
        n(i, j, 1) = static_cast<float>(v.y());
        n(i, j, 2) = static_cast<float>(v.z());
      }
    }
  });
  return n;
}

}  // namespace mesoscan
