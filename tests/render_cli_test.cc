// `mesoscan render` end to end on a small synthetic scan: seeds, explicit camera, named and
// rotated environments, turntables (object and light), labelled side-by-sides, albedo (given,
// and the scan's own by default), the mount's neutral material, the scale bar, what the output
// folder holds, --denoise, and the usage / bad-input exits.

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>

#include "core/image_io.h"
#include "core/scan_folder.h"
#include "render/overlay.h"
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
  EXPECT_EQ(sbs.height(), 18 + LabelStripHeight(18));
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

// Columns [x0, x0 + w) of rows [y0, height) of an image as one vector.
std::vector<float> Half(const ImageF& im, int x0, int w, int y0 = 0) {
  std::vector<float> v;
  for (int c = 0; c < im.channels(); ++c)
    for (int y = y0; y < im.height(); ++y)
      for (int x = x0; x < x0 + w; ++x) v.push_back(im(x, y, c));
  return v;
}

// Whether any pixel of rows [y0, y1) differs (all columns).
bool Differ(const ImageF& a, const ImageF& b, int y0, int y1) {
  for (int c = 0; c < a.channels(); ++c)
    for (int y = y0; y < y1; ++y)
      for (int x = 0; x < a.width(); ++x)
        if (a(x, y, c) != b(x, y, c)) return true;
  return false;
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
  // The images under the label strip; the strip holds the labels (dark text on white).
  const int strip = LabelStripHeight(18);
  ASSERT_EQ(a.height(), 18 + strip);
  EXPECT_EQ(Half(a, 0, 24, strip), Half(a, 28, 24, strip));
  float darkest = 1;
  for (int y = 0; y < strip; ++y)
    for (int x = 0; x < 24; ++x) darkest = std::min(darkest, a(x, y, 0));
  EXPECT_LT(darkest, 0.5f) << "no label drawn";
  // --compare accepts a scan folder too.
  r = RunMesoscan(Base(other) + " --compare " + FlatScan().string());
  ASSERT_EQ(r.code, 0) << r.output;
  const ImageF b = ReadImage(other / "side_by_side.png");
  const ImageF preview = ReadImage(other / "preview.png");
  EXPECT_EQ(Half(b, 0, 24, strip), Half(preview, 0, 24));
  EXPECT_NE(Half(b, 0, 24, strip), Half(b, 28, 24, strip));
  // A folder without height.exr: bad input naming the file; two comparisons at once: usage.
  const fs::path bad = CliTempDir("render", "sbs_bad");
  r = RunMesoscan(Base(bad) + " --compare-scan " + CliTempDir("render", "no_scan").string());
  EXPECT_EQ(r.code, 3) << r.output;
  EXPECT_NE(r.output.find("height.exr"), std::string::npos) << r.output;
  r = RunMesoscan(Base(bad) + " --compare ggx --compare-scan " + FlatScan().string());
  EXPECT_EQ(r.code, 2) << r.output;
}

// A sample on its mount: a 16 x 10 px block 0.5 mm high in the left half of a 40 x 40 px field
// at the mount plane (z = 0), with a colour albedo.exr in the scan folder (red).
fs::path MountedScan() {
  static const fs::path dir = [] {
    const fs::path d = CliTempDir("render", "mounted_scan");
    fs::create_directories(d);
    HeightField hf;
    hf.pixel_size = 1e-4;
    hf.x0 = -19.5e-4;
    hf.y0 = 19.5e-4;
    hf.z = ImageF(40, 40, 1, 0.0f);
    ImageF albedo(40, 40, 3, 0.2f);
    for (int j = 15; j < 25; ++j)
      for (int i = 4; i < 20; ++i) hf.z(i, j) = 5e-4f;
    for (int j = 0; j < 40; ++j)
      for (int i = 0; i < 40; ++i) albedo(i, j, 0) = 0.9f;
    WriteHeightExr(d / "height.exr", hf);
    WriteExr(d / "albedo.exr", albedo, {"R", "G", "B"}, {}, {}, "none");
    return d;
  }();
  return dir;
}

std::string MountedBase(const fs::path& out) {
  return "render " + MountedScan().string() + " --out " + out.string() +
         " --brdf lambert --env constant --size 40x30 --spp 16 --threads 2 --elevation 70";
}

// Reddish (R well above G) and neutral pixels of a render.
struct Colours {
  int red = 0, neutral = 0;
  double red_x = 0;  // mean column of the red pixels
};
Colours CountColours(const ImageF& im) {
  Colours c;
  for (int y = 0; y < im.height(); ++y)
    for (int x = 0; x < im.width(); ++x) {
      const float r = im(x, y, 0), g = im(x, y, 1), b = im(x, y, 2);
      if (r > 0.02f && g < 0.6f * r && b < 0.6f * r) {
        ++c.red;
        c.red_x += x;
      } else if (r > 0.02f && std::abs(r - g) < 0.1f * r && std::abs(r - b) < 0.1f * r) {
        ++c.neutral;
      }
    }
  if (c.red) c.red_x /= c.red;
  return c;
}

