#include "sim/object_change.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"
#include "core/scan_folder.h"

namespace mesoscan {
namespace {

double SmoothStep(double e0, double e1, double x) {
  const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3 - 2 * t);
}

std::vector<double> ParseNumbers(const std::string& text, size_t count, const std::string& option,
                                 const char* expected) {
  std::vector<double> v;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    try {
      size_t used = 0;
      const double d = std::stod(item, &used);
      if (used != item.size() || !std::isfinite(d)) throw std::invalid_argument(item);
      v.push_back(d);
    } catch (const std::exception&) {
      MESOSCAN_BAD_OPTION(option, "'" << text << "': expected " << expected);
    }
  }
  if (v.size() != count) MESOSCAN_BAD_OPTION(option, "'" << text << "': expected " << expected);
  return v;
}

// Distance from (x, y) to the segment s.
double SegmentDistance(const Scratch& s, double x, double y) {
  const double dx = s.x1 - s.x0, dy = s.y1 - s.y0, len2 = dx * dx + dy * dy;
  double t = len2 > 0 ? ((x - s.x0) * dx + (y - s.y0) * dy) / len2 : 0.0;
  t = std::clamp(t, 0.0, 1.0);
  return std::hypot(x - (s.x0 + t * dx), y - (s.y0 + t * dy));
}

}  // namespace

bool ObjectChange::empty() const {
  return scratches.empty() && erosions.empty() && wear_file.empty() &&
         std::all_of(pose.begin(), pose.end(), [](double v) { return v == 0.0; }) &&
         field_offset[0] == 0.0 && field_offset[1] == 0.0;
}

Rigid3d ObjectChange::Pose() const {
  const Vec3d r(pose[0], pose[1], pose[2]);
  const double angle = r.norm() * kPi / 180.0;
  Rigid3d t;
  if (angle > 0) t.rotation = Eigen::AngleAxisd(angle, r.normalized()).toRotationMatrix();
  t.translation = Vec3d(pose[3], pose[4], pose[5]) * 1e-3 -
                  t.rotation * Vec3d(field_offset[0], field_offset[1], 0.0);
  return t;
}

Scratch ParseScratch(const std::string& text, const std::string& option) {
  const auto v = ParseNumbers(text, 6, option, "X0,Y0,X1,Y1,WIDTH,DEPTH (mm, mm, mm, mm, um, um)");
  if (!(v[4] > 0) || !(v[5] >= 0))
    MESOSCAN_BAD_OPTION(option, "'" << text << "': expected WIDTH > 0 and DEPTH >= 0 (um)");
  return {v[0] * 1e-3, v[1] * 1e-3, v[2] * 1e-3, v[3] * 1e-3, v[4] * 1e-6, v[5] * 1e-6};
}

std::array<double, 2> ParseFieldOffset(const std::string& text, const std::string& option) {
  const auto v = ParseNumbers(text, 2, option, "X,Y (mm)");
  return {v[0] * 1e-3, v[1] * 1e-3};
}

ErosionPatch ParseErosion(const std::string& text, const std::string& option) {
  const auto v = ParseNumbers(text, 4, option, "CX,CY,RADIUS,DEPTH (mm, mm, mm, um)");
  if (!(v[2] * 1e-3 > kWearWallM) || !(v[3] >= 0))
    MESOSCAN_BAD_OPTION(option, "'" << text << "': expected RADIUS > " << kWearWallM * 1e3
                                    << " mm and DEPTH >= 0 (um)");
  return {v[0] * 1e-3, v[1] * 1e-3, v[2] * 1e-3, v[3] * 1e-6};
}

double ProceduralWearAt(const ObjectChange& change, double x, double y) {
  double dz = 0;
  for (const Scratch& s : change.scratches) {
    const double d = SegmentDistance(s, x, y);
    dz -= s.depth_m * (1.0 - SmoothStep(0.5 * s.width_m, 0.5 * s.width_m + kWearWallM, d));
  }
  for (const ErosionPatch& e : change.erosions) {
    const double r = std::hypot(x - e.cx, y - e.cy);
    dz -= e.depth_m * (1.0 - SmoothStep(e.radius_m - kWearWallM, e.radius_m, r));
  }
  return dz;
}

