#include "calibration/rig_file.h"

#include <cmath>

#include "core/error.h"
#include "core/sha256.h"

namespace mesoscan {
namespace fs = std::filesystem;

Json RigFile::ToJson() const { return {{"file", path.string()}, {"sha256", sha256}}; }

RigFile ReadRigFile(const fs::path& path) {
  RigFile f;
  std::error_code ec;
  f.path = fs::absolute(path, ec).lexically_normal();
  if (ec) f.path = path;
  f.rig = LoadRigFile(path);  // validates "rig" as the session parser does, naming the file
  if (f.rig.uncalibrated)
    MESOSCAN_BAD_INPUT(path.string() << ": rig: holds device sizes only (a calibration session's "
                                        "rig); `mesoscan calibrate --out` writes a calibrated one");
  f.sha256 = Sha256OfFile(path);
  const Json j = ReadJsonFile(path);
  if (j.contains("calibration")) {
    f.calibration = j["calibration"];
    if (!f.calibration.is_object())
      MESOSCAN_BAD_INPUT(path.string() << ": calibration: expected an object");
    if (f.calibration.contains("calibrated_region")) {
      const Json& r = f.calibration["calibrated_region"];
      if (r.contains("camera"))
        f.camera_region = CalibratedRegion::FromJson(
            r["camera"], path.string() + ": calibration.calibrated_region.camera");
      if (r.contains("projector"))
        f.projector_region = CalibratedRegion::FromJson(
            r["projector"], path.string() + ": calibration.calibrated_region.projector");
    }
  }
  auto distorted = [](const PinholeCamera& c) {
    for (double d : c.distortion)
      if (d != 0) return true;
    return false;
  };
  f.camera_distorted = distorted(f.rig.camera);
  f.projector_distorted = distorted(f.rig.projector);
  return f;
}

void UseRigFile(const RigFile& rig_file, Session* session) {
  const Rig& r = rig_file.rig;
  Rig& s = session->rig;
  auto same_size = [&](const PinholeCamera& a, const PinholeCamera& b, const char* device) {
    if (a.width != b.width || a.height != b.height)
      MESOSCAN_BAD_INPUT(rig_file.path.string()
                         << ": rig." << device << ": " << a.width << "x" << a.height
                         << " does not match the session's " << b.width << "x" << b.height << " ("
                         << (session->root / "session.json").string() << ")");
  };
  same_size(r.camera, s.camera, "camera");
  same_size(r.projector, s.projector, "projector");
  s.camera = r.camera;
  s.projector = r.projector;
  if (r.lens_shifter) s.lens_shifter = r.lens_shifter;
  s.uncalibrated = false;
}

Json CalibratedRegionCheck::ToJson() const {
  if (!known) return {{"known", false}};
  return {{"known", true},
          {"points", points},
          {"outside", outside},
          {"outside_fraction", OutsideFraction()}};
}

CalibratedRegionCheck CheckCalibratedRegion(const RigFile& rig_file, const ScanPoints& points) {
  CalibratedRegionCheck c;
  if (!rig_file.camera_region || !rig_file.projector_region) return c;
  c.known = true;
  const ImageF& xyz = points.xyz;
  for (int y = 0; y < xyz.height(); ++y)
    for (int x = 0; x < xyz.width(); ++x) {
      const Vec3d p(xyz(x, y, 0), xyz(x, y, 1), xyz(x, y, 2));
      if (!p.allFinite()) continue;
      ++c.points;
      Vec2d uc, up;
      const bool in = rig_file.rig.camera.Project(p, &uc) && rig_file.camera_region->Contains(uc) &&
                      rig_file.rig.projector.Project(p, &up) &&
                      rig_file.projector_region->Contains(up);
      if (!in) ++c.outside;
    }
  return c;
}

}  // namespace mesoscan
