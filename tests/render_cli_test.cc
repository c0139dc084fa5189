// `mesoscan render` end to end on a small synthetic scan: seeds, explicit camera, named and
// rotated environments, turntable, side-by-side, albedo, --denoise, and the usage / bad-input
// exits.

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>

#include "core/image_io.h"
#include "core/scan_folder.h"
#include "tests/cli_util.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

fs::path SmallScan() {
  static const fs::path dir = [] {
    const fs::path d = CliTempDir("render", "scan");
    fs::create_directories(d);
    HeightField hf;
    hf.pixel_size = 1e-4;
    hf.x0 = -15.5e-4;
    hf.y0 = 15.5e-4;
    hf.z = ImageF(32, 32, 1);
    for (int j = 0; j < 32; ++j)
      for (int i = 0; i < 32; ++i)
        hf.z(i, j) = static_cast<float>(5e-4 + 2e-4 * std::sin(i * 0.4) * std::cos(j * 0.3));
    for (int j = 12; j < 16; ++j)
      for (int i = 12; i < 18; ++i) hf.z(i, j) = NAN;  // a hole down to the mount
    WriteHeightExr(d / "height.exr", hf);
    return d;
  }();
  return dir;
}

std::string Base(const fs::path& out, const std::string& env = "sky") {
  return "render " + SmallScan().string() + " --out " + out.string() + " --brdf lambert --env " +
         env + " --size 24x18 --spp 16 --threads 2";
}

bool SameFile(const fs::path& a, const fs::path& b) {
  const ImageF x = ReadImage(a), y = ReadImage(b);
  if (x.pixels() != y.pixels() || x.channels() != y.channels()) return false;
  for (int c = 0; c < x.channels(); ++c)
    if (std::memcmp(x.channel(c), y.channel(c), x.pixels() * sizeof(float)) != 0) return false;
  return true;
}

TEST(RenderCli, SeedsReproduceAndDiffer) {
  const fs::path a = CliTempDir("render", "a"), b = CliTempDir("render", "b"),
                 c = CliTempDir("render", "c");
  ASSERT_EQ(RunMesoscan(Base(a) + " --seed 5").code, 0);
  ASSERT_EQ(RunMesoscan(Base(b) + " --seed 5").code, 0);
  ASSERT_EQ(RunMesoscan(Base(c) + " --seed 6").code, 0);
  EXPECT_TRUE(SameFile(a / "preview.exr", b / "preview.exr"));
  EXPECT_FALSE(SameFile(a / "preview.exr", c / "preview.exr"));
  EXPECT_TRUE(fs::exists(a / "preview.png"));
}

// --denoise writes preview_denoised.exr/png beside the raw preview, which stays the render
// without it (same seed: bit for bit); the denoised image is finite and as large.
TEST(RenderCli, DenoiseWritesBesideTheRawPreview) {
  const fs::path a = CliTempDir("render", "dn"), b = CliTempDir("render", "raw");
  ASSERT_EQ(RunMesoscan(Base(a) + " --seed 5 --denoise").code, 0);
  ASSERT_EQ(RunMesoscan(Base(b) + " --seed 5").code, 0);
  EXPECT_TRUE(SameFile(a / "preview.exr", b / "preview.exr"));
  EXPECT_FALSE(fs::exists(b / "preview_denoised.exr"));
  ASSERT_TRUE(fs::exists(a / "preview_denoised.png"));
  const ImageF dn = ReadImage(a / "preview_denoised.exr"), raw = ReadImage(a / "preview.exr");
  ASSERT_EQ(dn.width(), raw.width());
  ASSERT_EQ(dn.height(), raw.height());
  for (const float v : dn.data()) ASSERT_TRUE(std::isfinite(v) && v >= 0);
}

TEST(RenderCli, CameraTurntableCompareAlbedo) {
  const fs::path d = CliTempDir("render", "features");
  const auto r = RunMesoscan(Base(d) +
                             " --camera eye=0,-0.004,0.006:target=0,0,0:fov=35 --env-rotation 90 "
                             "--turntable 3 --compare ggx --albedo 0.8,0.5,0.3");
  ASSERT_EQ(r.code, 0) << r.output;
  for (const char* f : {"preview.png", "preview.exr", "side_by_side.png", "turntable.gif",
                        "turntable/frame_000.png", "turntable/frame_002.png"})
    EXPECT_TRUE(fs::exists(d / f)) << f;
  const ImageF sbs = ReadImage(d / "side_by_side.png");
  EXPECT_EQ(sbs.width(), 2 * 24 + 4);
}

