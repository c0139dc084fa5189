// Colour and reflectance through the whole pipeline, on the virtual rig's dyed fabric (assets/
// objects.h ColourObject: the ground truth's reflectance per channel is known):
//  - `simulate --object fabric` (coloured by default) under a projector whose irradiance falls
//    off towards its edges (--projector-falloff) with a grey card of reflectance 0.18 on the
//    mount beside the fabric; `reconstruct` decodes the frames' luminance;
//  - `maps --grey-card X,Y,W,H:0.18` (the card's camera pixels, as simulate recorded them): the
//    albedo is reflectance per channel: on the flat mount within 2% of the truth per channel; on
//    the fabric its median within 4% (measured 2.8% low: the fibre twist's 6 um ridges, 0.12 mm
//    apart, are near the camera's sampling limit and the measured heights keep only part of
//    their slopes, so the light on them is overstated), the same in both halves along the
//    projector's falloff and in every channel; the plain map (no
//    reference: relative albedo, 99th percentile 1) is measured beside it and its manifest says
//    it is relative;
//  - Blender 3.4 imports the map set through the add-on: the Principled BSDF's Base Color comes
//    from the RGB albedo, and a render of the plane under a white sun is red like the fabric.

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <map>
#include <vector>

#include "assets/objects.h"
#include "core/image_io.h"
#include "core/json.h"
#include "tests/export_consumers.h"

namespace mesoscan {
namespace {
using namespace consumers;  // NOLINT: the shared consumer helpers

constexpr double kCard = 0.18;

class MaterialsCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = fs::temp_directory_path() / ("mesoscan_materials_cli_test_" + std::to_string(getpid()));
    fs::remove_all(root_);
    fs::create_directories(root_);
    std::string out;
    // The fabric's upper-left corner (its lower-right 85 x 85 px), the card on the bare mount
    // up and left of it (camera pixels ~13..77).
    status_ = RunMesoscan(
        "-q simulate --object fabric --crop 700,330,200,200 --supersample 1 "
        "--ls-frames 20 --projector-falloff 0.4 --grey-card -18.84,18.78,3.5:" +
            std::to_string(kCard) + " --out " + Q(root_ / "fab.session"),
        &log_);
    if (status_ != 0) return;
    const Json s = ReadJsonFile(root_ / "fab.session/session.json");
    const Json& px = s.at("simulation").at("grey_card").at("camera_px");
    card_ = std::to_string(px[0].get<int>()) + "," + std::to_string(px[1].get<int>()) + "," +
            std::to_string(px[2].get<int>()) + "," + std::to_string(px[3].get<int>());
    status_ = RunMesoscan(
        "-q reconstruct " + Q(root_ / "fab.session") + " --out " + Q(root_ / "fab.scan"), &out);
    log_ += out;
    if (status_ != 0) return;
    status_ = RunMesoscan("-q maps " + Q(root_ / "fab.scan") + " --out " + Q(root_ / "ours") +
                              " --maps height,albedo,confidence --grey-card " + card_ + ":" +
                              std::to_string(kCard),
                          &out);
    log_ += out;
    if (status_ != 0) return;
    status_ = RunMesoscan("-q maps " + Q(root_ / "fab.scan") + " --out " + Q(root_ / "plain") +
                              " --maps height,albedo,confidence",
                          &out);
    log_ += out;
  }
  static void TearDownTestSuite() {
    std::error_code ec;
    fs::remove_all(root_, ec);
  }
  void SetUp() override { ASSERT_EQ(status_, 0) << log_; }
  static inline fs::path root_;
  static inline int status_ = -1;
  static inline std::string log_, card_;
};

// Per channel: the albedo over the true reflectance at the measured fabric samples of a map set
// (confidence > 0, 0.3 mm inside the fabric's edge), all of them and split at the fabric's middle
// column (the falloff changes across it).
struct Ratios {
  std::array<std::vector<double>, 3> all, left, right;
  std::array<std::vector<double>, 3> mount;  // the bare mount (flat: no relief below a pixel)
};

