#include "core/height_field.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <random>

namespace mesoscan {
namespace {

TEST(HeightField, NormalsOfTiltedPlane) {
  HeightField hf;
  hf.pixel_size = 1e-4;
  hf.x0 = 0;
  hf.y0 = 0;
  hf.z = ImageF(20, 10, 1);
  const double a = 0.1, b = -0.05;  // z = a x + b y
  for (int j = 0; j < 10; ++j)
    for (int i = 0; i < 20; ++i) hf.z(i, j) = static_cast<float>(a * hf.X(i) + b * hf.Y(j));
  const ImageF n = hf.Normals();
  const Vec3d expect = Vec3d(-a, -b, 1).normalized();
  for (int j = 0; j < 10; ++j)
    for (int i = 0; i < 20; ++i) {
      EXPECT_NEAR(n(i, j, 0), expect.x(), 1e-4);
      EXPECT_NEAR(n(i, j, 1), expect.y(), 1e-4);
    }
  EXPECT_NEAR(hf.Sample(hf.X(3.5), hf.Y(2.25)), a * hf.X(3.5) + b * hf.Y(2.25), 1e-7);
}

// The former per-pixel Normals (bounds-checked neighbours, Eigen's normalized()): the row
// kernel must give the same bits everywhere, NaN holes and edges included.
ImageF ReferenceNormals(const HeightField& hf) {
  const int w = hf.width(), h = hf.height();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  ImageF n(w, h, 3, nan);
  const double inv = 1.0 / hf.pixel_size;
  for (int j = 0; j < h; ++j)
    for (int i = 0; i < w; ++i) {
      const float c = hf.z(i, j);
      if (!std::isfinite(c)) continue;
      auto at = [&](int ii, int jj) -> float {
        return (ii >= 0 && jj >= 0 && ii < w && jj < h) ? hf.z(ii, jj) : nan;
      };
      const float l = at(i - 1, j), r = at(i + 1, j);
      double dzdx = 0;
      if (std::isfinite(l) && std::isfinite(r))
        dzdx = (r - l) * 0.5 * inv;
      else if (std::isfinite(r))
        dzdx = (r - c) * inv;
      else if (std::isfinite(l))
        dzdx = (c - l) * inv;
      const float u = at(i, j - 1), d = at(i, j + 1);
      double dzdy = 0;
      if (std::isfinite(u) && std::isfinite(d))
        dzdy = (u - d) * 0.5 * inv;
      else if (std::isfinite(u))
        dzdy = (u - c) * inv;
      else if (std::isfinite(d))
        dzdy = (c - d) * inv;
      const Vec3d v = Vec3d(-dzdx, -dzdy, 1.0).normalized();
      n(i, j, 0) = static_cast<float>(v.x());
      n(i, j, 1) = static_cast<float>(v.y());
      n(i, j, 2) = static_cast<float>(v.z());
    }
  return n;
}

TEST(HeightField, NormalsMatchPerPixelReferenceBitForBit) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> uz(-1e-3f, 1e-3f);
  std::uniform_real_distribution<float> u01(0.0f, 1.0f);
  const float inf = std::numeric_limits<float>::infinity();
  for (const auto& [w, h] : {std::pair{1, 1}, {1, 7}, {9, 1}, {2, 2}, {37, 23}, {130, 61}}) {
    HeightField hf;
    hf.pixel_size = 1.7e-5;
    hf.z = ImageF(w, h, 1);
    for (int j = 0; j < h; ++j)
      for (int i = 0; i < w; ++i) {
        const float p = u01(rng);
        hf.z(i, j) = p < 0.15f   ? std::numeric_limits<float>::quiet_NaN()
                     : p < 0.18f ? (p < 0.165f ? inf : -inf)
                                 : uz(rng) + (p > 0.99f ? 1e30f : 0.0f);
      }
    const ImageF got = hf.Normals(), want = ReferenceNormals(hf);
    ASSERT_EQ(got.data().size(), want.data().size());
    int nan_px = 0;
    for (size_t k = 0; k < got.data().size(); ++k) {
      uint32_t a, b;
      std::memcpy(&a, &got.data()[k], 4);
      std::memcpy(&b, &want.data()[k], 4);
      if (std::isnan(want.data()[k])) {
        ++nan_px;
        EXPECT_TRUE(std::isnan(got.data()[k])) << w << "x" << h << " entry " << k;
        continue;
      }
      EXPECT_EQ(a, b) << w << "x" << h << " entry " << k;
    }
    if (w * h > 100) {
      EXPECT_GT(nan_px, 0);  // the holes are exercised
    }
  }
}

}  // namespace
}  // namespace mesoscan