// A second scan: a plain slab at another height and size.
fs::path FlatScan() {
  static const fs::path dir = [] {
    const fs::path d = CliTempDir("render", "flat_scan");
    fs::create_directories(d);
    HeightField hf;
    hf.pixel_size = 1e-4;
    hf.x0 = -11.5e-4;
    hf.y0 = 11.5e-4;
    hf.z = ImageF(24, 24, 1, 3e-4f);
    WriteHeightExr(d / "height.exr", hf);
    return d;
  }();
  return dir;
}

// Columns [x0, x0 + w) of an image as one vector.
std::vector<float> Half(const ImageF& im, int x0, int w) {
  std::vector<float> v;
  for (int c = 0; c < im.channels(); ++c)
    for (int y = 0; y < im.height(); ++y)
      for (int x = x0; x < x0 + w; ++x) v.push_back(im(x, y, c));
  return v;
}

// Two scans side by side: one camera, light and exposure. The same scan on both sides gives two
// identical halves (same seed); another scan gives a different right half while the left half is
// the preview itself.
TEST(RenderCli, SideBySideOfTwoScans) {
  const fs::path same = CliTempDir("render", "sbs_same"), other = CliTempDir("render", "sbs_other");
  auto r = RunMesoscan(Base(same) + " --compare-scan " + SmallScan().string());
  ASSERT_EQ(r.code, 0) << r.output;
  const ImageF a = ReadImage(same / "side_by_side.png");
  ASSERT_EQ(a.width(), 2 * 24 + 4);
  EXPECT_EQ(Half(a, 0, 24), Half(a, 28, 24));
  // --compare accepts a scan folder too.
  r = RunMesoscan(Base(other) + " --compare " + FlatScan().string());
  ASSERT_EQ(r.code, 0) << r.output;
  const ImageF b = ReadImage(other / "side_by_side.png");
  const ImageF preview = ReadImage(other / "preview.png");
  EXPECT_EQ(Half(b, 0, 24), Half(preview, 0, 24));
  EXPECT_NE(Half(b, 0, 24), Half(b, 28, 24));
  // A folder without height.exr: bad input naming the file; two comparisons at once: usage.
  const fs::path bad = CliTempDir("render", "sbs_bad");
  r = RunMesoscan(Base(bad) + " --compare-scan " + CliTempDir("render", "no_scan").string());
  EXPECT_EQ(r.code, 3) << r.output;
  EXPECT_NE(r.output.find("height.exr"), std::string::npos) << r.output;
  r = RunMesoscan(Base(bad) + " --compare ggx --compare-scan " + FlatScan().string());
  EXPECT_EQ(r.code, 2) << r.output;
}

TEST(RenderCli, NamedEnvironmentWhenBlenderDataIsInstalled) {
  if (!fs::exists("/usr/share/blender/datafiles/studiolights/world/studio.exr"))
    GTEST_SKIP() << "blender-data not installed";
  const fs::path d = CliTempDir("render", "studio");
  const auto r = RunMesoscan(Base(d, "studio"));
  EXPECT_EQ(r.code, 0) << r.output;
}

TEST(RenderCli, BadArgumentsExitWithUsageOrBadInput) {
  const fs::path d = CliTempDir("render", "bad");
  auto r = RunMesoscan(Base(d) + " --camera eye=1,2:target=0,0,0");
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_NE(r.output.find("--camera"), std::string::npos);
  r = RunMesoscan(Base(d) + " --albedo purple");
  EXPECT_EQ(r.code, 2) << r.output;
  r = RunMesoscan(Base(d, "no-such-env"));
  EXPECT_EQ(r.code, 3) << r.output;
  EXPECT_NE(r.output.find("no-such-env"), std::string::npos);
  r = RunMesoscan(Base(d) + " --noise -1");
  EXPECT_EQ(r.code, 3) << r.output;
}

}  // namespace
}  // namespace mesoscan
