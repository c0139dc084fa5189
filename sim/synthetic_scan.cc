#include "sim/synthetic_scan.h"

#include <cmath>
#include <random>

#include "core/error.h"
#include "core/parallel.h"

namespace mesoscan {

Scan SyntheticScan(const std::function<double(double x, double y)>& surface,
                   const SyntheticScanOptions& o) {
  MESOSCAN_CHECK(o.width >= 1 && o.height >= 1 && o.pixel_size_m > 0 && o.noise_m >= 0 &&
                 o.supersample >= 1);
  Scan scan;
  HeightField& hf = scan.height;
  hf.pixel_size = o.pixel_size_m;
  hf.x0 = -(o.width - 1) / 2.0 * hf.pixel_size;
  hf.y0 = (o.height - 1) / 2.0 * hf.pixel_size;
  hf.z = ImageF(o.width, o.height, 1);
  hf.confidence = ImageF(o.width, o.height, 1, o.confidence);
  const int ss = o.supersample;
  ParallelForRows(o.height, [&](int j0, int j1) {
    for (int j = j0; j < j1; ++j)
      for (int i = 0; i < o.width; ++i) {
        double sum = 0;
        for (int v = 0; v < ss; ++v)
          for (int u = 0; u < ss; ++u)
            sum += surface(hf.X(i + (u + 0.5) / ss - 0.5), hf.Y(j + (v + 0.5) / ss - 0.5));
        hf.z(i, j) = static_cast<float>(sum / (ss * ss));
      }
  });
  std::mt19937 rng(o.seed);  // the noise in row order, whatever the threads
  std::normal_distribution<double> noise(0.0, 1.0);
  for (int j = 0; j < o.height; ++j)
    for (int i = 0; i < o.width; ++i) {
      const double z = hf.z(i, j) + o.noise_m * noise(rng);
      hf.z(i, j) = static_cast<float>(z);
      if (!std::isfinite(z)) hf.confidence(i, j) = 0.0f;
    }
  scan.normals = hf.Normals();
  scan.points.xyz = ImageF(2, 2, 3, std::nanf(""));
  scan.points.confidence = ImageF(2, 2, 1, 0.0f);
  scan.points.projector_u = ImageF(2, 2, 1, std::nanf(""));
  if (o.predicted_depth_rms_m > 0)
    scan.report["summary"]["predicted_depth_rms_m"] = o.predicted_depth_rms_m;
  return scan;
}

}  // namespace mesoscan
