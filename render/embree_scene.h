#pragma once
// Embree 3 behind one RAII wrapper (Mitsuba 3 scene_embree.inl): a shared device whose error
// callback is registered once, and a scene of height fields (RTC_GEOMETRY_TYPE_GRID) and
// horizontal planes with closest-hit and occlusion queries. Embree headers stay in the .cc.
//
// Precision: Embree traverses in float and sees each height-field cell as two triangles. The
// surface this class defines is the *bilinear* interpolant of the grid (HeightField::Sample):
// every Embree hit on a height field is refined in double by solving the ray/bilinear-patch
// quadratic exactly in the cells the ray crosses near the float hit, so a returned point lies
// on the bilinear surface to ~1e-12 m. Plane hits are recomputed analytically in double.
// Shadow rays (Occluded) still use Embree's triangulated surface; ShadowRayOrigin() moves the
// origin off the triangles of its cell, on the side the ray arrived from, so a surface does not
// shadow itself.

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "core/height_field.h"
#include "core/transform.h"

namespace mesoscan {

// Embree's version as the headers this module was compiled against say, e.g. "3.13.5" (for
// `mesoscan doctor`; Embree headers stay in render/).
std::string EmbreeVersion();

// One process-wide Embree device (created on first use, released with the last scene).
class EmbreeDevice;

struct RayHit {
  double t = 0.0;            // distance along the (unit) ray direction, metres
  Vec3d point;               // world point on the surface (bilinear patch or plane), metres
  Vec3d normal;              // unit geometric normal (+z side of the height field / plane)
  int geometry = -1;         // id returned by AddHeightField / AddPlane
  bool refined = true;       // false if the double refinement failed and the float hit was kept
  double shadow_lift = 0.0;  // metres: how far the triangulated surface may lie above `point`
};

class EmbreeScene {
 public:
  // Embree ray masks: a query sees the geometries whose mask shares a bit with the ray's.
  static constexpr unsigned kMaskHeightFields = 1u, kMaskPlanes = 2u, kMaskAll = 0xFFFFFFFFu;

  EmbreeScene();
  ~EmbreeScene();
  EmbreeScene(const EmbreeScene&) = delete;
  EmbreeScene& operator=(const EmbreeScene&) = delete;

  // Adds a height field as grid geometry (vertex buffer of world points in float). Cells with a
  // NaN corner are left out (split into runs of valid cells), so rays pass through holes.
  // The height field is copied. Returns the geometry id. Call before Commit().
  int AddHeightField(const HeightField& hf);

  // Adds the horizontal square |x|, |y| <= half_size_m at height z_m (e.g. the mount, z = 0),
  // facing +z. Returns the geometry id.
  int AddPlane(double z_m, double half_size_m = 1.0);

  // Builds the acceleration structure. Queries are thread-safe after this.
  void Commit();

  // Closest hit along origin + t * direction, t in [t_near, t_far]; `direction` must be unit.
  // `mask`: which kinds of geometry the ray sees (e.g. kMaskHeightFields: planes are skipped).
  std::optional<RayHit> Intersect(const Vec3d& origin, const Vec3d& direction, double t_near = 0.0,
                                  double t_far = 1e30, unsigned mask = kMaskAll) const;

  // True if anything blocks origin + t * direction for t in [t_near, t_far].
  bool Occluded(const Vec3d& origin, const Vec3d& direction, double t_near, double t_far) const;

  // A safe origin for a ray leaving `hit` on the side the incoming ray `incoming` (the
  // direction that reached the hit) came from: above the surface for a ray that arrived from
  // above (the usual case), below it for a ray that reached the underside of a height field
  // through a hole. The offset clears the triangulated surface of the cell (shadow_lift, either
  // way) plus 1e-7 m. Offsetting always towards +z restarted underside paths above
  // the sheet, where they picked up the sky (mount +1.9% under a slab with a hole).
  static Vec3d ShadowRayOrigin(const RayHit& hit, const Vec3d& incoming) {
    const double side = incoming.dot(hit.normal) > 0 ? -1.0 : 1.0;
    return hit.point + Vec3d(0, 0, side * (hit.shadow_lift + 1e-7));
  }
  // For a hit reached from above (camera / projector rays of the rig).
  static Vec3d ShadowRayOrigin(const RayHit& hit) { return ShadowRayOrigin(hit, Vec3d(0, 0, -1)); }

  // Number of Intersect calls whose double refinement failed (the float hit was returned).
  int64_t unrefined_hits() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace mesoscan
