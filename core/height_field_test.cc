#include "core/height_field.h"

#include <gtest/gtest.h>

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

}  // namespace
}  // namespace mesoscan
