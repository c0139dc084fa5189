#include "session/patterns.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <set>

namespace mesoscan {
namespace {

TEST(PatternsTest, SineMatchesSpecFormula) {
  Pattern p{PatternType::kSine, 'x', 7.3, 1.1};
  const ImageF im = RenderPattern(p, 40, 5);
  ASSERT_EQ(im.width(), 40);
  ASSERT_EQ(im.height(), 5);
  for (int v = 0; v < 5; ++v)
    for (int u = 0; u < 40; ++u)
      EXPECT_NEAR(im(u, v), 0.5 + 0.5 * std::cos(2 * std::numbers::pi * u / 7.3 + 1.1), 1e-7);
  // Axis y varies along rows only.
  p.axis = 'y';
  const ImageF iy = RenderPattern(p, 6, 30);
  for (int v = 0; v < 30; ++v)
    for (int u = 0; u < 6; ++u)
      EXPECT_NEAR(iy(u, v), 0.5 + 0.5 * std::cos(2 * std::numbers::pi * v / 7.3 + 1.1), 1e-7);
}

TEST(PatternsTest, StripesMatchSpecFormula) {
  // period 2: one-pixel bars, pixel 0 lit.
  Pattern p{PatternType::kStripes, 'x', 2, 0};
  ImageF im = RenderPattern(p, 10, 2);
  for (int u = 0; u < 10; ++u) EXPECT_EQ(im(u, 1), u % 2 == 0 ? 1.0f : 0.0f) << u;
  // period 6: floor(u / 3) even.
  p.period_px = 6;
  im = RenderPattern(p, 20, 1);
  for (int u = 0; u < 20; ++u) EXPECT_EQ(im(u, 0), (u / 3) % 2 == 0 ? 1.0f : 0.0f) << u;
  // Negative positions continue the pattern (floor, not truncation).
  p.period_px = 2;
  EXPECT_EQ(p.Value(-1, 0), 0.0);
  EXPECT_EQ(p.Value(-2, 0), 1.0);
}

TEST(PatternsTest, StripesAtFractionalPositionsUsePixelFootprints) {
  const Pattern p{PatternType::kStripes, 'x', 2, 0};
  EXPECT_EQ(p.Value(0.49, 0), 1.0);   // inside pixel 0
  EXPECT_EQ(p.Value(0.5, 0), 0.0);    // pixel 1 starts at 0.5
  EXPECT_EQ(p.Value(-0.5, 0), 1.0);   // pixel 0 is [-0.5, 0.5)
  EXPECT_EQ(p.Value(-0.51, 0), 0.0);  // pixel -1
  // The shifter moves the displayed image by +shift: at x the light comes from pixel x - shift.
  EXPECT_EQ(ValueAtShift(p, 1.0, 0, 1.0, 'x'), 1.0);  // pixel 0 moved onto x = 1
  EXPECT_EQ(ValueAtShift(p, 1.0, 0, 0.4, 'x'), 0.0);  // x - s = 0.6: pixel 1
  EXPECT_EQ(ValueAtShift(p, 1.0, 0, 0.6, 'x'), 1.0);  // x - s = 0.4: pixel 0
  const Pattern py{PatternType::kStripes, 'y', 2, 0};
  EXPECT_EQ(ValueAtShift(py, 0, 3.0, 1.0, 'y'), 1.0);
}

TEST(PatternsTest, WhiteBlackAndProjectorResponse) {
  EXPECT_EQ(RenderPattern({PatternType::kWhite}, 4, 3)(3, 2), 1.0f);
  EXPECT_EQ(RenderPattern({PatternType::kBlack}, 4, 3)(1, 1), 0.0f);
  const Pattern p{PatternType::kSine, 'x', 9, 0.3};
  const Response gamma{Response::Kind::kGamma, 2.2};
  const ImageF im = RenderPattern(p, 20, 2, gamma);
  for (int u = 0; u < 20; ++u)
    EXPECT_NEAR(im(u, 0), std::pow(0.5 + 0.5 * std::cos(2 * std::numbers::pi * u / 9 + 0.3), 2.2),
                1e-6);
}

TEST(PatternsTest, StandardPlanIsAValidSession) {
  FramePlanOptions o;
  const std::vector<Frame> frames = MakeStandardFrames(o);
  ASSERT_EQ(frames.size(), 9u + 50u + 2u);
  EXPECT_EQ(frames[0].file, "frames/ps07_0.png");  // the spec's example name
  EXPECT_EQ(frames[8].file, "frames/ps13_2.png");
  EXPECT_NEAR(frames[1].pattern.phase, 2 * std::numbers::pi / 3, 1e-15);
  // Lens shift over the whole range, both ends included: round(-2048 + i * 4096 / 49).
  EXPECT_EQ(frames[9].file, "frames/ls_000.png");
  EXPECT_EQ(frames[9].shift_steps, -2048);
  EXPECT_EQ(frames[10].shift_steps, -1964);
  EXPECT_EQ(frames[58].shift_steps, 2048);
  EXPECT_EQ(frames[59].file, "frames/white.png");
  EXPECT_EQ(frames[60].file, "frames/black.png");
  const FramePlan plan = MakeFramePlan(frames);
  EXPECT_EQ(plan.sine.size(), 3u);
  EXPECT_EQ(plan.distinct_shift_steps, 50);
  EXPECT_EQ(plan.max_shift_steps - plan.min_shift_steps, 4096);
  o.phases = 2;
  EXPECT_THROW(MakeStandardFrames(o), Error);
}

TEST(PatternsTest, CalibrationPlanHasSinesAlongBothAxesWhiteAndBlack) {
  FramePlanOptions o = CalibrationPlan(800, 600);
  o.extension = ".bmp";
  const std::vector<Frame> frames = MakeStandardFrames(o);
  ASSERT_EQ(frames.size(), 4u * 3u + 2u);
  EXPECT_EQ(frames[0].file, "frames/ps800_0.bmp");
  EXPECT_EQ(frames[3].file, "frames/ps50_0.bmp");
  EXPECT_EQ(frames[6].file, "frames/psy600_0.bmp");
  EXPECT_EQ(frames[9].file, "frames/psy37.5_0.bmp");
  EXPECT_EQ(frames[9].pattern.axis, 'y');
  EXPECT_EQ(frames[13].pattern.type, PatternType::kBlack);
  for (const Frame& f : frames) EXPECT_EQ(f.shift_steps, 0) << f.file;
  const FramePlan plan = MakeFramePlan(frames);
  EXPECT_EQ(plan.Periods('x'), (std::vector<double>{50, 800}));
  EXPECT_EQ(plan.Periods('y'), (std::vector<double>{37.5, 600}));
  EXPECT_TRUE(plan.lens_shift.empty());
  EXPECT_EQ(plan.white.size(), 1u);
  EXPECT_EQ(plan.black.size(), 1u);
  // Every file name is distinct.
  std::set<std::string> names;
  for (const Frame& f : frames) names.insert(f.file);
  EXPECT_EQ(names.size(), frames.size());
}

TEST(PatternsTest, PeriodListsParseOrNameTheOption) {
  EXPECT_EQ(ParsePeriodList("7,11,13", "FramePlanOptions.periods_px"),
            (std::vector<double>{7, 11, 13}));
  EXPECT_EQ(ParsePeriodList("800,50", "FramePlanOptions.periods_px"),
            (std::vector<double>{800, 50}));
  EXPECT_EQ(ParsePeriodList("37.5", "FramePlanOptions.cross_periods_px"),
            (std::vector<double>{37.5}));
  EXPECT_TRUE(ParsePeriodList("none", "FramePlanOptions.periods_px").empty());
  EXPECT_TRUE(ParsePeriodList("", "FramePlanOptions.periods_px").empty());
  for (const char* bad : {"7,x", "7,,11", "7,11,", "2", "1e999", "nan", "7 ", "-7"}) {
    try {
      ParsePeriodList(bad, "SimulateOptions.ps_periods_px");
      ADD_FAILURE() << "'" << bad << "' must be refused";
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::kUsage) << bad;
      EXPECT_EQ(e.option(), "SimulateOptions.ps_periods_px");
      EXPECT_EQ(std::string(e.what()).rfind("SimulateOptions.ps_periods_px: '", 0), 0u) << e.what();
    }
  }
}

}  // namespace
}  // namespace mesoscan
