#include "core/scan_folder.h"

#include <gtest/gtest.h>

#include <cmath>

#include "core/error.h"
#include "core/test_temp_dir.h"

namespace mesoscan {
namespace fs = std::filesystem;
namespace {

Scan SmallScan() {
  Scan scan;
  const int w = 5, h = 4;
  scan.points.xyz = ImageF(w, h, 3, 0.0f);
  scan.points.confidence = ImageF(w, h, 1, 0.5f);
  scan.points.projector_u = ImageF(w, h, 1, 0.0f);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      scan.points.xyz(x, y, 0) = 1e-3f * x;
      scan.points.xyz(x, y, 1) = -1e-3f * y;
      scan.points.xyz(x, y, 2) = 1e-4f * (x + y);
      scan.points.projector_u(x, y) = 100.0f + x;
    }
  scan.points.xyz(0, 0, 2) = std::numeric_limits<float>::quiet_NaN();
  scan.points.confidence(0, 0) = 0.0f;
  scan.height.z = ImageF(6, 3, 1, 2e-4f);
  scan.height.z(2, 1) = std::numeric_limits<float>::quiet_NaN();
  scan.height.confidence = ImageF(6, 3, 1, 1.0f);
  scan.height.x0 = -1.5e-3, scan.height.y0 = 2.5e-3, scan.height.pixel_size = 2e-5;
  scan.report = {{"session", "x.session"}, {"valid", 19}};
  return scan;
}

// The folder reads back as written: every sample (NaN where there is none), the grid and the
// report (the contract of docs/formats.md).
TEST(ScanFolder, ReadsBackWhatItWrote) {
  const fs::path dir = TestTempPath("scan_folder", "rt.scan");
  const Scan scan = SmallScan();
  WriteScanFolder(dir, scan);
  const Scan back = ReadScanFolder(dir);
  ASSERT_EQ(back.points.xyz.width(), 5);
  ASSERT_EQ(back.points.xyz.height(), 4);
  for (size_t i = 0; i < scan.points.xyz.data().size(); ++i) {
    const float a = scan.points.xyz.data()[i], b = back.points.xyz.data()[i];
    EXPECT_TRUE(a == b || (std::isnan(a) && std::isnan(b))) << i;
  }
  EXPECT_EQ(back.points.confidence.data(), scan.points.confidence.data());
  EXPECT_EQ(back.points.projector_u.data(), scan.points.projector_u.data());
  // The grid attributes are stored as float (docs/formats.md).
  EXPECT_FLOAT_EQ(back.height.x0, scan.height.x0);
  EXPECT_FLOAT_EQ(back.height.y0, scan.height.y0);
  EXPECT_FLOAT_EQ(back.height.pixel_size, scan.height.pixel_size);
  EXPECT_TRUE(std::isnan(back.height.z(2, 1)));
  EXPECT_EQ(back.height.z(0, 0), 2e-4f);
  EXPECT_EQ(back.normals.channels(), 3);
  EXPECT_EQ(back.report, scan.report);
}

TEST(ScanFolder, AMissingFileIsBadInputNamingIt) {
  const fs::path dir = TestTempPath("scan_folder", "partial.scan");
  WriteScanFolder(dir, SmallScan());
  fs::remove(dir / "height.exr");
  try {
    ReadScanFolder(dir);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
    EXPECT_NE(std::string(e.what()).find("height.exr"), std::string::npos) << e.what();
  }
  try {
    ReadScanFolder(dir / "nothing");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.file(), (dir / "nothing").string());
  }
}

}  // namespace
}  // namespace mesoscan
