#include "capture/sequencer.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <fstream>

#include "capture/lens_shifter.h"
#include "capture/lens_shifter_sim.h"
#include "capture/projector_window.h"
#include "capture/xvfb_server_test_util.h"
#include "core/error.h"
#include "core/image_io.h"
#include "session/patterns.h"
#include "session/raw_frame.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

constexpr int kProjW = 64, kProjH = 48, kCamW = 32, kCamH = 24;

// A plan: projector 64 x 48, camera 32 x 24 (the screen camera box-averages 2 x 2 screen
// pixels), periods 7 and 11 (LCM 77 >= 64) x 3 phases, 4 lens-shift frames over [-2048, 2048] (both
// ends), white, black: 12 frames.
Session Plan(const fs::path& root) {
  Session s;
  s.root = root;
  s.object = "sequencer test";
  s.rig = SmallTestRig(kCamW, kCamH, kProjW, kProjH, true);
  FramePlanOptions plan;
  plan.periods_px = {7, 11};
  plan.lens_shift_frames = 4;
  s.frames = MakeStandardFrames(plan);
  return s;
}

// A camera that fails (a device error) after `fail_after` captures, like an unplugged cable.
class FailingCamera : public CameraDevice {
 public:
  FailingCamera(CameraDevice& inner, int fail_after) : inner_(inner), left_(fail_after) {}
  std::string Name() const override { return inner_.Name(); }
  std::string FrameExtension() const override { return inner_.FrameExtension(); }
  void CaptureToFile(const fs::path& path) override {
    if (left_-- <= 0) MESOSCAN_THROW(ErrorKind::kDevice, Name() << ": capture failed (I/O error)");
    inner_.CaptureToFile(path);
  }

 private:
  CameraDevice& inner_;
  int left_;
};

