// Camera raw sessions through `mesoscan check` and the reconstruction's frame decoder, and the
// acquisition sequencer through `mesoscan capture`.

#include <gtest/gtest.h>

#include <fstream>
#include <random>

#include "capture/lens_shifter_sim.h"
#include "capture/sequencer.h"
#include "capture/xvfb_server_test_util.h"
#include "core/image_io.h"
#include "core/json.h"
#include "heightfield/frames.h"
#include "session/patterns.h"
#include "session/raw_frame.h"
#include "session/session.h"
#include "tests/cli_util.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

// A small phase-shift session (camera 12 x 11: sensor 24 x 22, LibRaw's minimum is 22 x 22)
// whose frames are DNG mosaics with black level 256 and white level 4095 (12-bit sensor).
Session RawSession(const fs::path& root) {
  Session s;
  s.root = root;
  s.created = "2026-11-21T12:00:00Z";
  s.object = "raw session";
  s.rig = SmallTestRig(12, 11, 60, 40, false);
  FramePlanOptions plan;
  plan.periods_px = {7, 11};
  plan.lens_shift_frames = 0;
  s.frames = MakeStandardFrames(plan);
  for (Frame& f : s.frames) f.file = fs::path(f.file).replace_extension(".dng").string();
  return s;
}

// Its frames are random codes: `check --quick` accepts the session, and `check` decodes every
// DNG whole and then refuses the session as reconstruct would (no pattern in the frames), not
// for a frame.
TEST(CaptureCli, DngSessionIsCheckedWholeAndDecodesToBinnedBlackSubtractedFrames) {
  const fs::path dir = CliTempDir("capture_cli", "dng");
  fs::remove_all(dir);
  fs::create_directories(dir / "frames");
  Session s = RawSession(dir);
  RawLevels levels;
  levels.black = {256, 256, 256, 256};
  levels.white = 4095;
  std::mt19937 rng(11);
  std::uniform_int_distribution<int> code(256, 4095);
  std::vector<ImageU16> mosaics;
  for (size_t i = 0; i < s.frames.size(); ++i) {
    ImageU16 m(24, 22);
    for (uint16_t& v : m.data()) v = static_cast<uint16_t>(code(rng));
    WriteCfaDng(s.FramePath(i), m, levels);
    mosaics.push_back(std::move(m));
  }
  WriteSessionJson(s);

  const CliResult quick = RunMesoscan("check --quick " + dir.string());
  EXPECT_EQ(quick.code, 0) << quick.output;
  const CliResult check = RunMesoscan("check " + dir.string());
  EXPECT_EQ(check.code, 3) << check.output;
  EXPECT_NE(check.output.find("could be reconstructed from the 132 pixels tried"),
            std::string::npos)
      << check.output;

  // The decoder of `reconstruct` sees 12 x 11 frames: (mean of each cell - 256) * 65535 / 3839,
  // then the session's black level (0) and linear response through a 65536-entry table.
  const Session r = ReadSession(dir);
  std::vector<int> all(r.frames.size());
  for (size_t i = 0; i < all.size(); ++i) all[i] = static_cast<int>(i);
  const FrameStack stack = LoadFrames(r, all, FrameLoadOptions());
  ASSERT_EQ(stack.width(), 12);
  ASSERT_EQ(stack.height(), 11);
  double max_err_codes = 0.0;
  for (int k = 0; k < stack.num_frames(); ++k)
    for (int y = 0; y < 11; ++y)
      for (int x = 0; x < 12; ++x) {
        const ImageU16& m = mosaics[k];
        const double mean = (double(m(2 * x, 2 * y)) + m(2 * x + 1, 2 * y) + m(2 * x, 2 * y + 1) +
                             m(2 * x + 1, 2 * y + 1)) /
                            4.0;
        const double expected = (mean - 256.0) / (4095.0 - 256.0);  // in [0, 1]
        max_err_codes = std::max(
            max_err_codes,
            std::abs(stack.Value(k, static_cast<size_t>(y) * 12 + x) - expected) * 65535.0);
      }
  EXPECT_LE(max_err_codes, 0.5 + 1e-3);  // one rounding to 16 bits
  // Gather (computed for a linear response, frames.h) gives Value's table entries to the bit.
  std::vector<float> row(12 * 11);
  for (int k = 0; k < stack.num_frames(); ++k) {
    stack.Gather(k, 0, row.size(), row.data());
    for (size_t i = 0; i < row.size(); ++i) ASSERT_EQ(row[i], stack.Value(k, i)) << k << " " << i;
  }
  fs::remove_all(dir);
}

