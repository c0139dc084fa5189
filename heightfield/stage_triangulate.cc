#include "heightfield/stage_triangulate.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <limits>

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
  // One array per task (~90 MB at 3 Mpx: their page faults and fills were serial).
  tbb::parallel_for<int64_t>(0, 6, [&](int64_t a) {
    switch (a) {
      case 0:
        points.xyz = ImageF(cam_w, cam_h, 3, kNaN);
        break;
      case 1:
        points.confidence = ImageF(cam_w, cam_h, 1, 0.0f);
        break;
      case 2:
        points.source = ImageF(cam_w, cam_h, 1, kNaN);
        break;
      case 3:
        points.projector_u = ImageF(cam_w, cam_h, 1, kNaN);
        break;
      case 4:
        if (options.keep_dz_du) out.dz_du = ImageF(cam_w, cam_h, 1, kNaN);
        break;
      default:
        out.sigma_z.assign(grid.pixels(), kNaN);
        break;
    }
  });
  // The camera's pinhole rays (no distortion): normalised x per column (no skew) and y per row,
  // the arithmetic of PinholeCamera::UndistortNormalized in its order; with the closed-form
  // column planes (Triangulator::PinholeT) the per-pixel work is two small matrix products, one
  // square root and a few divisions, inline. Other rigs take the general calls. Same bits.
  const PinholeCamera& cam = rig.camera;
  const bool camera_pinhole = !cam.HasDistortion();
  const bool closed_form = tri.closed_form();
  const Mat3d& K = cam.K;
  const Mat3d& rotation = cam.world_from_device.rotation;
  const Vec3d centre = cam.CentreInWorld();
  std::vector<double> xd_column;
  if (camera_pinhole && K(0, 1) == 0.0) {
    xd_column.resize(w);
    for (int x = 0; x < w; ++x)
      xd_column[x] = (static_cast<double>(x + roi.x) - K(0, 2) - K(0, 1) * 0.0) / K(0, 0);
  }
  // The point at u and the z of the point at u + du (forward difference); false: no point.
  const auto intersect = [&](const Vec3d& ray, const Vec3d& ray_device, double uu, Vec3d* p) {
    if (!closed_form) {
      const auto q = tri.IntersectDevice(ray, ray_device, uu);
      if (q) *p = *q;
      return q.has_value();
    }
    double t;
    if (!tri.PinholeT(ray_device, uu, &t)) return false;
    if (!(t > 0) || !std::isfinite(t) || !(tri.DeviceZ(ray_device, t) > 0)) return false;
    *p = centre + t * ray;
    return true;
  };
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const auto& range) {
    const int y0 = range.begin(), y1 = range.end();
    for (int y = y0; y < y1; ++y) {
      const int cy = y + roi.y;
      const double yd = (static_cast<double>(cy) - K(1, 2)) / K(1, 1);
      const size_t row = static_cast<size_t>(y) * w;
      const float* u_row = u.data() + row;
      PixelState* state_row = state.data() + row;
      float* pu = points.projector_u.row(cy) + roi.x;
      float* px = points.xyz.row(cy, 0) + roi.x;
      float* py = points.xyz.row(cy, 1) + roi.x;
      float* pz = points.xyz.row(cy, 2) + roi.x;
      float* conf = points.confidence.row(cy) + roi.x;
      float* src = points.source.row(cy) + roi.x;
      for (int x = 0; x < w; ++x) {
        if (std::isfinite(u_row[x])) pu[x] = u_row[x];
        if (state_row[x] != PixelState::kActive) continue;
        const size_t i = row + x;
        const int cx = x + roi.x;
        Vec3d ray;
        if (!camera_pinhole) {
          ray = tri.CameraRay(cx, cy);
        } else {
          const double xd = xd_column.empty()
                                ? (static_cast<double>(cx) - K(0, 2) - K(0, 1) * yd) / K(0, 0)
                                : xd_column[x];
          ray = (rotation * Vec3d(xd, yd, 1.0)).normalized();
        }
        const Vec3d ray_device = tri.DeviceDirection(ray);
        Vec3d p;
        if (!intersect(ray, ray_device, u_row[x], &p)) {
          state_row[x] = PixelState::kNoIntersection;
          continue;
        }
        px[x] = static_cast<float>(p.x());
        py[x] = static_cast<float>(p.y());
        pz[x] = static_cast<float>(p.z());
        conf[x] = combined.confidence[i];
        if (!combined.source.empty()) src[x] = combined.source[i];
        state_row[x] = PixelState::kOk;
        // dZ/du by a forward difference (the map is smooth on this scale).
        Vec3d b;
        if (intersect(ray, ray_device, u_row[x] + 0.5, &b)) {
          const float d = static_cast<float>(2.0 * (b.z() - p.z()));
          if (options.keep_dz_du) out.dz_du(cx, cy) = d;
          out.sigma_z[i] = combined.sigma_u[i] * std::abs(d);
        }
      }
    }
  });
  return out;
}

}  // namespace mesoscan