std::string ReadFile(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

class SequencerTest : public XvfbTest {
 protected:
  void SetUp() override {
    XvfbTest::SetUp();
    if (IsSkipped()) return;
    dir_ = fs::temp_directory_path() / ("mesoscan_sequencer_test_" + std::to_string(getpid()));
    fs::remove_all(dir_);
    ProjectorWindowOptions po;
    po.display = display();
    po.width = kProjW;
    po.height = kProjH;
    projector_ = MakeWindowProjector(po);
    LensShifterOptions so;
    so.port = sim_.Port();
    so.reply_timeout_s = 1.0;
    so.move_timeout_s = 2.0;
    shifter_ = MakeSerialShifter(so);
    options_.settle_s = 0.0;
  }
  void TearDown() override {
    if (!dir_.empty()) fs::remove_all(dir_);
  }

  SequencerSummary Run(const fs::path& root, CameraDevice& camera,
                       const SequencerOptions& options) {
    return RunAcquisition(Plan(root), camera, *projector_, shifter_.get(), options);
  }

  // Frames and session.json (without "created") of two session folders are identical.
  void ExpectSameSession(const fs::path& a, const fs::path& b) {
    const Session sa = ReadSession(a), sb = ReadSession(b);
    Json ja = SessionToJson(sa), jb = SessionToJson(sb);
    ja.erase("created");
    jb.erase("created");
    EXPECT_EQ(ja, jb);
    ASSERT_EQ(sa.frames.size(), sb.frames.size());
    for (size_t i = 0; i < sa.frames.size(); ++i)
      EXPECT_EQ(ReadFile(sa.FramePath(i)), ReadFile(sb.FramePath(i))) << sa.frames[i].file;
    EXPECT_FALSE(fs::exists(a / kCaptureJournal));
    EXPECT_FALSE(fs::exists(b / kCaptureJournal));
  }

  fs::path dir_;
  LensShifterSim sim_;
  std::unique_ptr<ProjectorDevice> projector_;
  std::unique_ptr<ShifterDevice> shifter_;
  SequencerOptions options_;
};

TEST_F(SequencerTest, CapturesWhatTheProjectorShowsUnderTheSpecNames) {
  auto camera = MakeScreenCamera(*projector_, kCamW, kCamH, false);
  const SequencerSummary sum = Run(dir_ / "a", *camera, options_);
  EXPECT_TRUE(sum.complete) << sum.BriefReport();
  EXPECT_EQ(sum.frames, 12);
  EXPECT_EQ(sum.captured, 12);
  EXPECT_EQ(sum.reused, 0);
  const Session s = ReadSession(dir_ / "a");
  ASSERT_EQ(s.frames.size(), 12u);
  EXPECT_EQ(s.frames[0].file, "frames/ps07_0.png");
  // Every frame is the 2x2 box mean of the 8-bit window pixels of its pattern.
  for (size_t i = 0; i < s.frames.size(); ++i) {
    const ImageF frame = ReadImageGrey(s.FramePath(i));
    double max_err = 0.0;
    for (int y = 0; y < kCamH; ++y)
      for (int x = 0; x < kCamW; ++x) {
        double sum8 = 0.0;
        for (int v = 2 * y; v < 2 * y + 2; ++v)
          for (int u = 2 * x; u < 2 * x + 2; ++u)
            sum8 += std::lround(s.frames[i].pattern.Value(u, v) * 255.0);
        max_err = std::max(max_err, std::abs(frame(x, y) - sum8 / 4.0 / 255.0));
      }
    EXPECT_LE(max_err, 0.5 / 65535.0 + 1e-7) << s.frames[i].file;
  }
  // The real serial driver moved the simulated controller through every position and home.
  EXPECT_EQ(sim_.position(), 0);
  EXPECT_GE(sim_.commands(), 1 + 12 + 1);  // ID?, one MOVE a frame, MOVE 0 at the end
}

TEST_F(SequencerTest, InterruptedThenResumedEqualsUninterrupted) {
  auto screen = MakeScreenCamera(*projector_, kCamW, kCamH, false);
  ASSERT_TRUE(Run(dir_ / "whole", *screen, options_).complete);

  // A device error after 5 frames: one line naming the camera, the journal keeps 5 frames.
  FailingCamera failing(*screen, 5);
  try {
    Run(dir_ / "parts", failing, options_);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kDevice);
    EXPECT_EQ(std::string(e.what()).rfind("screen camera (reads projector window on display", 0),
              0u)
        << e.what();
  }
  EXPECT_FALSE(fs::exists(dir_ / "parts" / "session.json"));
  ASSERT_TRUE(fs::exists(dir_ / "parts" / kCaptureJournal));

  // Ctrl-C: the interrupt flag stops the next run before it captures anything new.
  std::atomic<bool> stop{true};
  SequencerOptions interrupted = options_;
  interrupted.interrupt = &stop;
  try {
    Run(dir_ / "parts", *screen, interrupted);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("interrupted after 5 of 12 frames"), std::string::npos)
        << e.what();
  }

  // Capturing in parts: 3 more frames, then the rest.
  SequencerOptions part = options_;
  part.max_new_frames = 3;
  SequencerSummary sum = Run(dir_ / "parts", *screen, part);
  EXPECT_FALSE(sum.complete);
  EXPECT_EQ(sum.reused, 5);
  EXPECT_EQ(sum.captured, 3);
  const int moves_before = sim_.commands();
  sum = Run(dir_ / "parts", *screen, options_);
  EXPECT_TRUE(sum.complete) << sum.BriefReport();
  EXPECT_EQ(sum.reused, 8);
  EXPECT_EQ(sum.captured, 4);
  EXPECT_EQ(sim_.commands() - moves_before, 4 + 1);  // only the missing frames, then home
  ExpectSameSession(dir_ / "whole", dir_ / "parts");
}

// A kill between writing session.json and removing the journal leaves both;
// the re-run finishes that step (the journal goes) instead of refusing the completed session.
TEST_F(SequencerTest, AJournalLeftBesideTheCompletedSessionIsRemovedOnReRun) {
  auto screen = MakeScreenCamera(*projector_, kCamW, kCamH, false);
  SequencerOptions part = options_;
  part.max_new_frames = 11;
  ASSERT_FALSE(Run(dir_ / "k", *screen, part).complete);
  const fs::path journal = dir_ / "k" / kCaptureJournal;
  fs::copy_file(journal, dir_ / "journal.copy");
  ASSERT_TRUE(Run(dir_ / "k", *screen, options_).complete);
  ASSERT_FALSE(fs::exists(journal));
  fs::copy_file(dir_ / "journal.copy", journal);  // as if killed before the journal's removal
  const SequencerSummary sum = Run(dir_ / "k", *screen, options_);
  EXPECT_TRUE(sum.complete);
  EXPECT_EQ(sum.captured, 0);
  EXPECT_FALSE(fs::exists(journal));
  EXPECT_TRUE(fs::exists(dir_ / "k" / "session.json"));
}

