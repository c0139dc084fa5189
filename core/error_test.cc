#include "core/error.h"

#include <gtest/gtest.h>

namespace mesoscan {
namespace {

TEST(Error, TheLocationIsDataAndTheLineNamesItInOrder) {
  try {
    MESOSCAN_BAD_INPUT_AT(ErrorSite::Key("s/session.json", "rig.camera.K"),
                          "singular (" << 0 << ")");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
    EXPECT_EQ(e.exit_code(), 3);
    EXPECT_EQ(e.file(), "s/session.json");
    EXPECT_EQ(e.key(), "rig.camera.K");
    EXPECT_EQ(e.frame(), -1);
    EXPECT_TRUE(e.option().empty());
    EXPECT_EQ(std::string(e.what()), "s/session.json: rig.camera.K: singular (0)");
    EXPECT_EQ(e.Detail(), "singular (0)");
  }
  ErrorSite site = ErrorSite::Frame("frames/ps07_0.png", 4);
  site.option = "FrameLoadOptions.roi";
  const Error e(ErrorKind::kBadInput, site, {{false, "outside"}});
  EXPECT_EQ(std::string(e.what()), "FrameLoadOptions.roi: frames/ps07_0.png: frame 4: outside");
}

TEST(Error, OptionsInTheMessageAreNamedByTheCaller) {
  try {
    MESOSCAN_BAD_OPTION("TileOptions.size_m", "too large; use a smaller "
                                                  << OptionRef{"TileOptions.size_m"} << " or "
                                                  << OptionRef{"MapsOptions.crop"});
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kUsage);
    EXPECT_EQ(e.option(), "TileOptions.size_m");
    EXPECT_EQ(
        std::string(e.what()),
        "TileOptions.size_m: too large; use a smaller TileOptions.size_m or MapsOptions.crop");
    const auto upper = [](const std::string& field) { return "<" + field + ">"; };
    EXPECT_EQ(e.Format(upper),
              "<TileOptions.size_m>: too large; use a smaller <TileOptions.size_m> or "
              "<MapsOptions.crop>");
  }
}

TEST(Error, AtLocatesAnErrorWithoutChangingItsKindOrMessage) {
  const Error plain("unwrapping: period 0 px is not a positive number");
  EXPECT_EQ(plain.kind(), ErrorKind::kBadInput);
  EXPECT_TRUE(plain.file().empty());
  const Error located = plain.At(ErrorSite::File("s/session.json"));
  EXPECT_EQ(located.kind(), ErrorKind::kBadInput);
  EXPECT_EQ(std::string(located.what()),
            "s/session.json: unwrapping: period 0 px is not a positive number");
  const Error device = Error("no reply", ErrorKind::kDevice).At(ErrorSite::File("/dev/ttyUSB0"));
  EXPECT_EQ(device.exit_code(), 4);
}

TEST(Error, CheckOpPrintsBothValues) {
  try {
    const int a = 3, b = 4;
    MESOSCAN_CHECK_EQ(a, b);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kInternal);
    EXPECT_NE(std::string(e.what()).find("CHECK(a == b) failed: 3 vs 4"), std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace mesoscan
