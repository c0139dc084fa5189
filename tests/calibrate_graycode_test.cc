// Calibration from Gray-code boards (calibration/calibrate_codecs.h): the virtual rig's boards
// under a Gray code of the projector's columns and rows alone (each bit and its inverse, white,
// black: OpenCV's structured_light GrayCodePattern), five poses, a reduced camera; the projector
// corners come from integer codes through Moreno & Taubin's local homographies. Compared with the
// truth, OpenCV's calibration on the same corners beside ours; sessions that mix codecs or lack
// inverse frames are refused with one line naming session.json's key.

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <numbers>
#include <stdexcept>

#include "calibration/calibrate.h"
#include "core/error.h"
#include "core/fs.h"
#include "core/json.h"
#include "core/progress.h"
#include "session/session.h"
#include "sim/board_sim.h"
#include "sim/virtual_rig.h"
#include "tests/cli_util.h"
#include "tests/view_cache.h"

namespace fs = std::filesystem;

namespace mesoscan {
namespace {

constexpr const char* kBoard = "checker:8x5:10";

const CalibrationBoard& Board() {
  static const CalibrationBoard b = CalibrationBoard::Parse(kBoard, "test");
  return b;
}

// Camera 480 x 384 0.4 m above the mount, projector 512 x 384 (9 bits per axis) at 15 degrees,
// 0.42 m away (RealShapeRig's poses): about 0.9 camera pixels per projector pixel on the mount
// (the held-back captures' 1280 x 1024 camera sees about 1.2 per projector pixel). Radial
// distortion on both.
Rig GrayRig() {
  Rig rig = RealShapeRig();
  rig.camera.width = 480;
  rig.camera.height = 384;
  rig.camera.K << 1125, 0, 239.5, 0, 1125, 191.5, 0, 0, 1;
  rig.camera.distortion = {-0.08, 0.1, 0, 0, 0};
  rig.projector.width = 512;
  rig.projector.height = 384;
  rig.projector.K << 1250, 0, 255.5, 0, 1250, 191.5, 0, 0, 1;
  rig.projector.distortion = {0.04, 0, 0, 0, 0};
  return rig;
}

// Five poses (degrees, mm): flat, then tilts of 20-30 degrees about both axes.
const std::vector<std::array<double, 6>>& Poses() {
  static const std::vector<std::array<double, 6>> p = {{0, 0, 0, 0, 0, 0},
                                                       {25, 0, 8, 0, 0, 5},
                                                       {-20, 18, -10, 3, 0, 10},
                                                       {0, -28, 12, 0, 4, -5},
                                                       {18, 22, -5, -4, 0, 0}};
  return p;
}

fs::path Dir(const std::string& name) { return CliTempDir("calibrate_graycode", name); }

struct GrayCodeBoards : public ::testing::Test {
  static void SetUpTestSuite() {
    Progress::SetEnabled(false);
    truth_ = new Rig(GrayRig());
    const fs::path rig_file = Dir("true_rig.json");
    WriteRigFile(rig_file, *truth_);
    SimulateOptions so;
    so.rig = rig_file.string();
    so.supersample = 1;  // the checker is box-filtered analytically
    // A board-scale depth of field (the default, 200 px/m, is the scanning rig's close focus).
    so.defocus_px_per_m = 20;
    so.ps_periods_px.clear();
    so.graycode_bits = 9;  // 512 columns
    so.ls_frames = 0;
    BoardSimOptions bo;
    bo.board = Board();
    bo.graycode_y_bits = 9;  // 384 rows
    bo.frame_format = "png8";
    // The five views are simulated once per build of this test binary (tests/view_cache.h).
    sessions_ = new std::vector<fs::path>(
        testing_support::BoardViewsOnce("calibrate_graycode_views", so, bo, Poses(), 300));
  }
  static void TearDownTestSuite() {
    delete sessions_;
    delete truth_;
  }
  static Rig* truth_;
  static std::vector<fs::path>* sessions_;
};
Rig* GrayCodeBoards::truth_ = nullptr;
std::vector<fs::path>* GrayCodeBoards::sessions_ = nullptr;

// The true projector coordinate seen by camera pixel (x, y) of view i (the board plane).
bool TrueProjector(const Rig& t, const std::array<double, 6>& pose, double x, double y, Vec2d* up,
                   Vec3d* on_board) {
  const Rigid3d world_from_board = BoardPoseToRigid(pose);
  const Vec3d n = world_from_board.rotation.col(2), b0 = world_from_board.translation;
  const Vec3d c = t.camera.CentreInWorld();
  const Vec3d d = t.camera.RayDirectionInWorld(Vec2d(x, y));
  const double nd = n.dot(d);
  if (!(std::abs(nd) > 1e-12)) return false;
  const Vec3d p = c + (n.dot(b0 - c) / nd) * d;
  *on_board = world_from_board.Inverse() * p;
  return t.projector.Project(p, up);
}

// Every camera pixel the codec gives a projector coordinate lies within one column (row) of the
// truth; most lit board pixels get one.
TEST_F(GrayCodeBoards, DecodedPixelsAreWithinOneColumnOfTheTruth) {
  CalibrateOptions co;
  co.board = Board();
  const Session s = ReadSession((*sessions_)[1]);
  std::vector<uint32_t> pixels;
  for (int y = 0; y < s.rig.camera.height; y += 2)
    for (int x = 0; x < s.rig.camera.width; x += 2)
      pixels.push_back(static_cast<uint32_t>(y * s.rig.camera.width + x));
  const ProjectorCoordinates pc = DecodeProjectorCoordinates(s, pixels, co);
  int decoded = 0, seen = 0, off = 0;
  double worst = 0;
  for (size_t n = 0; n < pixels.size(); ++n) {
    const double x = pixels[n] % s.rig.camera.width, y = pixels[n] / s.rig.camera.width;
    Vec2d up;
    Vec3d b;
    if (!TrueProjector(*truth_, Poses()[1], x, y, &up, &b)) continue;
    // Well inside the projector.
    if (up.x() < 2 || up.y() < 2 || up.x() > 509 || up.y() > 381) continue;
    const bool light = std::abs(b.x()) < Board().HalfWidth() &&
                       std::abs(b.y()) < Board().HalfHeight() && !Board().Dark(b.x(), b.y());
    seen += light;
    if (!std::isfinite(pc.u[n]) || !std::isfinite(pc.v[n])) continue;
    decoded += light;
    const double e = std::max(std::abs(pc.u[n] - up.x()), std::abs(pc.v[n] - up.y()));
    worst = std::max(worst, e);
    off += e > 1.0;
  }
  std::printf(
      "decoded %d of %d pixels of the light squares, worst error of any decoded pixel %.3f px, "
      "%d beyond 1 px\n",
      decoded, seen, worst, off);
  // Measured: 88.5% of the light squares, worst error 0.497 px (the pixels left out straddle an
  // edge of the finest bit, whose stripes are 1.8 camera pixels wide here).
  EXPECT_EQ(off, 0);
  EXPECT_GT(decoded, 0.8 * seen);
}

TEST_F(GrayCodeBoards, RecoversTheRigBesideOpenCv) {
  CalibrateOptions co;
  co.board = Board();
  co.model = CalibrationModel::kK1K2;
  co.fix_tangential = true;
  std::vector<CalibrationView> views;
  for (const auto& d : *sessions_) views.push_back(DetectView(ReadSession(d), co));
  // The observation errors: corners against their true images.
  const Rig& t = *truth_;
  double sc = 0, sp = 0;
  int nc = 0, np = 0;
  for (size_t i = 0; i < views.size(); ++i) {
    const CalibrationView& v = views[i];
    ASSERT_TRUE(v.found) << v.name << ": " << v.problem;
    EXPECT_EQ(v.codec, "graycode");
    int decoded = 0;
    for (const auto& p : v.projector_px) decoded += p.allFinite();
    std::printf("view %zu: %d of %d projector corners\n", i, decoded, Board().num_corners());
    const Rigid3d world_from_board = BoardPoseToRigid(Poses()[i]);
    for (int k = 0; k < Board().num_corners(); ++k) {
      const Vec3d x = world_from_board * Board().Corner(k);
      Vec2d uc, up;
      ASSERT_TRUE(t.camera.Project(x, &uc));
      ASSERT_TRUE(t.projector.Project(x, &up));
      sc += (v.camera_px[k] - uc).squaredNorm();
      ++nc;
      if (v.projector_px[k].allFinite()) {
        sp += (v.projector_px[k] - up).squaredNorm();
        ++np;
      }
    }
  }
  const double obs_cam = std::sqrt(sc / nc), obs_prj = std::sqrt(sp / np),
               obs_stereo = std::sqrt((sc + sp) / (nc + np));
  std::printf("observations: camera corners %.4f px RMS, projector corners %.4f px (%d of %d)\n",
              obs_cam, obs_prj, np, nc);
  EXPECT_GE(np, 0.95 * nc);
  Rig sizes = t;
  sizes.uncalibrated = true;
  const CalibrationResult r = Calibrate(views, sizes, std::nullopt, co);
  std::printf("%s\n", r.BriefReport().c_str());
  const Json& cv = r.opencv["joint"];
  const double f[2][2] = {{r.rig.camera.K(0, 0), r.rig.camera.K(1, 1)},
                          {r.rig.projector.K(0, 0), r.rig.projector.K(1, 1)}};
  const double f_cv[2][2] = {
      {cv["camera"]["fx"].get<double>(), cv["camera"]["fy"].get<double>()},
      {cv["projector"]["fx"].get<double>(), cv["projector"]["fy"].get<double>()}};
  const double f_true[2] = {t.camera.K(0, 0), t.projector.K(0, 0)};
  for (int d = 0; d < 2; ++d) {
    std::printf(
        "%s fx %.2f fy %.2f (OpenCV %.2f %.2f, true %.2f): errors %.3f%% %.3f%% (OpenCV "
        "%.3f%% %.3f%%)\n",
        d ? "projector" : "camera", f[d][0], f[d][1], f_cv[d][0], f_cv[d][1], f_true[d],
        100 * (f[d][0] / f_true[d] - 1), 100 * (f[d][1] / f_true[d] - 1),
        100 * (f_cv[d][0] / f_true[d] - 1), 100 * (f_cv[d][1] / f_true[d] - 1));
    EXPECT_NEAR(f[d][0] / f_true[d], 1.0, 0.01) << d;
    EXPECT_NEAR(f[d][1] / f_true[d], 1.0, 0.01) << d;
  }
  std::printf("stereo RMS %.4f px (OpenCV stereoCalibrate %.4f px), observation noise %.4f px\n",
              r.rms_stereo_px, cv["rms_px"].get<double>(), obs_stereo);
  // The adjustment fits a few of the residuals' degrees of freedom: RMS ~ the observations'.
  EXPECT_GT(r.rms_stereo_px, 0.6 * obs_stereo);
  EXPECT_LT(r.rms_stereo_px, 1.2 * obs_stereo);
  const Rigid3d rel = r.rig.projector.world_from_device.Inverse() * r.rig.camera.world_from_device;
  const Rigid3d rel_true = t.projector.world_from_device.Inverse() * t.camera.world_from_device;
  const double dt_mm = (rel.translation - rel_true.translation).norm() * 1e3;
  std::printf("baseline error %.3f mm of %.1f mm\n", dt_mm, rel_true.translation.norm() * 1e3);
  EXPECT_LT(dt_mm, 0.01 * rel_true.translation.norm() * 1e3);
}

// session.json of `from` with `edit` applied, frames copied, into `to`.
fs::path EditedSession(const fs::path& from, const std::string& to,
                       const std::function<void(Json&)>& edit) {
  const fs::path dir = Dir(to);
  fs::remove_all(dir);
  fs::copy(from, dir, fs::copy_options::recursive);
  Json j = ReadJsonFile(dir / "session.json");
  edit(j);
  WriteJsonFile(dir / "session.json", j);
  return dir;
}

void ExpectRefused(const fs::path& session, const std::string& key, const std::string& words) {
  CalibrateOptions co;
  co.board = Board();
  try {
    DetectView(ReadSession(session), co);
    ADD_FAILURE() << session << ": accepted";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput) << e.what();
    EXPECT_EQ(e.key(), key) << e.what();
    EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
    EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << e.what();
  }
  // The command line: exit 3, one line naming the session file and the key.
  std::string args;
  for (int i = 0; i < 3; ++i) args += session.string() + " ";
  const CliResult r = RunMesoscan("calibrate " + args + "--board " + kBoard + " --out " +
                                  Dir("refused_rig.json").string());
  EXPECT_EQ(r.code, 3) << r.output;
  EXPECT_NE(r.output.find((session / "session.json").string() + ": " + key), std::string::npos)
      << r.output;
  EXPECT_FALSE(fs::exists(Dir("refused_rig.json")));
}

TEST_F(GrayCodeBoards, MixedCodecsAndMissingInversesAreRefused) {
  const fs::path src = (*sessions_)[0];
  // Bit 3 along x without its inverse frame.
  int dropped = -1;
  const fs::path no_inverse = EditedSession(src, "no_inverse", [&](Json& j) {
    Json frames = Json::array();
    for (const auto& f : j["frames"]) {
      const Json& p = f["pattern"];
      if (p["type"] == "graycode" && p["axis"] == "x" && p["bit"] == 3 &&
          p.value("inverted", false))
        continue;
      frames.push_back(f);
    }
    j["frames"] = frames;
  });
  for (size_t f = 0; f < ReadSession(no_inverse).frames.size(); ++f) {
    const Pattern& p = ReadSession(no_inverse).frames[f].pattern;
    if (p.type == PatternType::kGrayCode && p.axis == 'x' && p.bit == 3) dropped = f;
  }
  ASSERT_GE(dropped, 0);
  ExpectRefused(no_inverse, "frames[" + std::to_string(dropped) + "]", "inverse");
  // A Gray code along x, sines alone along y.
  const fs::path mixed = EditedSession(src, "mixed", [](Json& j) {
    Json frames = Json::array();
    for (const auto& f : j["frames"])
      if (!(f["pattern"]["type"] == "graycode" && f["pattern"]["axis"] == "y")) frames.push_back(f);
    for (int k = 0; k < 3; ++k)
      frames.push_back({{"file", "frames/gcy" + std::to_string(k) + ".png"},
                        {"pattern",
                         {{"type", "sine"},
                          {"axis", "y"},
                          {"period_px", 384},
                          {"phase", 2 * std::numbers::pi * k / 3}}},
                        {"shift_steps", 0}});
    j["frames"] = frames;
  });
  ExpectRefused(mixed, "frames", "same codec along both");
  fs::remove_all(no_inverse);
  fs::remove_all(mixed);
}

}  // namespace
}  // namespace mesoscan