// By default the scan's own albedo (colour) tints the sample and the bare mount is neutral
// diffuse grey; --mount sample paints the whole field in the sample's material (the mount red
// too); --albedo none leaves the sample the BRDF's grey.
TEST(RenderCli, TheSampleInItsAlbedoOnANeutralMount) {
  const fs::path d = CliTempDir("render", "mounted"), all = CliTempDir("render", "mounted_all"),
                 grey = CliTempDir("render", "mounted_grey");
  auto r = RunMesoscan(MountedBase(d));
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("albedo.exr (colour"), std::string::npos) << r.output;
  const Colours c = CountColours(ReadImage(d / "preview.exr"));
  ASSERT_EQ(RunMesoscan(MountedBase(all) + " --mount sample").code, 0);
  const Colours ca = CountColours(ReadImage(all / "preview.exr"));
  ASSERT_EQ(RunMesoscan(MountedBase(grey) + " --albedo none").code, 0);
  const Colours cg = CountColours(ReadImage(grey / "preview.exr"));
  std::cout << "red / neutral pixels: default " << c.red << " / " << c.neutral
            << ", --mount sample " << ca.red << " / " << ca.neutral << ", --albedo none " << cg.red
            << " / " << cg.neutral << "\n";
  // The block covers about a tenth of the field; the mount the rest.
  EXPECT_GT(c.red, 40);
  EXPECT_GT(c.neutral, 4 * c.red);
  EXPECT_GT(ca.red, 3 * c.red);
  EXPECT_EQ(cg.red, 0);
  r = RunMesoscan(MountedBase(CliTempDir("render", "mounted_bad")) + " --mount hidden");
  EXPECT_EQ(r.code, 2) << r.output;
}

// --turntable turns the object: half a turn later the block (left of the centre) is seen on the
// right; --turntable-light turns the light and the block stays where it is.
TEST(RenderCli, TurntableTurnsTheObjectAndTurntableLightTheLight) {
  const fs::path d = CliTempDir("render", "turn");
  const auto r = RunMesoscan(MountedBase(d) + " --turntable 2 --turntable-light 2");
  ASSERT_EQ(r.code, 0) << r.output;
  for (const char* f : {"turntable.gif", "turntable/frame_001.png", "turntable_light.gif",
                        "turntable_light/frame_001.png"})
    EXPECT_TRUE(fs::exists(d / f)) << f;
  const Colours o0 = CountColours(ReadImage(d / "turntable/frame_000.png")),
                o1 = CountColours(ReadImage(d / "turntable/frame_001.png")),
                l0 = CountColours(ReadImage(d / "turntable_light/frame_000.png")),
                l1 = CountColours(ReadImage(d / "turntable_light/frame_001.png"));
  std::cout << "red pixels' mean column: object turning " << o0.red_x << " -> " << o1.red_x
            << ", light turning " << l0.red_x << " -> " << l1.red_x << " (of 40)\n";
  ASSERT_GT(o0.red, 10);
  ASSERT_GT(o1.red, 10);
  EXPECT_LT(o0.red_x, 17);
  EXPECT_GT(o1.red_x, 23);
  EXPECT_NEAR(l0.red_x, l1.red_x, 2);
}

// The render folder holds the previews only (no copy of the tabulated MERL table); the progressive
// preview's path beside it is gone once the final preview is in place; --scale-bar changes the
// PNG's lower rows only, never the EXR.
TEST(RenderCli, OutputHoldsThePreviewsAndTheScaleBarOnlyThePng) {
  const fs::path d = CliTempDir("render", "merl"), bar = CliTempDir("render", "bar");
  const std::string args = " --brdf ggx-merl --env sky --size 48x36 --spp 4 --threads 2 --seed 3";
  auto r = RunMesoscan("render " + MountedScan().string() + " --out " + d.string() + args);
  ASSERT_EQ(r.code, 0) << r.output;
  uintmax_t bytes = 0;
  for (const auto& e : fs::recursive_directory_iterator(d)) {
    if (e.is_regular_file()) bytes += e.file_size();
    EXPECT_NE(e.path().extension(), ".binary") << e.path();
  }
  EXPECT_LT(bytes, 1u << 20);
  EXPECT_NE(r.output.find(d.string() + ".progress.png"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(d.string() + ".progress.png"));
  r = RunMesoscan("render " + MountedScan().string() + " --out " + bar.string() + args +
                  " --scale-bar");
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_TRUE(SameFile(d / "preview.exr", bar / "preview.exr"));
  const ImageF a = ReadImage(d / "preview.png"), b = ReadImage(bar / "preview.png");
  EXPECT_FALSE(Differ(a, b, 0, a.height() / 2));
  EXPECT_TRUE(Differ(a, b, a.height() / 2, a.height()));
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
