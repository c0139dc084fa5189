#pragma once
// HeightField: a regular grid over the world x-y plane (scan-outputs.md "height.exr").
// Pixel (i, j) (column i, row j) is at world (x0 + i*pixel_size, y0 - j*pixel_size); rows go
// towards -y like an image. z is metres above the mount plane z = 0; NaN where unknown.

#include <cmath>
#include <limits>

#include "core/image.h"
#include "core/transform.h"

namespace mesoscan {

struct HeightField {
  ImageF z;                  // metres, NaN = unknown
  ImageF confidence;         // [0, 1], 0 where z is NaN; same size as z (may be empty)
  double x0 = 0.0;           // world x of pixel (0,0) centre, metres
  double y0 = 0.0;           // world y of pixel (0,0) centre, metres
  double pixel_size = 1e-4;  // metres between neighbouring pixel centres, > 0

  int width() const { return z.width(); }
  int height() const { return z.height(); }
  double X(double i) const { return x0 + i * pixel_size; }
  double Y(double j) const { return y0 - j * pixel_size; }
  // World (x, y) -> fractional grid coordinates (i, j).
  double I(double x) const { return (x - x0) / pixel_size; }
  double J(double y) const { return (y0 - y) / pixel_size; }

  // Bilinear height at world (x, y); NaN outside the grid or if any of the 4 corners is NaN.
  double Sample(double x, double y) const;

  // Unit normals in world coordinates from central differences of the grid (one-sided at
  // borders and next to holes); NaN where z is NaN. Channels X, Y, Z.
  ImageF Normals() const;
};

}  // namespace mesoscan
