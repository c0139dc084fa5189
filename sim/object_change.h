#pragma once
// The object's placement and a known change to its surface (sim/README.md "Pose and wear"): the
// ground truth of `mesoscan compare`. A change is defined in the object's own coordinates (it
// moves with the object); the pose then places the changed object on the mount.

#include <array>
#include <string>
#include <vector>

#include "assets/objects.h"
#include "core/json.h"
#include "core/transform.h"

namespace mesoscan {

// A straight groove from (x0, y0) to (x1, y1) (object metres) with a flat bottom `depth_m` deep
// and `width_m` wide, its walls falling over kWearWallM on each side (a smoothstep).
struct Scratch {
  double x0 = 0, y0 = 0, x1 = 0, y1 = 0;
  double width_m = 0.3e-3;
  double depth_m = 20e-6;
};
// A round patch of material removed: `depth_m` inside radius_m - kWearWallM, falling to 0 at
// radius_m (a smoothstep).
struct ErosionPatch {
  double cx = 0, cy = 0;
  double radius_m = 1.5e-3;
  double depth_m = 5e-6;
};
inline constexpr double kWearWallM = 60e-6;

struct ObjectChange {
  // Rotation vector in degrees (about the world origin), then translation in mm: the pose of
  // `simulate --object-pose` and of the boards' --pose. All zero: the object as generated.
  std::array<double, 6> pose{};
  // The camera field's offset over the object (metres, object x, y): the object is moved by
  // (-x, -y) before the pose, so the field's centre (the world origin) lies over object point
  // (x, y): the tiles of a mosaic of a large object (`simulate --field-offset`), each re-placed
  // by its pose about the field's centre.
  std::array<double, 2> field_offset{};
  std::vector<Scratch> scratches;
  std::vector<ErosionPatch> erosions;
  // A height-change EXR (channel Z, signed metres, the scan-outputs grid attributes) added to
  // the object's surface in object coordinates; NaN or outside its grid: no change. Empty: none.
  std::string wear_file;

  bool empty() const;
  Rigid3d Pose() const;  // world_from_object: the pose after the field offset
};

// "X0,Y0,X1,Y1,WIDTH_UM,DEPTH_UM" (mm, mm, mm, mm, um, um); throws Error(kUsage) at `option`.
Scratch ParseScratch(const std::string& text, const std::string& option);
// "X,Y" (mm) -> metres.
std::array<double, 2> ParseFieldOffset(const std::string& text, const std::string& option);
// "CX,CY,RADIUS,DEPTH_UM" (mm, mm, mm, um).
ErosionPatch ParseErosion(const std::string& text, const std::string& option);

// The procedural change at object coordinates (x, y), metres: minus the depth removed (the
// scratches' and erosions' depths add where they overlap). The wear file is not included.
double ProceduralWearAt(const ObjectChange& change, double x, double y);

// Applies the change to `object`: the wear (procedural and file) to every cell above the mount
// (z > 0; heights stay >= 0), then the pose (resampled on a grid of the same spacing covering the
// posed object; cells off the object are the mount, z = 0). Throws Error naming the wear file if
// it cannot be read.
void ApplyObjectChange(const ObjectChange& change, SceneObject* object);

// The change's record for session.json's "simulation" key: pose (the 4x4 world_from_object),
// scratches, erosions and the wear file.
Json ObjectChangeRecord(const ObjectChange& change);

}  // namespace mesoscan
