// Writes the seed corpora of the fuzz targets into argv[1]/<target>/ (scripts/fuzz runs it):
// a small valid session.json and rig.json, MERL and RGL headers. Images come from oiiotool.
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>

#include "core/json.h"
#include "session/patterns.h"
#include "session/session.h"

namespace fs = std::filesystem;
using namespace mesoscan;

static void Put(const fs::path& path, const std::string& bytes) {
  fs::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary) << bytes;
}

template <typename T>
static std::string Bytes(const T& v) {
  return std::string(reinterpret_cast<const char*>(&v), sizeof(v));
}

int main(int argc, char** argv) {
  if (argc != 2) return 2;
  const fs::path out = argv[1];
  Session s;
  s.root = out;
  s.created = "2026-11-21T12:00:00Z";
  s.object = "seed";
  s.rig.camera.width = 8;
  s.rig.camera.height = 6;
  s.rig.camera.K << 100, 0, 3.5, 0, 100, 2.5, 0, 0, 1;
  s.rig.camera.world_from_device.rotation = Eigen::Vector3d(1, -1, -1).asDiagonal();
  s.rig.camera.world_from_device.translation = Vec3d(0, 0, 0.25);
  s.rig.projector.width = 60;
  s.rig.projector.height = 40;
  s.rig.projector.K << 200, 0, 29.5, 0, 200, 19.5, 0, 0, 1;
  s.rig.projector.world_from_device = s.rig.camera.world_from_device;
  s.rig.projector.world_from_device.translation = Vec3d(0.05, 0, 0.25);
  s.rig.lens_shifter = LensShifter{'x', 2048, {-2048, 2048}};
  FramePlanOptions plan;
  plan.periods_px = {7, 11};
  plan.lens_shift_frames = 4;
  s.frames = MakeStandardFrames(plan);
  const Json j = SessionToJson(s);
  Put(out / "fuzz_session" / "small.json", j.dump(1));
  Put(out / "fuzz_rig" / "rig.json", Json{{"rig", j.at("rig")}}.dump(1));

  std::string merl = Bytes(int32_t{90}) + Bytes(int32_t{90}) + Bytes(int32_t{180});
  for (int i = 0; i < 16; ++i) merl += Bytes(0.5);
  Put(out / "fuzz_merl" / "header.binary", merl);
  std::string tiny = Bytes(int32_t{1}) + Bytes(int32_t{1}) + Bytes(int32_t{2});
  for (int i = 0; i < 6; ++i) tiny += Bytes(0.25);
  Put(out / "fuzz_merl" / "tiny.binary", tiny);

  // RGL tensor file: magic, version 1.0, one field "theta_i" (float32, shape [2]).
  std::string rgl = std::string("tensor_file", 12) + '\x01' + '\x00' + Bytes(uint32_t{1});
  const std::string name = "theta_i";
  const uint64_t header = rgl.size() + 2 + name.size() + 2 + 1 + 8 + 8;
  rgl += Bytes(uint16_t(name.size())) + name + Bytes(uint16_t{1}) + '\x09' /* float32 */ +
         Bytes(uint64_t{header}) + Bytes(uint64_t{2});
  rgl += Bytes(0.0f) + Bytes(1.0f);
  Put(out / "fuzz_rgl" / "tiny.bsdf", rgl);
  return 0;
}
