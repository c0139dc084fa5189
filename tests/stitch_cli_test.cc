// `mesoscan stitch` on a simulated mosaic: a 2 x 2 mosaic (30% overlap) of an impasto painting
// through the virtual rig at a quarter of the paper rig's resolution (220 um pixels) on small
// tiles (kCrop camera pixels a side), each tile but the first re-placed by up to 3.5 mm and 5
// degrees; the stitched field against the painting's ground truth, beside the plain mosaic
// (nominal offsets, no registration). bench/stitch_mosaic.sh runs larger mosaics.

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "assets/objects.h"
#include "core/json.h"
#include "core/scan_folder.h"
#include "tests/cli_util.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

// Concatenation by append (GCC 12's -Wrestrict misfires on chains of operator+).
std::string Cat(std::initializer_list<std::string> parts) {
  std::string s;
  for (const std::string& p : parts) s.append(p);
  return s;
}

// The paper rig with every device at a quarter of its resolution (the same geometry).
const char* kQuarterRig = R"({"rig": {
 "camera": {"K": [[1136.3636363636363, 0, 271.5], [0, 1136.3636363636363, 178.5], [0, 0, 1]],
  "black_level": 0, "distortion": [0, 0, 0, 0, 0], "width": 544, "height": 358,
  "response": "linear", "world_from_device": [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 0.25],
  [0, 0, 0, 1]]},
 "lens_shifter": {"axis": "x", "range_steps": [-2048, 2048], "steps_per_px": 2048.0},
 "projector": {"K": [[412.5, 0, 99.5], [0, 412.5, 74.5], [0, 0, 1]],
  "distortion": [0, 0, 0, 0, 0], "width": 200, "height": 150, "response": "linear",
  "world_from_device": [[0.9396926207859084, 0, -0.3420201433256687, 0.09063533798130222],
   [0, -1, 0, 0], [-0.3420201433256687, 0, -0.9396926207859084, 0.24901854450826574],
   [0, 0, 0, 1]]}}})";

constexpr int kCrop = 96;                           // camera pixels per tile side
constexpr double kPixelMm = 0.22;                   // the quarter rig's pixel on the mount
constexpr double kStepMm = 0.7 * kCrop * kPixelMm;  // 30% overlap
constexpr const char* kCanvas = "impasto:50x50";

struct Figures {
  double rms_um = 0, seam_over_interior = 0;
  int64_t pixels = 0;
};

// The stitched field against the painting (the mosaic frame is the object's: the first tile is
// placed exactly) over the mosaic's nominal extent less 4 pixels (a tile's own border pixels are
// left out of its single-scan RMS likewise; the re-placed tiles' ragged outer borders are no
// part of the mosaic), and the mean |gradient| of its error on the tiles' nominal borders inside
// the mosaic against elsewhere.
Figures Evaluate(const fs::path& scan, const SceneObject& truth) {
  const HeightField hf = ReadHeightExr(scan / "height.exr");
  ImageF err(hf.width(), hf.height(), 1, std::nanf(""));
  const double half = 0.5 * kCrop * kPixelMm * 1e-3, step = kStepMm * 1e-3;
  const double outer = 0.5 * step + half - 4 * hf.pixel_size;
  double ss = 0;
  Figures f;
  for (int j = 3; j < hf.height() - 3; ++j)
    for (int i = 3; i < hf.width() - 3; ++i) {
      if (!std::isfinite(hf.z(i, j))) continue;
      if (std::abs(hf.X(i)) > outer || std::abs(hf.Y(j)) > outer) continue;
      const double e = hf.z(i, j) - truth.SurfaceZ(hf.X(i), hf.Y(j));
      err(i, j) = static_cast<float>(e);
      ss += e * e;
      ++f.pixels;
    }
  f.rms_um = std::sqrt(ss / std::max<int64_t>(1, f.pixels)) * 1e6;
  // The seams: the tiles' nominal borders inside the mosaic (x or y within 2 px of them).
  double seam = 0, interior = 0;
  int64_t ns = 0, ni = 0;
  for (int j = 4; j < hf.height() - 4; ++j)
    for (int i = 4; i < hf.width() - 4; ++i) {
      const float gx = err(i + 1, j) - err(i - 1, j), gy = err(i, j + 1) - err(i, j - 1);
      if (!std::isfinite(gx) || !std::isfinite(gy)) continue;
      if (std::abs(hf.X(i)) > outer || std::abs(hf.Y(j)) > outer) continue;
      const double g = std::hypot(gx, gy);
      bool on_seam = false;
      for (double c : {-0.5 * step, 0.5 * step})
        for (double s : {-half, half}) {
          if (std::abs(c + s) > outer) continue;  // the mosaic's outer border
          on_seam |= std::abs(hf.X(i) - (c + s)) < 2 * hf.pixel_size;
          on_seam |= std::abs(hf.Y(j) - (c + s)) < 2 * hf.pixel_size;
        }
      (on_seam ? seam : interior) += g;
      ++(on_seam ? ns : ni);
    }
  f.seam_over_interior = (seam / std::max<int64_t>(1, ns)) / (interior / std::max<int64_t>(1, ni));
  return f;
}

