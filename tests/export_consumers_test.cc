// The exports checked by their real consumers: `mesoscan export` on a synthetic
// scan, then
//  - gltf-transform validate (the Khronos glTF validator): zero errors on every GLB;
//  - Blender 3.4 in background mode (tests/consumers/blender_checks.py): the GLB imports with
//    the right vertex count and bounding box in metres; a Displace modifier driven by the EXR
//    (midlevel 0, scale 1) and by the 16-bit PNG (the sidecar's midlevel and scale) lands on
//    the scan's heights; the normal maps read through a Normal Map node give back the scan's
//    normals (OpenGL directly, DirectX after the usual green inversion), so a bump is lit from
//    the side the light is on;
//  - OpenImageIO's iinfo / oiiotool: every EXR has the expected channels and attributes.
// Consumers are installed by `scripts/install-deps --consumers`; a missing one skips its test
// with the command that installs it. tests/export_coin_test.cc runs the same checks on the demo
// coin; the helpers are in tests/export_consumers.h.

#include "tests/export_consumers.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <random>

#include "core/json.h"
#include "core/scan_folder.h"

namespace mesoscan {
namespace {
using namespace consumers;  // NOLINT: the shared consumer helpers of tests/export_consumers.h

// A 160 x 120 scan at 50 um (8 x 6 mm): a 0.4 mm Gaussian relief with a smaller 0.1 mm bump
// on a 1% ramp 0.2 mm above the mount, a shadow hole and a few dropped samples. Slopes stay
// below 0.3 so that every consumer's normal handling is in its linear range.
Scan MakeScan() {
  Scan s;
  HeightField& hf = s.height;
  const int w = 160, h = 120;
  hf.pixel_size = 50e-6;
  hf.x0 = -4e-3;
  hf.y0 = 3e-3;
  hf.z = ImageF(w, h, 1);
  hf.confidence = ImageF(w, h, 1);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(0, 1);
  for (int j = 0; j < h; ++j) {
    for (int i = 0; i < w; ++i) {
      const double x = hf.X(i), y = hf.Y(j);
      const double r1 = (x * x + y * y) / (2 * 1.0e-3 * 1.0e-3);
      const double dx = x - 2.5e-3, dy = y + 1.5e-3;
      const double r2 = (dx * dx + dy * dy) / (2 * 0.4e-3 * 0.4e-3);
      const double z = 0.2e-3 + 0.01 * (x + 4e-3) + 0.4e-3 * std::exp(-r1) + 0.1e-3 * std::exp(-r2);
      const double hx = i - 30.0, hy = j - 90.0;
      const bool hole = hx * hx + hy * hy < 100.0 || u(rng) < 0.002;
      hf.z(i, j) = hole ? std::nanf("") : static_cast<float>(z);
      hf.confidence(i, j) = hole ? 0.0f : 0.9f;
    }
  }
  s.normals = hf.Normals();
  // points.exr: a camera looking straight down with one pixel per grid sample.
  s.points.xyz = ImageF(w, h, 3);
  s.points.confidence = hf.confidence;
  s.points.projector_u = ImageF(w, h, 1, std::nanf(""));
  for (int j = 0; j < h; ++j) {
    for (int i = 0; i < w; ++i) {
      const bool valid = std::isfinite(hf.z(i, j));
      s.points.xyz(i, j, 0) = valid ? static_cast<float>(hf.X(i)) : std::nanf("");
      s.points.xyz(i, j, 1) = valid ? static_cast<float>(hf.Y(j)) : std::nanf("");
      s.points.xyz(i, j, 2) = hf.z(i, j);
    }
  }
  s.report = {{"note", "synthetic scan of tests/export_consumers_test.cc"}};
  return s;
}

class ExportConsumers : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ =
        fs::temp_directory_path() / ("mesoscan_export_consumers_test_" + std::to_string(getpid()));
    fs::remove_all(root_);
    fs::create_directories(root_);
    scan_ = new Scan(MakeScan());
    WriteScanFolder(root_ / "synthetic.scan", *scan_);
    std::string out;
    // A: every format, OpenGL normals, lossless mesh. B: DirectX normals. C: decimated mesh.
    const std::string scan = " -q export " + Q(root_ / "synthetic.scan") + " --out ";
    status_a_ = RunMesoscan(scan + Q(root_ / "a"), &out);
    log_ = out;
    status_b_ = RunMesoscan(scan + Q(root_ / "b") + " --format png16 --normals dx", &out);
    log_ += out;
    status_c_ = RunMesoscan(scan + Q(root_ / "c") + " --format glb --max-triangles 4000", &out);
    log_ += out;
  }
  static void TearDownTestSuite() {
    delete scan_;
    std::error_code ec;
    fs::remove_all(root_,
                   ec);  // each ctest case is its own process: do not leave its folder behind
  }

