#include "session/raw_frame.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <fstream>
#include <random>

#include "capture/xvfb_server_test_util.h"
#include "core/error.h"
#include "core/image_io.h"
#include "session/patterns.h"
#include "session/session.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

class RawFrameTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("mesoscan_raw_frame_test_" + std::to_string(getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "frames");
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

// A mosaic whose four cell positions carry distinct, known codes (a Bayer scene where R, G and B
// differ), noise-free so every expected value is exact.
ImageU16 TestMosaic(int w, int h, const RawLevels& levels, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> u(0, 4000);
  ImageU16 m(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const int pos = (y % 2) * 2 + (x % 2);
      m(x, y) = static_cast<uint16_t>(levels.black[pos] + u(rng) * (pos + 1) * 0.9);
    }
  return m;
}

TEST_F(RawFrameTest, DngDecodesToTheBlackSubtractedMeanOfEachBayerCell) {
  RawLevels levels;
  levels.black = {512, 520, 508, 516};  // per-position black, as DNG BlackLevelRepeatDim 2x2 says
  levels.white = 16383;                 // 14-bit sensor
  // LibRaw (dcraw's identify) refuses sensors narrower or shorter than 22 px.
  const ImageU16 mosaic = TestMosaic(28, 24, levels, 7);
  const fs::path file = dir_ / "frame.dng";
  WriteCfaDng(file, mosaic, levels);

  // LibRaw hands back the mosaic untouched (no demosaic, no black subtraction, no scaling).
  const ImageU16 back = ReadRawMosaic(file);
  ASSERT_EQ(back.width(), 28);
  ASSERT_EQ(back.height(), 24);
  EXPECT_EQ(back.data(), mosaic.data());

  const RawLevels read = ReadRawLevels(file);
  EXPECT_TRUE(read.from_file);
  for (int i = 0; i < 4; ++i) EXPECT_EQ(read.black[i], levels.black[i]) << i;
  EXPECT_EQ(read.white, levels.white);

  const ImageU16 grey = ReadRawGrey(file);
  ASSERT_EQ(grey.width(), 14);
  ASSERT_EQ(grey.height(), 12);
  const double black = (512 + 520 + 508 + 516) / 4.0;
  int exact = 0;
  for (int y = 0; y < 12; ++y)
    for (int x = 0; x < 14; ++x) {
      const double mean = (double(mosaic(2 * x, 2 * y)) + mosaic(2 * x + 1, 2 * y) +
                           mosaic(2 * x, 2 * y + 1) + mosaic(2 * x + 1, 2 * y + 1)) /
                          4.0;
      const double expected = (mean - black) * 65535.0 / (16383.0 - black);
      // Rounded once: within half a code of the exact value.
      EXPECT_LE(std::abs(grey(x, y) - expected), 0.5 + 1e-9) << x << "," << y;
      exact += grey(x, y) == std::lround(expected);
    }
  EXPECT_EQ(exact, 14 * 12);
}

TEST_F(RawFrameTest, WhiteLevelSaturatesAndBlackClampsAtZero) {
  RawLevels levels;
  levels.black = {1000, 1000, 1000, 1000};
  levels.white = 4095;
  ImageU16 mosaic(22, 22, 1, 1000);
  for (int x = 0; x < 2; ++x)
    for (int y = 0; y < 2; ++y) mosaic(x, y) = 4095;  // cell 0 at the white level
  mosaic(2, 0) = 900;                                 // below black: clamps to 0, never wraps
  mosaic(3, 0) = 900;
  mosaic(2, 1) = 900;
  mosaic(3, 1) = 900;
  WriteCfaDng(dir_ / "sat.dng", mosaic, levels);
  const ImageU16 grey = ReadRawGrey(dir_ / "sat.dng");
  EXPECT_EQ(grey(0, 0), 65535);
  EXPECT_EQ(grey(1, 0), 0);
}

// LibRaw reads the levels from the file: a DNG whose BlackLevel differs per cell position and
// whose WhiteLevel is a 12-bit sensor's (as a CR2 or NEF declares them in its maker notes and
// masked border, which LibRaw reads for those formats the same way).
TEST_F(RawFrameTest, LevelsComeFromTheFileThroughLibRaw) {
  RawLevels levels;
  levels.black = {128, 131, 127, 130};
  levels.white = 4000;
  WriteCfaDng(dir_ / "levels.dng", TestMosaic(24, 22, levels, 3), levels);
  const RawLevels read = ReadRawLevels(dir_ / "levels.dng");
  EXPECT_TRUE(read.from_file);
  for (int i = 0; i < 4; ++i) EXPECT_EQ(read.black[i], levels.black[i]) << i;
  EXPECT_EQ(read.white, 4000);
  // Another white level, another file: nothing is assumed.
  levels.white = 15000;
  WriteCfaDng(dir_ / "levels2.dng", TestMosaic(24, 22, levels, 4), levels);
  EXPECT_EQ(ReadRawLevels(dir_ / "levels2.dng").white, 15000);
}

// The colour texture: each cell's R, mean of its two G and B, black-subtracted and scaled by the
// white level, on the grey frame's half-size grid; for an RGGB and a GRBG sensor.
TEST_F(RawFrameTest, ColourTextureFromADng) {
  RawLevels levels;
  levels.black = {200, 210, 190, 205};
  levels.white = 16383;
  for (const std::array<uint8_t, 4> cfa :
       {std::array<uint8_t, 4>{0, 1, 1, 2}, std::array<uint8_t, 4>{1, 0, 2, 1}}) {
    const ImageU16 mosaic = TestMosaic(28, 24, levels, 11);
    const fs::path file = dir_ / "colour.dng";
    WriteCfaDng(file, mosaic, levels, cfa);
    const ImageF rgb = ReadRawColour(file);
    ASSERT_EQ(rgb.width(), 14);
    ASSERT_EQ(rgb.height(), 12);
    ASSERT_EQ(rgb.channels(), 3);
    const double black = (200 + 210 + 190 + 205) / 4.0;
    for (int y = 0; y < 12; ++y)
      for (int x = 0; x < 14; ++x) {
        double sum[3] = {0, 0, 0};
        int n[3] = {0, 0, 0};
        for (int i = 0; i < 4; ++i) {
          const int c = cfa[i];
          sum[c] += mosaic(2 * x + i % 2, 2 * y + i / 2) - levels.black[i];
          ++n[c];
        }
        for (int c = 0; c < 3; ++c)
          EXPECT_NEAR(rgb(x, y, c), std::max(0.0, sum[c] / n[c] / (16383.0 - black)), 1e-6)
              << x << "," << y << " channel " << c;
      }
    // Its luminance-free check: the grey frame is the mean of the same four codes.
    const ImageU16 grey = ReadRawGrey(file);
    EXPECT_NEAR(grey(3, 4) / 65535.0, (rgb(3, 4, 0) + 2 * rgb(3, 4, 1) + rgb(3, 4, 2)) / 4.0, 1e-4);
  }
}

TEST_F(RawFrameTest, UnreadableRawNamesTheFrame) {
  { std::ofstream(dir_ / "junk.nef") << "not a raw file"; }
  try {
    ReadRawGrey(dir_ / "junk.nef", "frames/junk.nef: frames[3]");
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
    EXPECT_EQ(std::string(e.what()).rfind("frames/junk.nef: frames[3]: cannot read camera raw", 0),
              0u)
        << e.what();
  }
}

TEST_F(RawFrameTest, ExtensionsAreCaseInsensitive) {
  EXPECT_TRUE(IsCameraRawPath("a/b.NEF"));
  EXPECT_TRUE(IsCameraRawPath("x.dng"));
  EXPECT_TRUE(IsCameraRawPath("x.Cr2"));
  EXPECT_FALSE(IsCameraRawPath("x.png"));
  EXPECT_FALSE(IsCameraRawPath("x.tif"));
}

TEST_F(RawFrameTest, LibRawVersionIsReported) {
  EXPECT_EQ(LibRawVersion().rfind("0.", 0), 0u) << LibRawVersion();  // LibRaw 0.20 here
}

// A session whose frames are DNG files twice the camera size passes the reader's checks and each
// frame decodes to camera.width x camera.height.
TEST_F(RawFrameTest, DngSessionPassesTheReaderAndDecodes) {
  Session s;
  s.root = dir_;
  s.created = "2026-11-21T12:00:00Z";
  s.object = "dng session";
  s.rig = SmallTestRig(12, 11, 60, 40, false);  // sensor 24 x 22: LibRaw's minimum is 22 x 22
  FramePlanOptions plan;
  plan.periods_px = {7, 11};
  plan.lens_shift_frames = 0;
  s.frames = MakeStandardFrames(plan);
  RawLevels levels;
  levels.black = {256, 256, 256, 256};
  levels.white = 65535;
  for (size_t i = 0; i < s.frames.size(); ++i) {
    s.frames[i].file = fs::path(s.frames[i].file).replace_extension(".dng").string();
    WriteCfaDng(s.FramePath(i), TestMosaic(24, 22, levels, 100 + i), levels);
  }
  WriteSessionJson(s);
  const Session r = ReadSession(dir_);
  ASSERT_EQ(r.frames.size(), s.frames.size());
  for (size_t i = 0; i < r.frames.size(); ++i) {
    const ImageU16 grey = ReadRawGrey(r.FramePath(i));
    EXPECT_EQ(grey.width(), 12);
    EXPECT_EQ(grey.height(), 11);
  }
}

}  // namespace
}  // namespace mesoscan
