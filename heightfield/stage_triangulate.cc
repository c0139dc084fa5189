#include "heightfield/stage_triangulate.h"

#include <cmath>
#include <limits>

#include "core/parallel.h"
#include "heightfield/triangulate.h"

namespace mesoscan {

TriangulatedPoints TriangulatePoints(const Rig& rig, const RoiGrid& grid,
                                     const CombinedPixels& combined,
                                     const TriangulateOptions& options, PixelStates* state_out) {
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  PixelStates& state = *state_out;
  const int cam_w = rig.camera.width, cam_h = rig.camera.height;
  const int w = grid.width, h = grid.height;
  const PixelRect& roi = grid.roi;
  const std::vector<float>& u = combined.u;
  const Triangulator tri(rig.camera, rig.projector, options.axis);
  TriangulatedPoints out;
  ScanPoints& points = out.points;
  points.xyz = ImageF(cam_w, cam_h, 3, kNaN);
  points.confidence = ImageF(cam_w, cam_h, 1, 0.0f);
  points.source = ImageF(cam_w, cam_h, 1, std::numeric_limits<float>::quiet_NaN());
  points.projector_u = ImageF(cam_w, cam_h, 1, kNaN);
  if (options.keep_dz_du) out.dz_du = ImageF(cam_w, cam_h, 1, kNaN);
  out.sigma_z.assign(grid.pixels(), kNaN);
  ParallelForRows(h, [&](int y0, int y1) {
    for (int y = y0; y < y1; ++y)
      for (int x = 0; x < w; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        const int cx = x + roi.x, cy = y + roi.y;
        if (std::isfinite(u[i])) points.projector_u(cx, cy) = u[i];
        if (state[i] != PixelState::kActive) continue;
        const Vec3d ray = tri.CameraRay(cx, cy);
        const Vec3d ray_device = tri.DeviceDirection(ray);
        const auto p = tri.IntersectDevice(ray, ray_device, u[i]);
        if (!p) {
          state[i] = PixelState::kNoIntersection;
          continue;
        }
        for (int c = 0; c < 3; ++c) points.xyz(cx, cy, c) = static_cast<float>((*p)[c]);
        points.confidence(cx, cy) = combined.confidence[i];
        if (!combined.source.empty()) points.source(cx, cy) = combined.source[i];
        state[i] = PixelState::kOk;
        // dZ/du by a forward difference (the map is smooth on this scale).
        const auto b = tri.IntersectDevice(ray, ray_device, u[i] + 0.5);
        if (b) {
          const float d = static_cast<float>(2.0 * (b->z() - p->z()));
          if (options.keep_dz_du) out.dz_du(cx, cy) = d;
          out.sigma_z[i] = combined.sigma_u[i] * std::abs(d);
        }
      }
  });
  return out;
}

}  // namespace mesoscan