  void SetUp() override {
    ASSERT_EQ(status_a_, 0) << log_;
    ASSERT_EQ(status_b_, 0) << log_;
    ASSERT_EQ(status_c_, 0) << log_;
  }

  static inline fs::path root_;
  static inline Scan* scan_ = nullptr;
  static inline int status_a_ = -1, status_b_ = -1, status_c_ = -1;
  static inline std::string log_;
};

TEST_F(ExportConsumers, GltfTransformValidateReportsNoErrors) {
  if (!fs::exists(kGltfTransform)) GTEST_SKIP() << kGltfTransform << " missing: " << kInstall;
  for (const fs::path& glb : {root_ / "a/synthetic.glb", root_ / "c/synthetic.glb"}) {
    ASSERT_TRUE(fs::exists(glb)) << glb;
    const GltfValidation v = ValidateGlb(glb);
    EXPECT_TRUE(v.no_errors) << glb << "\n" << v.report;
    EXPECT_TRUE(v.no_warnings) << glb << "\n" << v.report;
  }
}

TEST_F(ExportConsumers, OiioReadsEveryExrWithItsChannelsAndAttributes) {
  if (FindOnPath("iinfo").empty())
    GTEST_SKIP() << "iinfo missing: apt-get install openimageio-tools";
  ExpectIinfoReadsExr(root_ / "a/synthetic_height.exr", scan_->height, "Y", true);
  ExpectIinfoReadsExr(root_ / "a/synthetic_normal_gl.exr", scan_->height, "R, G, B", false);
  ExpectOiiotoolStatsMatch(root_ / "a/synthetic_height.exr", scan_->height);
}

