#include "maps/maps_derived.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"
#include "maps/maps_flatten.h"

namespace mesoscan {
namespace {

constexpr float kNan = std::numeric_limits<float>::quiet_NaN();

int Wrap(int i, int n) { return ((i % n) + n) % n; }

// Central difference of z along x (dir 0) or y (dir 1, image rows), metres per pixel.
double Diff(const ImageF& z, int x, int y, int dir, bool periodic) {
  const int w = z.width(), h = z.height();
  const int n = dir == 0 ? w : h;
  const int c = dir == 0 ? x : y;
  auto at = [&](int k) -> double {
    if (periodic)
      k = Wrap(k, n);
    else if (k < 0 || k >= n)
      return std::nan("");
    return dir == 0 ? z(k, y) : z(x, k);
  };
  const double zc = at(c), zp = at(c + 1), zm = at(c - 1);
  if (std::isfinite(zp) && std::isfinite(zm)) return 0.5 * (zp - zm);
  if (std::isfinite(zp)) return zp - zc;
  if (std::isfinite(zm)) return zc - zm;
  return 0.0;
}

}  // namespace

void AoOptions::Check() const {
  if (directions < 4 || steps < 2 || !(radius_m > 0))
    MESOSCAN_THROW(ErrorKind::kUsage, "ao: directions >= 4, steps >= 2 and radius > 0 expected");
}

ImageF NormalsOf(const HeightField& hf, bool periodic) {
  const int w = hf.width(), h = hf.height();
  ImageF n(w, h, 3, kNan);
  ParallelForRows(h, [&](int r0, int r1) {
    for (int y = r0; y < r1; ++y)
      for (int x = 0; x < w; ++x) {
        if (!std::isfinite(hf.z(x, y))) continue;
        // World x = column, world y = -row.
        const double gx = Diff(hf.z, x, y, 0, periodic) / hf.pixel_size;
        const double gy = -Diff(hf.z, x, y, 1, periodic) / hf.pixel_size;
        const double s = 1.0 / std::sqrt(1 + gx * gx + gy * gy);
        n(x, y, 0) = static_cast<float>(-gx * s);
        n(x, y, 1) = static_cast<float>(-gy * s);
        n(x, y, 2) = static_cast<float>(s);
      }
  });
  return n;
}

ImageF AmbientOcclusion(const HeightField& hf, const AoOptions& o, bool periodic) {
  o.Check();
  const int w = hf.width(), h = hf.height();
  const double radius_px = std::max(1.0, o.radius_m / hf.pixel_size);
  // Sample offsets per azimuth (pixels, quadratic spacing from 1 px), and their distances.
  struct Tap {
    float dx, dy, dist_m;
  };
  std::vector<Tap> taps;
  for (int d = 0; d < o.directions; ++d) {
    const double a = 2 * kPi * (d + 0.5) / o.directions;
    for (int s = 1; s <= o.steps; ++s) {
      const double t = static_cast<double>(s) / o.steps;
      const double r =
          std::max(static_cast<double>(s) / o.steps * 1.0, 1.0 + (radius_px - 1.0) * t * t);
      taps.push_back({static_cast<float>(r * std::cos(a)), static_cast<float>(r * std::sin(a)),
                      static_cast<float>(r * hf.pixel_size)});
    }
  }
  ImageF ao(w, h, 1, kNan);
  ParallelForRows(h, [&](int r0, int r1) {
    for (int y = r0; y < r1; ++y)
      for (int x = 0; x < w; ++x) {
        const float z0 = hf.z(x, y);
        if (!std::isfinite(z0)) continue;
        double sum = 0;
        for (int d = 0; d < o.directions; ++d) {
          double max_tan = 0;
          for (int s = 0; s < o.steps; ++s) {
            const Tap& t = taps[d * o.steps + s];
            // Bilinear sample.
            const double fx = x + t.dx, fy = y + t.dy;
            int ix = static_cast<int>(std::floor(fx)), iy = static_cast<int>(std::floor(fy));
            const double a = fx - ix, b = fy - iy;
            int ix1 = ix + 1, iy1 = iy + 1;
            if (periodic) {
              ix = Wrap(ix, w), ix1 = Wrap(ix1, w), iy = Wrap(iy, h), iy1 = Wrap(iy1, h);
            } else if (ix < 0 || iy < 0 || ix1 >= w || iy1 >= h) {
              break;
            }
            const double zq = (1 - a) * (1 - b) * hf.z(ix, iy) + a * (1 - b) * hf.z(ix1, iy) +
                              (1 - a) * b * hf.z(ix, iy1) + a * b * hf.z(ix1, iy1);
            if (!std::isfinite(zq)) continue;
            max_tan = std::max(max_tan, (zq - z0) / t.dist_m);
          }
          sum += 1.0 / (1.0 + max_tan * max_tan);  // cos^2(atan(t))
        }
        ao(x, y) = static_cast<float>(sum / o.directions);
      }
  });
  return ao;
}

ImageF MeanCurvature(const HeightField& hf, double sigma_px, bool periodic) {
  const int w = hf.width(), h = hf.height();
  const ImageF zs = sigma_px > 0 ? NormalisedGaussianBlur(hf.z, sigma_px, periodic) : hf.z;
  ImageF k(w, h, 1, kNan);
  const double p = hf.pixel_size;
  auto at = [&](int x, int y) -> double {
    if (periodic) return zs(Wrap(x, w), Wrap(y, h));
    return zs(std::clamp(x, 0, w - 1), std::clamp(y, 0, h - 1));
  };
  ParallelForRows(h, [&](int r0, int r1) {
    for (int y = r0; y < r1; ++y)
      for (int x = 0; x < w; ++x) {
        if (!std::isfinite(hf.z(x, y))) continue;
        const double c = at(x, y);
        // Rows go towards -y: d/dy = -d/drow; the second derivatives keep their sign, the
        // mixed one flips.
        const double zx = (at(x + 1, y) - at(x - 1, y)) / (2 * p);
        const double zy = -(at(x, y + 1) - at(x, y - 1)) / (2 * p);
        const double zxx = (at(x + 1, y) - 2 * c + at(x - 1, y)) / (p * p);
        const double zyy = (at(x, y + 1) - 2 * c + at(x, y - 1)) / (p * p);
        const double zxy =
            -(at(x + 1, y + 1) - at(x + 1, y - 1) - at(x - 1, y + 1) + at(x - 1, y - 1)) /
            (4 * p * p);
        const double g = 1 + zx * zx + zy * zy;
        const double hm = -((1 + zy * zy) * zxx - 2 * zx * zy * zxy + (1 + zx * zx) * zyy) /
                          (2 * std::pow(g, 1.5));
        if (std::isfinite(hm)) k(x, y) = static_cast<float>(hm);
      }
  });
  return k;
}

ImageF ProjectorIrradiance(const HeightField& hf, const ImageF& n, const Vec3d& c) {
  const int w = hf.width(), h = hf.height();
  MESOSCAN_CHECK(n.width() == w && n.height() == h && n.channels() == 3);
  ImageF e(w, h, 1, kNan);
  ParallelForRows(h, [&](int r0, int r1) {
    for (int y = r0; y < r1; ++y)
      for (int x = 0; x < w; ++x) {
        const double z = hf.z(x, y);
        if (!std::isfinite(z) || !std::isfinite(n(x, y, 0))) continue;
        const Vec3d d = c - Vec3d(hf.X(x), hf.Y(y), z);
        const double r2 = d.squaredNorm();
        const double cosi =
            (n(x, y, 0) * d.x() + n(x, y, 1) * d.y() + n(x, y, 2) * d.z()) / std::sqrt(r2);
        if (cosi > 1e-3) e(x, y) = static_cast<float>(cosi / r2);
      }
  });
  std::vector<float> v;
  for (float f : e.data())
    if (std::isfinite(f)) v.push_back(f);
  if (!v.empty()) {
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    const float med = v[v.size() / 2];
    for (float& f : e.data()) f /= med;
  }
  return e;
}

}  // namespace mesoscan
