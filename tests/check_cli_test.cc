// `mesoscan check` through the real executable: a small session written here (tiny frames), mutated
// copies of it, a scan folder, and the independent coin-edge example.

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <sstream>

#include "core/fs.h"
#include "core/image_io.h"
#include "core/scan_folder.h"
#include "session/patterns.h"
#include "session/session.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

struct CliResult {
  int exit_code = -1;
  std::string out, err;
};

// Runs `mesoscan <args>` with stdout and stderr captured to files.
CliResult Mesoscan(const std::string& args, const fs::path& work) {
  const fs::path out = work / "stdout.txt", err = work / "stderr.txt";
  const std::string cmd =
      std::string(MESOSCAN_EXE) + " " + args + " >" + out.string() + " 2>" + err.string();
  const int status = std::system(cmd.c_str());
  CliResult r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = ReadTextFile(out);
  r.err = ReadTextFile(err);
  return r;
}

class CheckCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    work_ = fs::temp_directory_path() / ("mesoscan_check_cli_" + std::to_string(getpid()));
    fs::remove_all(work_);
    fs::create_directories(work_);
  }
  void TearDown() override { fs::remove_all(work_); }

  // A 16x12 session of the flat mount (z = 0): periods 7, 11 x 3 phases, 8 lens-shift frames,
  // white, black. The projector, 80 mm beside the camera, is aimed at the camera's view; each
  // pixel sees the ideal profiles of its projector column u (as heightfield/reconstruct_test.cc
  // writes them): sines 0.5 + 0.5 cos(2 pi u / p + phase), stripes 0.5 + 0.4 cos(pi (s - u)) at
  // shift s px, scaled by albedo 0.8 over ambient 0.05, so that the session reconstructs.
  fs::path WriteSession(const std::string& name) {
    const fs::path dir = work_ / name;
    fs::create_directories(dir / "frames");
    Session s;
    s.root = dir;
    s.object = "cli test";
    s.rig.camera.width = 16;
    s.rig.camera.height = 12;
    s.rig.camera.K << 500, 0, 7.5, 0, 500, 5.5, 0, 0, 1;
    s.rig.camera.world_from_device.rotation = Eigen::Vector3d(1, -1, -1).asDiagonal();
    s.rig.camera.world_from_device.translation = Vec3d(0, 0, 0.25);
    s.rig.projector.width = 64;
    s.rig.projector.height = 48;
    s.rig.projector.K << 300, 0, 31.5, 0, 300, 23.5, 0, 0, 1;
    const double a = std::atan2(0.08, 0.25);
    s.rig.projector.world_from_device.rotation << std::cos(a), 0, -std::sin(a), 0, -1, 0,
        -std::sin(a), 0, -std::cos(a);
    s.rig.projector.world_from_device.translation = Vec3d(0.08, 0, 0.25);
    s.rig.lens_shifter = LensShifter{'x', 2048, {-2048, 2048}};
    FramePlanOptions plan;
    plan.periods_px = {7, 11};
    plan.lens_shift_frames = 8;
    s.frames = MakeStandardFrames(plan);
    ImageF u(16, 12, 1);
    for (int y = 0; y < 12; ++y)
      for (int x = 0; x < 16; ++x) {
        const Vec3d o = s.rig.camera.CentreInWorld();
        const Vec3d d = s.rig.camera.RayDirectionInWorld({double(x), double(y)});
        Vec2d uv = Vec2d::Zero();
        EXPECT_TRUE(s.rig.projector.Project(o - o.z() / d.z() * d, &uv));
        u(x, y) = static_cast<float>(uv.x());
      }
    for (const Frame& f : s.frames) {
      ImageF im(16, 12, 1);
      for (size_t i = 0; i < im.pixels(); ++i) {
        const double c = u.data()[i];
        double v = 0;
        switch (f.pattern.type) {
          case PatternType::kSine:
            v = 0.5 +
                0.5 * std::cos(2 * std::numbers::pi * c / f.pattern.period_px + f.pattern.phase);
            break;
          case PatternType::kStripes:
            v = 0.5 + 0.4 * std::cos(std::numbers::pi * (f.shift_steps / 2048.0 - c));
            break;
          case PatternType::kWhite:
            v = 1;
            break;
          default:
            v = 0;
        }
        im.data()[i] = static_cast<float>(0.05 + 0.8 * v);
      }
      WritePng16(dir / f.file, QuantizeU16(im));
    }
    WriteSessionJson(s);
    return dir;
  }

  // Rewrites session.json of `dir` after `mutate`.
  static void MutateJson(const fs::path& dir, const std::function<void(Json&)>& mutate) {
    Json j = ReadJsonFile(dir / "session.json");
    mutate(j);
    WriteJsonFile(dir / "session.json", j);
  }

  fs::path work_;
};