TEST_F(SequencerTest, AChangedFrameIsCapturedAgainFromThere) {
  auto screen = MakeScreenCamera(*projector_, kCamW, kCamH, false);
  SequencerOptions part = options_;
  part.max_new_frames = 6;
  ASSERT_FALSE(Run(dir_ / "s", *screen, part).complete);
  // Frame 2 is overwritten by something else: frames 2.. are taken again.
  const Session plan = PlanForCamera(Plan(dir_ / "s"), *screen);
  WritePng16(plan.FramePath(2), ImageU16(kCamW, kCamH, 1, 123));
  const SequencerSummary sum = Run(dir_ / "s", *screen, options_);
  EXPECT_TRUE(sum.complete);
  EXPECT_EQ(sum.reused, 2);
  EXPECT_EQ(sum.captured, 10);
  ASSERT_TRUE(Run(dir_ / "ref", *screen, options_).complete);
  ExpectSameSession(dir_ / "ref", dir_ / "s");
}

TEST_F(SequencerTest, CompletedSessionNeedsForceAndAnotherPlansJournalIsRefused) {
  auto screen = MakeScreenCamera(*projector_, kCamW, kCamH, false);
  ASSERT_TRUE(Run(dir_ / "s", *screen, options_).complete);
  const std::string before = ReadFile(dir_ / "s" / "session.json");
  try {
    Run(dir_ / "s", *screen, options_);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kUsage);
    EXPECT_NE(std::string(e.what()).find("pass SequencerOptions.force"), std::string::npos)
        << e.what();
    EXPECT_EQ(e.file(), (dir_ / "s" / "session.json").string());
  }
  EXPECT_EQ(ReadFile(dir_ / "s" / "session.json"), before);
  SequencerOptions force = options_;
  force.force = true;
  const SequencerSummary sum = Run(dir_ / "s", *screen, force);
  EXPECT_TRUE(sum.complete);
  EXPECT_EQ(sum.captured, 12);

  // A partial capture, then the same folder with another rig: refused, journal kept.
  SequencerOptions part = options_;
  part.max_new_frames = 2;
  ASSERT_FALSE(Run(dir_ / "p", *screen, part).complete);
  Session other = Plan(dir_ / "p");
  other.rig.camera.K(0, 0) = 101;
  try {
    RunAcquisition(other, *screen, *projector_, shifter_.get(), options_);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
    EXPECT_NE(std::string(e.what()).find("capture_journal.jsonl: written for another plan"),
              std::string::npos)
        << e.what();
  }
}

TEST_F(SequencerTest, DeviceErrorsNameTheDevice) {
  auto screen = MakeScreenCamera(*projector_, kCamW, kCamH, false);
  // The controller refuses a move.
  sim_.InjectError("motor stall");
  try {
    Run(dir_ / "s", *screen, options_);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kDevice);
    EXPECT_EQ(std::string(e.what()).rfind("lens shifter on " + sim_.Port() + ": ", 0), 0u)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("motor stall"), std::string::npos) << e.what();
  }
  // Lens-shift frames without a shifter: a usage error before anything moves.
  try {
    RunAcquisition(Plan(dir_ / "t"), *screen, *projector_, nullptr, options_);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kUsage) << e.what();
  }
  // A window that is not the rig's projector size.
  Session small = Plan(dir_ / "u");
  small.rig.projector.width = 60;
  small.rig.projector.K(0, 2) = 29.5;
  try {
    RunAcquisition(small, *screen, *projector_, shifter_.get(), options_);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kDevice);
    EXPECT_NE(std::string(e.what()).find("shows 64x48 px, the rig's projector is 60x48"),
              std::string::npos)
        << e.what();
  }
}

TEST_F(SequencerTest, RawScreenCameraWritesDngsThatDecodeToThePngValues) {
  auto png = MakeScreenCamera(*projector_, kCamW, kCamH, false);
  auto dng = MakeScreenCamera(*projector_, kCamW, kCamH, true);
  ASSERT_TRUE(Run(dir_ / "png", *png, options_).complete);
  ASSERT_TRUE(Run(dir_ / "dng", *dng, options_).complete);
  const Session a = ReadSession(dir_ / "png"), b = ReadSession(dir_ / "dng");
  EXPECT_EQ(b.frames[0].file, "frames/ps07_0.dng");
  for (size_t i = 0; i < a.frames.size(); ++i) {
    const ImageU16 grey = ReadRawGrey(b.FramePath(i));
    const ImageF ref = ReadImage(a.FramePath(i));
    ASSERT_EQ(grey.width(), kCamW);
    for (size_t k = 0; k < grey.pixels(); ++k)
      ASSERT_EQ(grey.data()[k], std::lround(ref.data()[k] * 65535.0)) << a.frames[i].file;
  }
}

}  // namespace
}  // namespace mesoscan
