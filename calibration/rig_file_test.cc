#include "calibration/rig_file.h"

#include <gtest/gtest.h>

#include <cmath>

#include "core/error.h"
#include "core/test_temp_dir.h"

namespace mesoscan {
namespace {

// A 200x100 camera looking down from 0.25 m and a 100x80 projector beside it.
Rig SmallRig() {
  Rig r;
  r.camera.width = 200;
  r.camera.height = 100;
  r.camera.K << 1000, 0, 99.5, 0, 1000, 49.5, 0, 0, 1;
  r.camera.world_from_device.rotation = Vec3d(1, -1, -1).asDiagonal();
  r.camera.world_from_device.translation = Vec3d(0, 0, 0.25);
  r.projector = r.camera;
  r.projector.width = 100;
  r.projector.height = 80;
  r.projector.K << 500, 0, 49.5, 0, 500, 39.5, 0, 0, 1;
  r.projector.world_from_device.translation = Vec3d(0.001, 0, 0.25);
  return r;
}

std::filesystem::path WriteRig(const std::string& name, const Rig& rig, const Json& calibration) {
  Session s;
  s.rig = rig;
  Json j = {{"rig", SessionToJson(s)["rig"]}};
  if (!calibration.is_null()) j["calibration"] = calibration;
  const std::filesystem::path p = TestTempPath("rig_file", name);
  WriteJsonFile(p, j);
  return p;
}

TEST(RigFile, ReplacesTheSessionsDevicesAndKeepsItsResponse) {
  const Rig rig = SmallRig();
  const RigFile f = ReadRigFile(WriteRig("a.json", rig, Json()));
  EXPECT_EQ(f.sha256.size(), 64u);
  EXPECT_FALSE(f.camera_region.has_value());
  Session s;
  s.root = "/data/coin.session";
  s.rig = rig;
  s.rig.camera.K(0, 0) = 900;
  s.rig.camera_response.kind = Response::Kind::kSrgb;
  UseRigFile(f, &s);
  EXPECT_EQ(s.rig.camera.K(0, 0), 1000);
  EXPECT_EQ(s.rig.camera_response.kind, Response::Kind::kSrgb);
}

TEST(RigFile, AnotherCameraSizeIsBadInputNamingBothFiles) {
  const RigFile f = ReadRigFile(WriteRig("b.json", SmallRig(), Json()));
  Session s;
  s.root = "/data/coin.session";
  s.rig = SmallRig();
  s.rig.camera.width = 400;
  try {
    UseRigFile(f, &s);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
    EXPECT_NE(m.find("b.json: rig.camera: 200x100"), std::string::npos) << m;
    EXPECT_NE(m.find("/data/coin.session/session.json"), std::string::npos) << m;
  }
}

// Points whose pixels lie outside the corners' hulls are counted; a point inside both is not.
TEST(RigFile, CountsPointsOutsideTheCalibratedRegion) {
  const Rig rig = SmallRig();
  // Camera hull: the left half of the image; projector hull: all of it.
  const Json region = {
      {"camera",
       {{"width", 200}, {"height", 100}, {"hulls", {{{0, 0}, {99, 0}, {99, 99}, {0, 99}}}}}},
      {"projector",
       {{"width", 100}, {"height", 80}, {"hulls", {{{0, 0}, {99, 0}, {99, 79}, {0, 79}}}}}}};
  const RigFile f = ReadRigFile(WriteRig("c.json", rig, {{"calibrated_region", region}}));
  ASSERT_TRUE(f.camera_region && f.projector_region);
  ScanPoints pts;
  pts.xyz = ImageF(2, 1, 3);
  // On the mount (z = 0) under camera pixels x = 50 (inside) and x = 150 (outside).
  for (int i = 0; i < 2; ++i) {
    const Vec3d o = rig.camera.CentreInWorld();
    const Vec3d d = rig.camera.RayDirectionInWorld(Vec2d(i ? 150 : 50, 50));
    const Vec3d x = o + d * (-o.z() / d.z());
    for (int c = 0; c < 3; ++c) pts.xyz(i, 0, c) = static_cast<float>(x[c]);
  }
  const CalibratedRegionCheck c = CheckCalibratedRegion(f, pts);
  EXPECT_TRUE(c.known);
  EXPECT_EQ(c.points, 2);
  EXPECT_EQ(c.outside, 1);
}

TEST(RigFile, MalformedRegionIsBadInputNamingTheKey) {
  const std::filesystem::path p =
      WriteRig("d.json", SmallRig(), {{"calibrated_region", {{"camera", {{"width", 200}}}}}});
  try {
    ReadRigFile(p);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("calibration.calibrated_region.camera"), std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace mesoscan