TEST_F(ExportConsumers, BlenderImportsTheGlbDisplacesByTheMapsAndReadsTheNormalHandedness) {
  const std::string blender = FindOnPath("blender");
  if (blender.empty()) GTEST_SKIP() << "blender missing: " << kInstall;
  const HeightField& hf = scan_->height;
  const Json side = ReadJsonFile(root_ / "a/synthetic_height.json");
  // Sample pixels: every 7th valid one.
  Json samples = Json::array();
  for (int j = 3; j < hf.height(); j += 7)
    for (int i = 2; i < hf.width(); i += 7)
      if (std::isfinite(hf.z(i, j))) samples.push_back({i, j});
  Json cfg = BlenderConfig(root_ / "a", "synthetic", hf, samples);
  cfg["normal_dx"] = (root_ / "b/synthetic_normal_dx.png").string();
  const Json r = RunBlenderChecks(blender, root_, cfg);
  ASSERT_FALSE(r.is_null());

  // 1. GLB: the lossless mesh's vertices and bounding box, in metres, z up.
  ExpectGlbImportMatches(r.at("glb"), LosslessMeshOf(FilledSurface(hf, root_ / "a", "synthetic")),
                         "synthetic_height.exr");

  // 2. Displacement: within 1 um of the scan's heights (the required bound; the EXR is exact in
  // float32, the PNG within half a quantisation step of (max - min) / 65535).
  const double step = side.at("scale").get<double>() / 65535.0;
  auto scan_z = [&](size_t k) { return hf.z(samples[k][0].get<int>(), samples[k][1].get<int>()); };
  const double max_exr = MaxDeviation(r.at("displace_exr"), samples.size(), scan_z);
  const double max_exr_nodes = MaxDeviation(r.at("displace_exr_nodes"), samples.size(), scan_z);
  const double max_png = MaxDeviation(r.at("displace_png"), samples.size(), scan_z);
  EXPECT_LT(max_exr, 1e-6);
  EXPECT_LT(max_png, 1e-6);
  // Blender's image texture applies brightness/contrast as (v - 0.5) * 1 + 0.5 in float32: the
  // metre values (~1e-4) are rounded to the float32 grid at 0.5, one ulp = 2^-24 = 6e-8 m. The
  // Geometry Nodes image texture reads the float itself.
  EXPECT_LT(max_exr, 6e-8);
  EXPECT_LT(max_exr_nodes, 1e-9);
  EXPECT_LT(max_png, 0.5 * step + 1e-9);
  RecordProperty("blender_max_displacement_error_exr_m", std::to_string(max_exr));
  RecordProperty("blender_max_displacement_error_png_m", std::to_string(max_png));
  // The one-channel EXR (channel Y) is read as grey: R = G = B = the height.
  const auto& rgba = r.at("exr_first_sample_rgba");
  const double z0 = hf.z(samples[0][0].get<int>(), samples[0][1].get<int>());
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(rgba[k].get<double>(), z0, 1e-9) << "channel " << k;

  // 3. Normal maps. Baked shading normals against the scan's normals, pixel by pixel.
  auto compare = [&](const Json& bake, double y_sign) {
    return MaxBakedNormalError(bake, hf, scan_->normals, y_sign);
  };
  // 16-bit quantisation (1.5e-5 per component) and Cycles' float shading: 1e-3.
  EXPECT_LT(compare(r.at("bake_gl"), 1.0), 1e-3);
  EXPECT_LT(compare(r.at("bake_dx_inverted"), 1.0), 1e-3);
  // Read without the DirectX fix, the green is mirrored: the test can tell the two apart.
  EXPECT_LT(compare(r.at("bake_dx_as_gl"), -1.0), 1e-3);
  EXPECT_GT(compare(r.at("bake_dx_as_gl"), 1.0), 0.1);
  // Lit side: a light from the upper right (+x, +y, +z). The big bump's upper-right flank (at
  // 1 sigma towards +x+y) faces it, its lower-left flank faces away.
  auto lit = [&](const Json& bake, double x, double y) {
    const int i = static_cast<int>(std::lround(hf.I(x))),
              j = static_cast<int>(std::lround(hf.J(y)));
    const std::array<double, 3> b = BakedNormal(bake, i, j);
    return (b[0] + b[1] + b[2]) / std::sqrt(3.0);
  };
  const double s = 0.7e-3;
  for (const char* key : {"bake_gl", "bake_dx_inverted"}) {
    EXPECT_GT(lit(r.at(key), s, s), lit(r.at(key), -s, -s) + 0.1) << key;
    EXPECT_GT(lit(r.at(key), -s, s), lit(r.at(key), -s, -s) + 0.05) << key;  // y alone
  }
  EXPECT_LT(lit(r.at("bake_dx_as_gl"), -s, s), lit(r.at("bake_dx_as_gl"), -s, -s));
}

TEST_F(ExportConsumers, DecimatedGlbStatesItsErrorAndMeetsTheBudget) {
  const Json m = ReadJsonFile(root_ / "c/manifest.json");
  const Json* mesh = nullptr;
  for (const auto& f : m.at("files"))
    if (f.at("role") == "mesh") mesh = &f;
  ASSERT_NE(mesh, nullptr);
  EXPECT_LE(mesh->at("triangles").get<int64_t>(), 4000);
  EXPECT_GT(mesh->at("lossless_triangles").get<int64_t>(), 30000);
  const double err = mesh->at("max_height_error_m");
  EXPECT_GT(err, 0.0);
  EXPECT_LT(err, 20e-6);  // 4000 triangles over a 0.5 mm relief
}

}  // namespace
}  // namespace mesoscan