TEST(CaptureCli, DoctorReportsOpenCvEmbreeAndLibRaw) {
  const CliResult r = RunMesoscan("doctor --display :9999");
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("  OpenCV 4."), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("  Embree 3."), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("  LibRaw 0."), std::string::npos) << r.output;
}

std::string ReadFile(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

int Lines(const std::string& text) {
  int n = 0;
  for (char c : text) n += c == '\n';
  return n;
}

// `mesoscan capture` with the real projector window (Xvfb), the real serial driver against the
// simulated controller on a pty (in this process), and the screen camera. The screen camera
// sees the projector's image itself, not a scene: its sessions pass `check --quick`, and `check`
// (which reconstructs a window, as reconstruct would) refuses them after decoding every frame
// (the white frame is the screen's full white: saturated).
class CaptureCommand : public XvfbTest {
 protected:
  void SetUp() override {
    XvfbTest::SetUp();
    if (IsSkipped()) return;
    dir_ = CliTempDir("capture_cli", "capture");
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    // Rig: projector 64 x 48, camera 32 x 24, shifter over [-2048, 2048).
    Session s;
    s.rig = SmallTestRig(32, 24, 64, 48, true);
    s.frames = {Frame{"frames/white.png", Pattern{}, 0}};
    std::ofstream(dir_ / "rig.json") << Json{{"rig", SessionToJson(s)["rig"]}}.dump(2);
  }
  void TearDown() override {
    if (!dir_.empty()) fs::remove_all(dir_);
  }

  // `-q capture` of the test rig into dir_/name with extra arguments.
  CliResult Capture(const std::string& name, const std::string& extra,
                    const std::string& camera = "screen") {
    return RunMesoscan("-q capture --out " + (dir_ / name).string() + " --rig " +
                       (dir_ / "rig.json").string() + " --camera " + camera + " --shifter " +
                       sim_.Port() + " --display " + display() +
                       " --periods 7,11 --ls-frames 4 --settle 0 " + extra);
  }

  fs::path dir_;
  LensShifterSim sim_;
};

TEST_F(CaptureCommand, ResumedCaptureEqualsAnUninterruptedOneAndPassesCheckQuick) {
  const CliResult whole = Capture("whole", "");
  ASSERT_EQ(whole.code, 0) << whole.output;
  EXPECT_EQ(sim_.position(), 0);  // back at the neutral position
  const CliResult quick = RunMesoscan("check --quick " + (dir_ / "whole").string());
  EXPECT_EQ(quick.code, 0) << quick.output;
  const CliResult check = RunMesoscan("check " + (dir_ / "whole").string());
  EXPECT_EQ(check.code, 3) << check.output;
  EXPECT_NE(check.output.find("saturated in some frame"), std::string::npos) << check.output;

  // Stopped after 5 frames, then resumed: the same session.
  const CliResult part = Capture("parts", "--max-frames 5");
  ASSERT_EQ(part.code, 0) << part.output;
  EXPECT_NE(part.output.find("5 of 12 frames (0 reused, 5 captured)"), std::string::npos)
      << part.output;
  EXPECT_FALSE(fs::exists(dir_ / "parts" / "session.json"));
  EXPECT_TRUE(fs::exists(dir_ / "parts" / kCaptureJournal));
  const CliResult rest = Capture("parts", "");
  ASSERT_EQ(rest.code, 0) << rest.output;
  EXPECT_NE(rest.output.find("12 of 12 frames (5 reused, 7 captured)"), std::string::npos)
      << rest.output;
  EXPECT_EQ(RunMesoscan("check --quick " + (dir_ / "parts").string()).code, 0);
  const Session a = ReadSession(dir_ / "whole"), b = ReadSession(dir_ / "parts");
  Json ja = SessionToJson(a), jb = SessionToJson(b);
  ja.erase("created");
  jb.erase("created");
  EXPECT_EQ(ja, jb);
  ASSERT_EQ(a.frames.size(), 12u);
  for (size_t i = 0; i < a.frames.size(); ++i)
    EXPECT_EQ(ReadFile(a.FramePath(i)), ReadFile(b.FramePath(i))) << a.frames[i].file;
  EXPECT_FALSE(fs::exists(dir_ / "parts" / kCaptureJournal));

  // A completed session is not overwritten without --force.
  const std::string manifest = ReadFile(dir_ / "whole" / "session.json");
  const CliResult again = Capture("whole", "");
  EXPECT_EQ(again.code, 2) << again.output;
  EXPECT_EQ(Lines(again.output), 1) << again.output;
  EXPECT_NE(again.output.find("pass --force"), std::string::npos) << again.output;
  EXPECT_EQ(ReadFile(dir_ / "whole" / "session.json"), manifest);
  EXPECT_EQ(Capture("whole", "--force").code, 0);
}

TEST_F(CaptureCommand, RawCameraSessionIsCheckedWhole) {
  const CliResult r = Capture("dng", "--no-white", "screen-dng");
  ASSERT_EQ(r.code, 0) << r.output;
  const Session s = ReadSession(dir_ / "dng");
  EXPECT_EQ(s.frames.front().file, "frames/ps07_0.dng");
  const CliResult quick = RunMesoscan("check --quick " + (dir_ / "dng").string());
  EXPECT_EQ(quick.code, 0) << quick.output;
  const CliResult check = RunMesoscan("check " + (dir_ / "dng").string());
  EXPECT_EQ(check.code, 3) << check.output;
  EXPECT_NE(check.output.find("could be reconstructed from the 768 pixels tried"),
            std::string::npos)
      << check.output;
}

// `capture --plan calibration` shows sines along both projector axes, white and
// black (no lens shift, so no shifter needed) on a rig that holds device sizes only; the session
// is a calibration session, and `simulate --object board:...` of the same rig lists the same
// frames (one generator, session/patterns.h).
TEST_F(CaptureCommand, CalibrationPlanCapturesBothAxesAndMatchesTheBoardSimulation) {
  Session sized;
  sized.rig = SmallTestRig(32, 24, 64, 48, false);
  Json rig = SessionToJson(sized)["rig"];
  for (const char* device : {"camera", "projector"})
    for (const char* key : {"K", "distortion", "world_from_device"}) rig[device].erase(key);
  std::ofstream(dir_ / "sizes.json") << Json{{"rig", rig}}.dump(2);
  const fs::path out = dir_ / "calib";
  const CliResult r = RunMesoscan("-q capture --plan calibration --out " + out.string() +
                                  " --rig " + (dir_ / "sizes.json").string() +
                                  " --camera screen --display " + display() + " --settle 0");
  ASSERT_EQ(r.code, 0) << r.output;
  const Session s = ReadSession(out);
  EXPECT_TRUE(s.rig.uncalibrated);
  // Periods: the projector's width and 1/16 of it along x (64, 4), its height and 1/16 along y
  // (48, 3); 3 phases each, white, black.
  const FramePlan plan = MakeFramePlan(s.frames);
  EXPECT_EQ(plan.Periods('x'), (std::vector<double>{4, 64}));
  EXPECT_EQ(plan.Periods('y'), (std::vector<double>{3, 48}));
  EXPECT_TRUE(plan.lens_shift.empty());
  ASSERT_EQ(s.frames.size(), 14u);
  // A y sine varies along camera rows only; an x sine along columns only.
  for (const size_t i : {size_t{0}, size_t{6}}) {
    const ImageF f = ReadImageGrey(s.FramePath(i));
    double along_x = 0, along_y = 0;
    for (int y = 0; y + 1 < f.height(); ++y)
      for (int x = 0; x + 1 < f.width(); ++x) {
        along_x += std::abs(f(x + 1, y) - f(x, y));
        along_y += std::abs(f(x, y + 1) - f(x, y));
      }
    const bool y_sine = s.frames[i].pattern.axis == 'y';
    EXPECT_GT(y_sine ? along_y : along_x, 1.0) << s.frames[i].file;
    EXPECT_EQ(y_sine ? along_x : along_y, 0.0) << s.frames[i].file;
  }
  const CliResult check = RunMesoscan("check " + out.string());
  EXPECT_EQ(check.code, 0) << check.output;
  EXPECT_NE(check.output.find("calibration session"), std::string::npos) << check.output;

  // The simulator's board session of the calibrated rig: the same frame list.
  const fs::path board = dir_ / "board";
  const CliResult sim = RunMesoscan("-q simulate --object board:checker:5x4:10 --rig " +
                                    (dir_ / "rig.json").string() + " --out " + board.string());
  ASSERT_EQ(sim.code, 0) << sim.output;
  const Session b = ReadSession(board);
  ASSERT_EQ(b.frames.size(), s.frames.size());
  for (size_t i = 0; i < s.frames.size(); ++i) {
    EXPECT_EQ(b.frames[i].file, s.frames[i].file);
    EXPECT_EQ(b.frames[i].pattern.type, s.frames[i].pattern.type) << s.frames[i].file;
    EXPECT_EQ(b.frames[i].pattern.axis, s.frames[i].pattern.axis) << s.frames[i].file;
    EXPECT_EQ(b.frames[i].pattern.period_px, s.frames[i].pattern.period_px) << s.frames[i].file;
    EXPECT_EQ(b.frames[i].pattern.phase, s.frames[i].pattern.phase) << s.frames[i].file;
    EXPECT_EQ(b.frames[i].shift_steps, s.frames[i].shift_steps) << s.frames[i].file;
  }

  // A calibration plan takes no lens-shift frames; an unknown plan is a usage error.
  for (const char* extra :
       {"--plan calibration --ls-frames 8", "--plan turntable", "--periods-y 30,7"}) {
    const CliResult bad = RunMesoscan("-q capture --out " + (dir_ / "bad").string() + " --rig " +
                                      (dir_ / "sizes.json").string() + " --camera screen " +
                                      "--display " + display() + " " + extra);
    EXPECT_EQ(bad.code, 2) << extra << ": " << bad.output;
    EXPECT_EQ(Lines(bad.output), 1) << extra << ": " << bad.output;
  }
}

// `capture --plan calibration --patterns graycode` shows a Gray code of the projector's columns
// and rows, each bit and its inverse, white and black (OpenCV's GrayCodePattern frames): the
// camera (reading the window back at half its size) sees each bit as the pattern says; the board
// simulation of the same plan lists the same frames. sine+graycode: one period per axis, each with
// a complementary code of half its width.
TEST_F(CaptureCommand, GrayCodeCalibrationPlansShowTheCodeAlongBothAxes) {
  Session sized;
  sized.rig = SmallTestRig(32, 24, 64, 48, false);
  Json rig = SessionToJson(sized)["rig"];
  for (const char* device : {"camera", "projector"})
    for (const char* key : {"K", "distortion", "world_from_device"}) rig[device].erase(key);
  std::ofstream(dir_ / "sizes.json") << Json{{"rig", rig}}.dump(2);
  const fs::path out = dir_ / "gray";
  const CliResult r = RunMesoscan("-q capture --plan calibration --patterns graycode --out " +
                                  out.string() + " --rig " + (dir_ / "sizes.json").string() +
                                  " --camera screen --display " + display() + " --settle 0");
  ASSERT_EQ(r.code, 0) << r.output;
  const Session s = ReadSession(out);
  // 6 bits along x (64 columns) and along y (48 rows), each with its inverse; white, black.
  ASSERT_EQ(s.frames.size(), 26u);
  int coded[2] = {0, 0};
  for (size_t i = 0; i < s.frames.size(); ++i) {
    const Pattern& p = s.frames[i].pattern;
    if (p.type != PatternType::kGrayCode) continue;
    EXPECT_EQ(p.bits, 6) << s.frames[i].file;
    EXPECT_EQ(p.block_px, 1.0) << s.frames[i].file;
    ++coded[p.axis == 'y'];
    if (p.bit == 5) continue;  // the finest stripes are 2 projector px: mixed in a camera pixel
    // Camera pixel (x, y) sees projector pixels 2x..2x+1, 2y..2y+1: one bit value.
    const ImageF f = ReadImageGrey(s.FramePath(i));
    for (int y = 0; y < f.height(); ++y)
      for (int x = 0; x < f.width(); ++x)
        ASSERT_NEAR(f(x, y), p.Value(2 * x, 2 * y), 1e-3)
            << s.frames[i].file << " " << x << "," << y;
  }
  EXPECT_EQ(coded[0], 12);
  EXPECT_EQ(coded[1], 12);
  const CliResult check = RunMesoscan("check " + out.string());
  EXPECT_EQ(check.code, 0) << check.output;
  const fs::path board = dir_ / "gray_board";
  const CliResult sim =
      RunMesoscan("-q simulate --object board:checker:5x4:10 --patterns graycode --rig " +
                  (dir_ / "rig.json").string() + " --out " + board.string());
  ASSERT_EQ(sim.code, 0) << sim.output;
  const Session b = ReadSession(board);
  ASSERT_EQ(b.frames.size(), s.frames.size());
  for (size_t i = 0; i < s.frames.size(); ++i) {
    EXPECT_EQ(b.frames[i].file, s.frames[i].file);
    EXPECT_EQ(b.frames[i].pattern.type, s.frames[i].pattern.type) << s.frames[i].file;
    EXPECT_EQ(b.frames[i].pattern.axis, s.frames[i].pattern.axis) << s.frames[i].file;
    EXPECT_EQ(b.frames[i].pattern.bit, s.frames[i].pattern.bit) << s.frames[i].file;
    EXPECT_EQ(b.frames[i].pattern.inverted, s.frames[i].pattern.inverted) << s.frames[i].file;
  }
  // sine+graycode: period 16 along x (blocks of 8: 3 bits), 12 along y (blocks of 6: 3 bits).
  const CliResult both = RunMesoscan(
      "-q capture --plan calibration --patterns sine+graycode --periods 16 --periods-y 12 --out " +
      (dir_ / "both").string() + " --rig " + (dir_ / "sizes.json").string() +
      " --camera screen --display " + display() + " --settle 0");
  ASSERT_EQ(both.code, 0) << both.output;
  const Session sb = ReadSession(dir_ / "both");
  const FramePlan plan = MakeFramePlan(sb.frames);
  EXPECT_EQ(plan.Periods('x'), (std::vector<double>{16}));
  EXPECT_EQ(plan.Periods('y'), (std::vector<double>{12}));
  int bits[2] = {0, 0};
  for (const Frame& f : sb.frames)
    if (f.pattern.type == PatternType::kGrayCode) {
      EXPECT_EQ(f.pattern.block_px, f.pattern.axis == 'x' ? 8.0 : 6.0);
      ++bits[f.pattern.axis == 'y'];
    }
  EXPECT_EQ(bits[0], 6);
  EXPECT_EQ(bits[1], 6);
  // Two periods cannot be ordered by one code: a usage error naming --patterns.
  const CliResult bad = RunMesoscan(
      "-q capture --plan calibration --patterns sine+graycode --out " + (dir_ / "bad").string() +
      " --rig " + (dir_ / "sizes.json").string() + " --camera screen --display " + display());
  EXPECT_EQ(bad.code, 2) << bad.output;
  EXPECT_NE(bad.output.find("--patterns"), std::string::npos) << bad.output;
}

// `capture --patterns heterodyne`: a scan of the three-frequency set (42, 45, 48 px, three
// steps each), white and black, no lens-shift frames although the rig has a shifter; the camera
// (the window read back at half its size) sees each sine as the pattern says. --periods and
// --phases name another set.
TEST_F(CaptureCommand, HeterodyneScanPlanShowsTheThreePeriods) {
  const std::string common = " --rig " + (dir_ / "rig.json").string() +
                             " --camera screen --shifter " + sim_.Port() + " --display " +
                             display() + " --settle 0 --patterns heterodyne";
  const fs::path out = dir_ / "het";
  const CliResult r = RunMesoscan("-q capture --out " + out.string() + common);
  ASSERT_EQ(r.code, 0) << r.output;
  const Session s = ReadSession(out);
  const FramePlan plan = MakeFramePlan(s.frames);
  EXPECT_EQ(plan.Periods('x'), HeterodynePeriods());
  EXPECT_TRUE(plan.lens_shift.empty());
  ASSERT_EQ(s.frames.size(), 11u);  // 3 x 3 sines, white, black
  int sines = 0;
  for (size_t i = 0; i < s.frames.size(); ++i) {
    const Pattern& p = s.frames[i].pattern;
    if (p.type != PatternType::kSine) continue;
    ++sines;
    EXPECT_EQ(p.axis, 'x') << s.frames[i].file;
    // Camera pixel (x, y) sees projector pixels 2x..2x+1 (8-bit screen).
    const ImageF f = ReadImageGrey(s.FramePath(i));
    for (int y = 0; y < f.height(); ++y)
      for (int x = 0; x < f.width(); ++x)
        ASSERT_NEAR(f(x, y), 0.5 * (p.Value(2 * x, 2 * y) + p.Value(2 * x + 1, 2 * y)), 0.02)
            << s.frames[i].file << " " << x << "," << y;
  }
  EXPECT_EQ(sines, 9);
  const CliResult other = RunMesoscan("-q capture --out " + (dir_ / "het4").string() + common +
                                      " --periods 20,24 --phases 4");
  ASSERT_EQ(other.code, 0) << other.output;
  const Session s4 = ReadSession(dir_ / "het4");
  EXPECT_EQ(MakeFramePlan(s4.frames).Periods('x'), (std::vector<double>{20, 24}));
  EXPECT_EQ(s4.frames.size(), 10u);
}

TEST_F(CaptureCommand, DeviceErrorsExitFourWithOneLineNamingTheDevice) {
  struct Case {
    std::string args, mentions;
  };
  const std::string rig = (dir_ / "rig.json").string();
  const std::string out = (dir_ / "bad").string();
  const Case cases[] = {
      {"--camera screen --shifter /dev/nonexistent-tty --display " + display(),
       "/dev/nonexistent-tty"},
      {"--camera screen --shifter " + sim_.Port() + " --display :9999", ":9999"},
      {"--camera gphoto2:NoSuchCamera --shifter " + sim_.Port() + " --display " + display(),
       "camera"},
  };
  for (const Case& c : cases) {
    const CliResult r = RunMesoscan("-q capture --out " + out + " --rig " + rig + " " + c.args);
    EXPECT_EQ(r.code, 4) << c.args << ": " << r.output;
    EXPECT_EQ(Lines(r.output), 1) << c.args << ": " << r.output;
    EXPECT_NE(r.output.find(c.mentions), std::string::npos) << c.args << ": " << r.output;
  }
  // Lens-shift frames without a shifter, or a bad --periods: usage errors (2).
  const CliResult no_shifter = RunMesoscan("-q capture --out " + out + " --rig " + rig +
                                           " --camera screen --display " + display());
  EXPECT_EQ(no_shifter.code, 2) << no_shifter.output;
  const CliResult bad_periods =
      RunMesoscan("-q capture --out " + out + " --rig " + rig + " --periods 7,x --camera screen");
  EXPECT_EQ(bad_periods.code, 2) << bad_periods.output;
  EXPECT_NE(bad_periods.output.find("--periods"), std::string::npos) << bad_periods.output;
}

}  // namespace
}  // namespace mesoscan