// The RMS of a single tile's height field against the painting (the same margin): the tile's
// world point (x, y) lies over the painting's R^T ((x, y) - t) + o (re-placed by the rotation
// rz_deg about the field's centre and the shift t after the object moved by -o).
double SingleScanRmsUm(const fs::path& scan, const SceneObject& truth, double ox, double oy,
                       double rz_deg, double tx, double ty) {
  const HeightField hf = ReadHeightExr(scan / "height.exr");
  const double a = rz_deg * 3.14159265358979323846 / 180, c = std::cos(a), s = std::sin(a);
  double ss = 0;
  int64_t n = 0;
  for (int j = 3; j < hf.height() - 3; ++j)
    for (int i = 3; i < hf.width() - 3; ++i) {
      if (!std::isfinite(hf.z(i, j))) continue;
      const double x = hf.X(i) - tx, y = hf.Y(j) - ty;
      const double e = hf.z(i, j) - truth.SurfaceZ(c * x + s * y + ox, -s * x + c * y + oy);
      ss += e * e;
      ++n;
    }
  return std::sqrt(ss / std::max<int64_t>(1, n)) * 1e6;
}

TEST(StitchCli, MosaicOfFourReplacedTilesMatchesTheGroundTruthWithoutSeams) {
  const fs::path work = CliTempDir("StitchCli", "Mosaic");
  fs::create_directories(work);
  { std::ofstream(work / "quarter.json") << kQuarterRig; }
  // Tile k: field centre over the painting's (ox, oy); re-placed about it (deg, mm).
  const double poses[4][3] = {{0, 0, 0}, {4.0, 2.0, -1.5}, {-5.0, -1.5, 2.0}, {2.5, 2.5, 1.0}};
  std::string scans, offsets;
  double single_rms = 0;
  const SceneObject truth = MakeObject(kCanvas, 1e-4);
  for (int k = 0; k < 4; ++k) {
    const double ox = (k % 2 - 0.5) * kStepMm, oy = (0.5 - k / 2) * kStepMm;
    const std::string t = (work / Cat({"t", std::to_string(k)})).string();
    char args[512];
    std::snprintf(args, sizeof(args),
                  "simulate --object %s --rig '%s' --crop %d,%d,%d,%d --supersample 1 "
                  "--ls-frames 8 --seed %d --field-offset %.3f,%.3f --object-pose "
                  "0,0,%.2f,%.2f,%.2f,0 --out '%s'",
                  kCanvas, (work / "quarter.json").c_str(), 272 - kCrop / 2, 179 - kCrop / 2, kCrop,
                  kCrop, k + 1, ox, oy, poses[k][0], poses[k][1], poses[k][2], t.c_str());
    CliRun r = RunCli(args, work);
    ASSERT_EQ(r.code, 0) << r.err;
    r = RunCli(Cat({"reconstruct '", t, "' --out '", t, ".scan'"}), work);
    ASSERT_EQ(r.code, 0) << r.err;
    single_rms =
        std::max(single_rms, SingleScanRmsUm(Cat({t, ".scan"}), truth, ox * 1e-3, oy * 1e-3,
                                             poses[k][0], poses[k][1] * 1e-3, poses[k][2] * 1e-3));
    scans.append(Cat({" '", t, ".scan'"}));
    char o[64];
    std::snprintf(o, sizeof(o), " %.3f,%.3f", ox, oy);
    offsets += o;
  }
  CliRun r = RunCli(
      Cat({"stitch", scans, " --offset", offsets, " --out '", (work / "ours").string(), "'"}),
      work);
  ASSERT_EQ(r.code, 0) << r.err;
  r = RunCli(Cat({"stitch", scans, " --offset", offsets, " --no-register --out '",
                  (work / "plain").string(), "'"}),
             work);
  ASSERT_EQ(r.code, 0) << r.err;
  const Figures ours = Evaluate(work / "ours", truth), plain = Evaluate(work / "plain", truth);
  std::printf(
      "single-scan RMS (worst tile) %.2f um; stitched: ours %.2f um (seam/interior %.2f, "
      "%lld px), plain %.2f um (seam/interior %.2f)\n",
      single_rms, ours.rms_um, ours.seam_over_interior, static_cast<long long>(ours.pixels),
      plain.rms_um, plain.seam_over_interior);
  EXPECT_LE(ours.rms_um, 1.1 * single_rms);
  EXPECT_LE(ours.seam_over_interior, 1.2);
  EXPECT_GT(plain.rms_um, 3 * ours.rms_um);  // the re-placement is far beyond the noise
  // The folder is a scan folder the other commands read.
  const Scan s = ReadScanFolder(work / "ours");
  EXPECT_GT(s.height.width(), kCrop);
  const Json rep = ReadJsonFile(work / "ours" / "report.json");
  EXPECT_EQ(rep.at("stitch").at("poses").size(), 4u);

  // Bad input: a missing scan folder names it (exit 3), nothing written; offsets miscounted
  // (exit 2).
  r = RunCli(Cat({"stitch", scans, " '", (work / "nope.scan").string(), "' --out '",
                  (work / "x").string(), "'"}),
             work);
  EXPECT_EQ(r.code, 3) << r.err;
  EXPECT_EQ(r.ErrLines(), 1) << r.err;
  EXPECT_NE(r.err.find("nope.scan"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(work / "x"));
  r = RunCli(Cat({"stitch", scans, " --offset 0,0 --out '", (work / "x").string(), "'"}), work);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_EQ(r.ErrLines(), 1) << r.err;
  EXPECT_FALSE(fs::exists(work / "x"));
}

}  // namespace
}  // namespace mesoscan
