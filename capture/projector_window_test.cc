#include "capture/projector_window.h"

#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <thread>

#include "capture/xvfb_server_test_util.h"
#include "core/error.h"
#include "session/patterns.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

class ProjectorWindowTest : public XvfbTest {};

// Every screenshot pixel is the pattern's displayed value quantised to 8 bits, on R = G = B.
void ExpectShows(const ImageU8& shot, const Pattern& pattern) {
  int mismatches = 0;
  for (int v = 0; v < shot.height(); ++v)
    for (int u = 0; u < shot.width(); ++u) {
      const int expected =
          static_cast<int>(std::lround(static_cast<float>(pattern.Value(u, v)) * 255.0f));
      for (int c = 0; c < 3; ++c)
        if (shot(u, v, c) != expected && mismatches++ < 5)
          ADD_FAILURE() << "pixel (" << u << ", " << v << ") channel " << c << ": "
                        << int{shot(u, v, c)} << ", expected " << expected;
    }
  EXPECT_EQ(mismatches, 0);
}

TEST_F(ProjectorWindowTest, FullScreenShowsPatternsPixelForPixel) {
  ProjectorWindowOptions o;
  o.display = server_->display();
  ProjectorWindow window(o);
  ASSERT_EQ(window.width(), 320);
  ASSERT_EQ(window.height(), 240);
  for (const Pattern& p :
       {Pattern{PatternType::kSine, 'x', 7.3, 1.1}, Pattern{PatternType::kStripes, 'x', 2, 0},
        Pattern{PatternType::kSine, 'y', 13, 0.4}, Pattern{PatternType::kWhite}}) {
    window.Show(RenderPattern(p, window.width(), window.height()));
    ExpectShows(window.Screenshot(), p);
  }
}

TEST_F(ProjectorWindowTest, WindowAtAnOffsetAndColour) {
  ProjectorWindowOptions o;
  o.display = server_->display();
  o.x = 20;
  o.y = 10;
  o.width = 100;
  o.height = 50;
  ProjectorWindow window(o);
  const Pattern p{PatternType::kStripes, 'x', 6, 0};
  window.Show(RenderPattern(p, 100, 50));
  ExpectShows(window.Screenshot(), p);
  // RGB images keep their channels.
  ImageF rgb(100, 50, 3, 0.0f);
  for (int v = 0; v < 50; ++v)
    for (int u = 0; u < 100; ++u) {
      rgb(u, v, 0) = 1.0f;
      rgb(u, v, 2) = 0.5f;
    }
  rgb(3, 4, 1) = std::nanf("");
  window.Show(rgb);
  const ImageU8 shot = window.Screenshot();
  EXPECT_EQ(shot(3, 4, 0), 255);
  EXPECT_EQ(shot(3, 4, 1), 0);  // NaN shows black
  EXPECT_EQ(shot(3, 4, 2), 128);
  // Wrong size is refused.
  EXPECT_THROW(window.Show(ImageF(99, 50)), Error);
  // A window that does not fit the screen is a device error.
  o.width = 400;
  EXPECT_THROW(ProjectorWindow too_big(o), Error);
}

TEST_F(ProjectorWindowTest, ProbeDisplay) {
  const DisplayProbe ok = ProbeDisplay(server_->display());
  EXPECT_TRUE(ok.opens);
  EXPECT_EQ(ok.width, 320);
  EXPECT_EQ(ok.height, 240);
  const DisplayProbe bad = ProbeDisplay(":9999");
  EXPECT_FALSE(bad.opens);
  EXPECT_EQ(bad.error, "cannot open X display ':9999'");
}

TEST(ProjectorWindowNoServerTest, MissingDisplayIsADeviceError) {
  ProjectorWindowOptions o;
  o.display = ":9999";
  try {
    ProjectorWindow w(o);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kDevice);
    EXPECT_EQ(std::string(e.what()), "cannot open X display ':9999'");
  }
}

}  // namespace
}  // namespace mesoscan