namespace mesoscan {
namespace {

// `capture --rehearse` needs no hardware, no display and no shifter port: its
// own Xvfb, the screen camera and the simulated shifter on a pty; the session passes
// `check --quick` (the screen camera sees no scene: `check` refuses it, as above).
TEST(CaptureRehearse, AFullCaptureWithoutHardwarePassesCheckQuick) {
  if (::access("/usr/bin/Xvfb", X_OK) != 0) GTEST_SKIP() << "Xvfb not installed";
  const fs::path dir = CliTempDir("capture_cli", "rehearse");
  fs::remove_all(dir);
  fs::create_directories(dir);
  Session s;
  s.rig = SmallTestRig(32, 24, 64, 48, true);
  s.frames = {Frame{"frames/white.png", Pattern{}, 0}};
  std::ofstream(dir / "rig.json") << Json{{"rig", SessionToJson(s)["rig"]}}.dump(2);
  const CliResult r =
      RunMesoscan("-q capture --rehearse --out " + (dir / "R").string() + " --rig " +
                  (dir / "rig.json").string() + " --periods 7,11 --ls-frames 4 --settle 0");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("a rehearsal of the capture chain"), std::string::npos) << r.output;
  EXPECT_TRUE(fs::exists(dir / "R" / "session.json"));
  EXPECT_FALSE(fs::exists(dir / "R" / kCaptureJournal));
  EXPECT_NE(ReadJsonFile(dir / "R" / "session.json")["object"].get<std::string>().find(
                "capture rehearsal"),
            std::string::npos);
  const CliResult c = RunMesoscan("check --quick " + (dir / "R").string());
  EXPECT_EQ(c.code, 0) << c.output;
  fs::remove_all(dir);
}

}  // namespace
}  // namespace mesoscan