void ApplyObjectChange(const ObjectChange& change, SceneObject* object) {
  if (change.empty()) return;
  HeightField& hf = object->height;
  // The wear, in object coordinates, on the object's cells (the mount margin stays at 0).
  HeightField wear;
  if (!change.wear_file.empty()) wear = ReadHeightExr(change.wear_file);
  if (!change.scratches.empty() || !change.erosions.empty() || !change.wear_file.empty()) {
    ParallelForRows(hf.height(), [&](int j0, int j1) {
      for (int j = j0; j < j1; ++j)
        for (int i = 0; i < hf.width(); ++i) {
          float& z = hf.z(i, j);
          if (!(z > 0)) continue;
          double dz = ProceduralWearAt(change, hf.X(i), hf.Y(j));
          if (wear.width() > 0) {
            const double w = wear.Sample(hf.X(i), hf.Y(j));
            if (std::isfinite(w)) dz += w;
          }
          z = static_cast<float>(std::max(0.0, z + dz));
        }
    });
  }
  const Rigid3d pose = change.Pose();
  if (pose.rotation.isIdentity(0) && pose.translation.isZero(0)) return;

  // The posed object on a grid of the same spacing covering its footprint.
  const Rigid3d inv = pose.Inverse();
  float zmax = 0;
  for (float z : hf.z.data())
    if (std::isfinite(z)) zmax = std::max(zmax, z);
  double xmin = std::numeric_limits<double>::infinity(), xmax = -xmin, ymin = xmin, ymax = -xmin;
  for (int c = 0; c < 8; ++c) {
    const Vec3d p = pose * Vec3d(hf.X((c & 1) ? hf.width() - 1 : 0),
                                 hf.Y((c & 2) ? hf.height() - 1 : 0), (c & 4) ? zmax : 0.0);
    xmin = std::min(xmin, p.x());
    xmax = std::max(xmax, p.x());
    ymin = std::min(ymin, p.y());
    ymax = std::max(ymax, p.y());
  }
  const double ps = hf.pixel_size;
  HeightField out;
  out.pixel_size = ps;
  out.x0 = std::floor(xmin / ps) * ps;
  out.y0 = std::ceil(ymax / ps) * ps;
  const int w = static_cast<int>(std::ceil((xmax - out.x0) / ps)) + 1;
  const int h = static_cast<int>(std::ceil((out.y0 - ymin) / ps)) + 1;
  out.z = ImageF(w, h, 1, 0.0f);
  ImageF albedo(w, h, 1, 0.0f);
  ParallelForRows(h, [&](int j0, int j1) {
    for (int j = j0; j < j1; ++j)
      for (int i = 0; i < w; ++i) {
        const double x = out.X(i), y = out.Y(j);
        // The object point whose posed image lies above (x, y): a fixed point on the posed
        // height (converges for the small tilts of an object lying on the mount).
        Vec3d p = inv * Vec3d(x, y, pose.translation.z());
        double zs = hf.Sample(p.x(), p.y()), zw = 0;
        for (int it = 0; it < 6 && std::isfinite(zs); ++it) {
          zw = (pose * Vec3d(p.x(), p.y(), zs)).z();
          p = inv * Vec3d(x, y, zw);
          zs = hf.Sample(p.x(), p.y());
        }
        const bool on_object = std::isfinite(zs) && zs > 0;
        if (std::isnan(zs) && p.x() >= hf.X(0) && p.x() <= hf.X(hf.width() - 1) &&
            p.y() <= hf.Y(0) && p.y() >= hf.Y(hf.height() - 1))
          out.z(i, j) = std::numeric_limits<float>::quiet_NaN();  // a hole of the object
        else
          out.z(i, j) = on_object ? static_cast<float>(std::max(0.0, zw)) : 0.0f;
        albedo(i, j) =
            static_cast<float>(on_object ? object->Albedo(p.x(), p.y()) : MountAlbedo(x, y));
      }
  });
  object->height = std::move(out);
  object->albedo = std::move(albedo);
}

Json ObjectChangeRecord(const ObjectChange& change) {
  Json j;
  j["pose"] = change.pose;
  j["world_from_object"] = MatrixToJson(change.Pose().Matrix());
  j["pose_units"] = "rotation vector in degrees, translation in mm";
  if (change.field_offset[0] != 0.0 || change.field_offset[1] != 0.0)
    j["field_offset_m"] = change.field_offset;
  Json s = Json::array(), e = Json::array();
  for (const Scratch& c : change.scratches)
    s.push_back({{"from_m", {c.x0, c.y0}},
                 {"to_m", {c.x1, c.y1}},
                 {"width_m", c.width_m},
                 {"depth_m", c.depth_m},
                 {"wall_m", kWearWallM}});
  for (const ErosionPatch& c : change.erosions)
    e.push_back({{"centre_m", {c.cx, c.cy}},
                 {"radius_m", c.radius_m},
                 {"depth_m", c.depth_m},
                 {"wall_m", kWearWallM}});
  j["scratches"] = s;
  j["erosions"] = e;
  if (!change.wear_file.empty()) j["wear_file"] = change.wear_file;
  return j;
}

}  // namespace mesoscan
