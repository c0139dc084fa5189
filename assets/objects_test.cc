#include "assets/objects.h"

#include <gtest/gtest.h>

#include <cmath>

#include "core/error.h"

namespace mesoscan {
namespace {

// The tilted plane is exact on its grid: z = (x - kBarX0) tan(angle) inside the bar, 0 outside.
TEST(Objects, TheTiltedPlaneIsAPlaneOnTheMount) {
  const SceneObject bar = MakeObject("plane", 0.5e-3);
  EXPECT_EQ(bar.name, "plane");
  ASSERT_GT(bar.height.width(), 10);
  const double slope = std::tan(kBarAngleRad);
  for (const double x : {-15e-3, 0.0, 12e-3}) {
    EXPECT_NEAR(bar.SurfaceZ(x, 0.0), (x - kBarX0) * slope, 1e-9) << x;
    EXPECT_NEAR(bar.SurfaceZ(x, kBarHalfWidthM + 2e-3), 0.0, 1e-12) << "beside the bar";
  }
  for (const float a : bar.albedo.data()) EXPECT_TRUE(a >= 0 && a <= 1);
}

// The ramp's steps: kRampSheets sheets of kRampSheetM, one more every kRampStepWidthM.
TEST(Objects, TheRampHasItsSheets) {
  const SceneObject ramp = MakeObject("ramp", 0.2e-3);
  const double x_top = kRampX0 + (kRampSheets - 0.5) * kRampStepWidthM;
  EXPECT_NEAR(ramp.SurfaceZ(kRampX0 + 0.5 * kRampStepWidthM, 0), kRampSheetM, 1e-9);
  EXPECT_NEAR(ramp.SurfaceZ(x_top, 0), kRampSheets * kRampSheetM, 1e-9);
}

TEST(Objects, AnUnknownObjectIsBadInputAtTheCallersOption) {
  try {
    MakeObject("teapot", 0.0, "SimulateOptions.object");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
    EXPECT_EQ(e.option(), "SimulateOptions.object");
    EXPECT_NE(std::string(e.what()).find("unknown object 'teapot'"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace mesoscan