Ratios MeasureAgainstTruth(const fs::path& session, const fs::path& dir) {
  std::map<std::string, double> ga, ma;
  const ImageF truth = ReadExrChannels(session / "gt_albedo.exr", {"R", "G", "B"}, &ga);
  const ImageF albedo = ReadExrChannels(dir / "fab_albedo.exr", {"R", "G", "B"}, &ma);
  const ImageF conf = ReadImage(dir / "fab_confidence.png");
  const double tx0 = ga.at("mesoscan:x0"), ty0 = ga.at("mesoscan:y0"),
               tp = ga.at("mesoscan:pixel_size");
  const double x0 = ma.at("mesoscan:x0"), y0 = ma.at("mesoscan:y0"),
               p = ma.at("mesoscan:pixel_size");
  const double inner = kMaterialHalfM - 0.3e-3;
  // The fabric's visible part: x from -inner to the crop's right edge.
  const double x_mid = 0.5 * (-inner + (x0 + (albedo.width() - 1) * p));
  Ratios r;
  for (int j = 0; j < albedo.height(); ++j)
    for (int i = 0; i < albedo.width(); ++i) {
      const double x = x0 + i * p, y = y0 - j * p;
      const bool fabric = std::abs(x) <= inner && std::abs(y) <= inner;
      const bool mount =
          std::abs(x) > kMaterialHalfM + 0.3e-3 || std::abs(y) > kMaterialHalfM + 0.3e-3;
      if ((!fabric && !mount) || !(conf(i, j) > 0)) continue;
      // The truth bilinear at (x, y).
      const double fi = (x - tx0) / tp, fj = (ty0 - y) / tp;
      const int i0 = static_cast<int>(std::floor(fi)), j0 = static_cast<int>(std::floor(fj));
      if (i0 < 0 || j0 < 0 || i0 + 1 >= truth.width() || j0 + 1 >= truth.height()) continue;
      const double a = fi - i0, b = fj - j0;
      for (int c = 0; c < 3; ++c) {
        const double t = (1 - a) * (1 - b) * truth(i0, j0, c) + a * (1 - b) * truth(i0 + 1, j0, c) +
                         (1 - a) * b * truth(i0, j0 + 1, c) + a * b * truth(i0 + 1, j0 + 1, c);
        const double v = albedo(i, j, c);
        if (!(t > 0.02) || !std::isfinite(v)) continue;
        if (mount) {
          r.mount[c].push_back(v / t);
          continue;
        }
        r.all[c].push_back(v / t);
        (x < x_mid ? r.left : r.right)[c].push_back(v / t);
      }
    }
  return r;
}

double Median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

double QuantileOf(std::vector<double> v, double q) {
  if (v.empty()) return std::nan("");
  const size_t k = static_cast<size_t>(q * (v.size() - 1));
  std::nth_element(v.begin(), v.begin() + k, v.end());
  return v[k];
}