TEST_F(CheckCliTest, ValidSessionSummary) {
  const fs::path dir = WriteSession("ok");
  const CliResult r = Mesoscan("check " + dir.string(), work_);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("camera: 16x12"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("projector: 64x48"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("frames: 16, 16x12, 16-bit grey"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("phase shift (axis x): periods 7,11 x 3 phases; unambiguous over 77 px"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("lens shift: 8 frames at 8 positions over -2048..2048 steps"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("white: yes; black: yes"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("ground truth: no"), std::string::npos) << r.out;
  EXPECT_TRUE(r.err.empty()) << r.err;
  // The session.json path is accepted too.
  EXPECT_EQ(Mesoscan("check " + (dir / "session.json").string(), work_).exit_code, 0);
}

TEST_F(CheckCliTest, CoinEdgeExample) {
  const fs::path example = fs::path(MESOSCAN_SHARED_DIR) / "spec/examples/coin-edge";
  if (!fs::exists(example / "session.json")) GTEST_SKIP() << "no example at " << example;
  const CliResult r = Mesoscan("check " + example.string(), work_);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(
      r.out.find("phase shift (axis x): periods 7,11,13 x 3 phases; unambiguous over 1001 px"),
      std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("lens shift: 50 frames at 50 positions over -2048..1966 steps"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("ground truth: yes (points gt_points.exr, height gt_height.exr)"),
            std::string::npos)
      << r.out;
}

TEST_F(CheckCliTest, BadSessionsExitThreeWithOneLine) {
  struct Case {
    std::string name;
    std::function<void(const fs::path&)> mutate;
    std::string expected;  // stderr
  };
  const std::vector<Case> cases = {
      {"singular_k",
       [](const fs::path& d) { MutateJson(d, [](Json& j) { j["rig"]["camera"]["K"][0][0] = 0; }); },
       "mesoscan: session.json: rig.camera.K: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with "
       "fx > 0 and fy > 0 (a non-singular pinhole matrix)\n"},
      {"format",
       [](const fs::path& d) {
         MutateJson(d, [](Json& j) { j["format"] = "mesoscan-session/2"; });
       },
       "mesoscan: session.json: format: expected \"mesoscan-session/1\" (or a 1.x minor), got "
       "\"mesoscan-session/2\"\n"},
      {"two_phases",
       [](const fs::path& d) { MutateJson(d, [](Json& j) { j["frames"].erase(4); }); },
       "mesoscan: session.json: frames: sine period 11 px (axis x) has 2 distinct phases, "
       "expected at least 3\n"},
      {"missing_frame", [](const fs::path& d) { fs::remove(d / "frames/ls_003.png"); },
       "mesoscan: frames/ls_003.png: file not found (frames[9].file)\n"},
      {"wrong_size",
       [](const fs::path& d) { WritePng16(d / "frames/white.png", ImageU16(640, 480)); },
       "mesoscan: frames/white.png: size 640x480, expected 16x12 (rig.camera.width/height)\n"},
      {"bad_json", [](const fs::path& d) { WriteTextFile(d / "session.json", "{\"format\": \n"); },
       "mesoscan: session.json: not valid JSON (syntax error at line 2, column 1)\n"},
      {"escape",
       [](const fs::path& d) {
         MutateJson(d, [](Json& j) { j["frames"][0]["file"] = "../secret.png"; });
       },
       "mesoscan: session.json: frames[0].file: \"../secret.png\" leaves the session folder, "
       "expected a path inside it (no \"..\")\n"},
  };
  for (const Case& c : cases) {
    const fs::path dir = WriteSession(c.name);
    c.mutate(dir);
    const CliResult r = Mesoscan("check " + dir.string(), work_);
    EXPECT_EQ(r.exit_code, 3) << c.name;
    EXPECT_EQ(r.err, c.expected) << c.name;
    EXPECT_TRUE(r.out.empty()) << c.name << ": " << r.out;
  }
}

TEST_F(CheckCliTest, NotASessionOrScan) {
  const CliResult missing = Mesoscan("check " + (work_ / "nothing").string(), work_);
  EXPECT_EQ(missing.exit_code, 3);
  EXPECT_EQ(missing.err, "mesoscan: " + (work_ / "nothing").string() +
                             ": not found, expected a session or scan folder\n");
  fs::create_directories(work_ / "empty");
  const CliResult empty = Mesoscan("check " + (work_ / "empty").string(), work_);
  EXPECT_EQ(empty.exit_code, 3);
  EXPECT_EQ(empty.err, "mesoscan: " + (work_ / "empty").string() +
                           ": expected a session folder (session.json) or a scan folder "
                           "(points.exr, height.exr)\n");
  EXPECT_EQ(Mesoscan("check", work_).exit_code, 2);  // usage
}

TEST_F(CheckCliTest, ScanFolder) {
  Scan scan;
  const int w = 6, h = 4;
  scan.points.xyz = ImageF(w, h, 3, 0.001f);
  scan.points.confidence = ImageF(w, h, 1, 1.0f);
  scan.points.projector_u = ImageF(w, h, 1, 10.0f);
  scan.points.xyz(0, 0, 2) = std::numeric_limits<float>::quiet_NaN();
  scan.points.confidence(0, 0) = 0;
  scan.height.z = ImageF(5, 3, 1, 0.002f);
  scan.height.confidence = ImageF(5, 3, 1, 1.0f);
  scan.height.pixel_size = 2e-5;
  scan.report = {{"session", "x"}, {"valid", 23}};
  const fs::path dir = work_ / "s.scan";
  WriteScanFolder(dir, scan);
  const CliResult r = Mesoscan("check " + dir.string(), work_);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("points.exr: 6x4, 23 of 24 pixels reconstructed"), std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("height.exr: 5x3, pixel 20 um"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("z 2..2 mm"), std::string::npos) << r.out;
  fs::remove(dir / "normal.exr");
  const CliResult broken = Mesoscan("check " + dir.string(), work_);
  EXPECT_EQ(broken.exit_code, 3);
  EXPECT_EQ(broken.err, "mesoscan: " + (dir / "normal.exr").string() + ": file not found\n");
}

TEST_F(CheckCliTest, DoctorReportsAndExitsZero) {
  const CliResult r = Mesoscan("doctor --display :9999", work_);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("OpenImageIO 2."), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("OpenEXR 3."), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("libgphoto2 2."), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("cameras (libgphoto2):"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("serial ports ("), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("display: :9999: cannot open X display ':9999'"), std::string::npos)
      << r.out;
}

}  // namespace
}  // namespace mesoscan
