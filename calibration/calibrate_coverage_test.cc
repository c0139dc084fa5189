#include "calibration/calibrate_coverage.h"

#include <gtest/gtest.h>

namespace mesoscan {
namespace {

TEST(ConvexHull, DropsInteriorPointsAndContainsTheInside) {
  CalibratedRegion r;
  r.width = 100;
  r.height = 100;
  r.hulls = {ConvexHull({{10, 10}, {50, 50}, {90, 10}, {90, 90}, {10, 90}, {30, 60}})};
  EXPECT_EQ(r.hulls[0].size(), 4u);
  EXPECT_TRUE(r.Contains({50, 50}));
  EXPECT_TRUE(r.Contains({11, 89}));
  EXPECT_FALSE(r.Contains({5, 50}));
  EXPECT_FALSE(r.Contains({50, 95}));
  // Stored and read back.
  const CalibratedRegion back = CalibratedRegion::FromJson(r.ToJson(), "test");
  EXPECT_TRUE(back.Contains({50, 50}));
  EXPECT_FALSE(back.Contains({5, 50}));
}

// A board that stays in the middle third of the image covers about a ninth of it: poor, and the
// advice names every edge; one that reaches the left and bottom only misses the others.
TEST(MeasureCoverage, CentreThirdIsPoorAndTheAdviceNamesTheEdges) {
  CalibratedRegion centre;
  centre.width = 900;
  centre.height = 600;
  centre.hulls = {{{300, 200}, {600, 200}, {600, 400}, {300, 400}}};
  const auto all = [](const Vec2d&) { return true; };
  const DeviceCoverage c = MeasureCoverage("camera", centre, all, 0.5);
  EXPECT_NEAR(c.fraction, 1.0 / 9, 0.03);
  EXPECT_TRUE(c.poor);
  EXPECT_NE(c.advice.find("corners cover 11% of the camera image"), std::string::npos) << c.advice;
  EXPECT_NE(c.advice.find("left, right, top and bottom edges"), std::string::npos) << c.advice;

  CalibratedRegion spread = centre;
  spread.hulls.push_back({{0, 300}, {500, 300}, {500, 599}, {0, 599}});
  spread.hulls.push_back({{400, 0}, {899, 0}, {899, 599}, {400, 599}});
  const DeviceCoverage s = MeasureCoverage("camera", spread, all, 0.5);
  EXPECT_GT(s.fraction, 0.7);
  ASSERT_EQ(s.missing.size(), 1u) << s.advice;
  EXPECT_EQ(s.missing[0], "top left") << s.advice;
}

}  // namespace
}  // namespace mesoscan