TEST_F(MaterialsCli, DyedFabricAlbedoIsReflectancePerChannel) {
  const Json ours_manifest = ReadJsonFile(root_ / "ours/manifest.json");
  const Json plain_manifest = ReadJsonFile(root_ / "plain/manifest.json");
  EXPECT_NE(ours_manifest.at("albedo").at("units").get<std::string>().find("reflectance"),
            std::string::npos)
      << ours_manifest.at("albedo").dump();
  EXPECT_NE(plain_manifest.at("albedo").at("units").get<std::string>().find("relative"),
            std::string::npos);
  EXPECT_EQ(plain_manifest.at("albedo").at("reference").get<std::string>().rfind("none", 0), 0u);
  const Ratios ours = MeasureAgainstTruth(root_ / "fab.session", root_ / "ours");
  const Ratios plain = MeasureAgainstTruth(root_ / "fab.session", root_ / "plain");
  const char* names[3] = {"R", "G", "B"};
  std::cout << "grey card " << card_ << ", " << ours.all[0].size() << " measured fabric samples\n";
  for (int c = 0; c < 3; ++c) {
    ASSERT_GT(ours.all[c].size(), 2000u) << names[c];
    const double m = Median(ours.all[c]), ml = Median(ours.left[c]), mr = Median(ours.right[c]);
    const double pm = Median(plain.all[c]), pl = Median(plain.left[c]), pr = Median(plain.right[c]);
    std::cout << names[c] << ": albedo / true reflectance, median (left half, right half; "
              << "p10..p90): ours " << m << " (" << ml << ", " << mr << "; "
              << QuantileOf(ours.all[c], 0.1) << ".." << QuantileOf(ours.all[c], 0.9)
              << "), plain relative " << pm << " (" << pl << ", " << pr << "; "
              << QuantileOf(plain.all[c], 0.1) << ".." << QuantileOf(plain.all[c], 0.9)
              << "); the bare mount: ours " << Median(ours.mount[c]) << ", plain "
              << Median(plain.mount[c]) << "\n";
    // The radiometric chain (falloff, card, response, colour) on the flat mount: 2%.
    EXPECT_NEAR(Median(ours.mount[c]), 1.0, 0.02) << names[c];
    // The fabric: relief near the sampling limit, whose slopes the measured heights only partly
    // keep, leaves it a few percent low (measured 2.8%, the same in every channel and both
    // halves; the irradiance of the central-difference normals left it 3.5% low): 4% here, the
    // colour balance (each channel against the others) and the falloff (left against right)
    // within 1%.
    EXPECT_NEAR(m, 1.0, 0.04) << names[c];
    EXPECT_NEAR(ml / mr, 1.0, 0.01) << names[c];
    // The plain map is relative brightness: off by its arbitrary scale.
    EXPECT_GT(std::abs(pm - 1.0), 0.1) << names[c];
  }
  for (int c = 1; c < 3; ++c)
    EXPECT_NEAR(Median(ours.all[c]) / Median(ours.all[0]), 1.0, 0.01) << names[c] << " / R";
}

TEST_F(MaterialsCli, TheColourReachesBlendersBaseColour) {
  const std::string blender = FindOnPath("blender");
  if (blender.empty()) GTEST_SKIP() << "blender missing: " << kInstall;
  const fs::path zip = MESOSCAN_ADDON_ZIP;
  ASSERT_TRUE(fs::exists(zip)) << zip;
  const fs::path tmp = root_ / "blender";
  fs::create_directories(tmp / "user_scripts");
  // The fabric alone (a square of the height grid inside it).
  std::string out;
  ASSERT_EQ(RunMesoscan("-q maps " + Q(root_ / "fab.scan") + " --out " + Q(root_ / "fabric") +
                            " --maps height,albedo --crop 125,125,70,70 --grey-card " + card_ +
                            ":" + std::to_string(kCard),
                        &out),
            0)
      << out;
  const Json cfg = {{"addon_zip", zip.string()},
                    {"manifest", (root_ / "fabric/manifest.json").string()},
                    {"tmp", tmp.string()},
                    {"out", (tmp / "out.json").string()},
                    {"render_px", 48}};
  WriteJsonFile(tmp / "cfg.json", cfg);
  std::string log;
  const int status = RunCommand("BLENDER_USER_SCRIPTS=" + Q(tmp / "user_scripts") + " " + blender +
                                    " -b --factory-startup --python-exit-code 1 -P " +
                                    Q(kSource / "tests/consumers/blender_colour_checks.py") +
                                    " -- " + Q(tmp / "cfg.json"),
                                &log);
  ASSERT_EQ(status, 0) << log;
  const Json r = ReadJsonFile(tmp / "out.json");
  std::cout << r.dump(1) << "\n";
  const Json& imgs = r.at("base_color_images");
  EXPECT_NE(std::find(imgs.begin(), imgs.end(), "albedo"), imgs.end()) << imgs.dump();
  const Json& a = r.at("albedo_image");
  EXPECT_EQ(a.at("colorspace"), "sRGB");
  EXPECT_GE(a.at("channels").get<int>(), 3);
  // The fabric is a rose red: R well above G and B in the texture and in the render.
  const Json& tm = a.at("mean_rgb");
  EXPECT_GT(tm[0].get<double>(), 1.2 * tm[1].get<double>()) << tm.dump();
  const Json& rm = r.at("render_mean_rgb");
  EXPECT_GT(rm[0].get<double>(), 1.1 * rm[1].get<double>()) << rm.dump();
  EXPECT_GT(rm[0].get<double>(), 1.1 * rm[2].get<double>()) << rm.dump();
}

}  // namespace
}  // namespace mesoscan
