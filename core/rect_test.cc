#include "core/rect.h"

#include <gtest/gtest.h>

#include "core/error.h"

namespace mesoscan {
namespace {

// Error(kUsage) at the options field, whose message names the text.
void ExpectUsage(const std::string& text) {
  try {
    ParsePixelRect(text, "ExportOptions.crop");
    FAIL() << "'" << text << "' must be refused";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kUsage) << text;
    EXPECT_EQ(e.option(), "ExportOptions.crop");
    EXPECT_NE(std::string(e.what()).find("ExportOptions.crop: '" + text + "'"), std::string::npos)
        << e.what();
  }
}

TEST(PixelRect, CommasAndGeometrySpellTheSameRectangle) {
  const PixelRect r = ParsePixelRect("960,620,256,192", "FrameLoadOptions.roi");
  EXPECT_EQ(r, (PixelRect{960, 620, 256, 192}));
  EXPECT_EQ(ParsePixelRect("256x192+960+620", "ExportOptions.crop"), r);
  EXPECT_EQ(ParsePixelRect(" 1, 2 ,3,4", "ExportOptions.crop"), (PixelRect{1, 2, 3, 4}));
  EXPECT_EQ(ToString(r), "960,620,256,192");
  EXPECT_FALSE(r.whole());
  EXPECT_TRUE(PixelRect{}.whole());
  // The largest int is a value (the caller checks it against its image), one more is refused.
  EXPECT_EQ(ParsePixelRect("2147483647,0,1,1", "ExportOptions.crop").x, 2147483647);
}

TEST(PixelRect, MalformedRectanglesAreUsageErrorsNamingTheOption) {
  for (const char* text : {"1,2,30", "1,2,0,4", "1,2,3,0", "-1,2,3,4", "1,2,three,4", "10x10",
                           "1,2,3,4,5", "", "0x4+1+1", "2147483648,0,1,1", "99999999999,0,1,1"})
    ExpectUsage(text);
}

}  // namespace
}  // namespace mesoscan
