// `mesoscan maps` on a synthetic scan of the hammered-metal material sample
// (assets/objects.h MakeHammeredMetal: the truth is known), and its consumer, the Blender add-on:
//  - the CLI writes a finished, tileable map set: every manifest file exists, the tile is the
//    asked physical size, the seam gradient statistics are within 10% of the interior's, the
//    flattened height is the texture (the sample's tilt and sag removed) and the removed part
//    is written; it prints the one line that loads the set in Blender;
//  - bad input gives one line, a distinct exit code and no output folder;
//  - `--size N` resamples every map to N px (a tile on its period), the physical size kept;
//  - the tile is cut from the sample, not the bare mount around it (a simulated corner of the
//    woven fabric, the flatten fit on the fabric), `--tile-at` overrides the choice and a tile on
//    the mount is warned about;
//  - the albedo of `export` and `maps` has a value wherever the height has one (filled holes
//    included: no black outline around the coin's letters and rim);
//  - `export --tile` writes the same map set into OUT/maps next to the raw exports;
//  - Blender 3.4 installs the add-on zip, imports the set onto a plane of its physical size
//    with the expected node tree (Displacement Midlevel 0, Scale 1, world space, Repeat), a
//    Cycles render of its true displacement matches a plane displaced by the EXR in Python, and
//    the tile repeated 2 x 2 under raking light shows no seam (an untiled crop does).

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <string>
#include <vector>

#include "assets/objects.h"
#include "core/image_io.h"
#include "core/json.h"
#include "core/scan_folder.h"
#include "maps/maps_flatten.h"
#include "maps/maps_tile.h"
#include "tests/export_consumers.h"

namespace mesoscan {
namespace {
using namespace consumers;  // NOLINT: the shared consumer helpers

constexpr double kPixel = 50e-6;
constexpr double kTileMm = 8.0;

// The metal sample's interior (inside its margin), with small holes (shadows, rejected pixels)
// and one large one; the truth keeps every sample.
struct Synthetic {
  Scan scan;
  HeightField truth;
  ImageF albedo;
};

Synthetic MakeSynthetic() {
  const SceneObject metal = MakeHammeredMetal(kPixel);
  const int m = 10, w = metal.height.width() - 2 * m, h = metal.height.height() - 2 * m;
  Synthetic s;
  HeightField& hf = s.scan.height;
  hf.pixel_size = kPixel;
  hf.x0 = metal.height.X(m);
  hf.y0 = metal.height.Y(m);
  hf.z = ImageF(w, h, 1);
  hf.confidence = ImageF(w, h, 1, 0.9f);
  s.albedo = ImageF(w, h, 1);
  for (int j = 0; j < h; ++j)
    for (int i = 0; i < w; ++i) {
      hf.z(i, j) = metal.height.z(i + m, j + m);
      s.albedo(i, j) = metal.albedo(i + m, j + m);
    }
  s.truth = hf;
  for (int j = 0; j < h; ++j)
    for (int i = 0; i < w; ++i) {
      const bool small = ((i - 37) % 61 == 0 || (i - 38) % 61 == 0) && i < w - 5 &&
                         (j % 47) >= 10 && (j % 47) < 13;
      const bool large = std::hypot(i - 100.0, j - 480.0) < 40;  // 2 mm: stays a hole
      if (small || large) hf.z(i, j) = std::nanf(""), hf.confidence(i, j) = 0.0f;
    }
  s.scan.normals = hf.Normals();
  s.scan.points.xyz = ImageF(2, 2, 3, std::nanf(""));
  s.scan.points.confidence = ImageF(2, 2, 1, 0.0f);
  s.scan.points.projector_u = ImageF(2, 2, 1, std::nanf(""));
  s.scan.report = {{"note", "synthetic scan of tests/maps_cli_test.cc"}};
  return s;
}

class MapsCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = fs::temp_directory_path() / ("mesoscan_maps_cli_test_" + std::to_string(getpid()));
    fs::remove_all(root_);
    fs::create_directories(root_);
    syn_ = new Synthetic(MakeSynthetic());
    WriteScanFolder(root_ / "metal.scan", syn_->scan);
    WriteExr(root_ / "albedo.exr", syn_->albedo, {"Y"});
    const std::string scan = Q(root_ / "metal.scan");
    status_ = RunMesoscan("maps " + scan + " --out " + Q(root_ / "tiled") +
                              " --flatten poly:2 --tile 8 --roughness 0.35 --albedo " +
                              Q(root_ / "albedo.exr"),
                          &log_);
    // The untiled control: a square crop of the same size, flattened the same way.
    std::string out;
    const int n = static_cast<int>(std::lround(kTileMm * 1e-3 / kPixel));
    untiled_status_ = RunMesoscan("-q maps " + scan + " --out " + Q(root_ / "untiled") +
                                      " --flatten poly:2 --crop 200,100," + std::to_string(n) +
                                      "," + std::to_string(n) + " --maps height,normal,ao",
                                  &out);
    log_ += out;
    // The whole sample flattened, for the texture check.
    whole_status_ = RunMesoscan("-q maps " + scan + " --out " + Q(root_ / "whole") +
                                    " --flatten poly:2 --maps height,confidence",
                                &out);
    log_ += out;
  }
  static void TearDownTestSuite() {
    delete syn_;
    std::error_code ec;
    fs::remove_all(root_,
                   ec);  // each ctest case is its own process: do not leave its folder behind
  }
  void SetUp() override { ASSERT_EQ(status_, 0) << log_; }
  static inline fs::path root_;
  static inline Synthetic* syn_ = nullptr;
  static inline int status_ = -1, untiled_status_ = -1, whole_status_ = -1;
  static inline std::string log_;
};

TEST_F(MapsCli, WritesAFinishedTileableMapSet) {
  const Json m = ReadJsonFile(root_ / "tiled/manifest.json");
  EXPECT_EQ(m.at("format"), "mesoscan-maps/1");
  EXPECT_TRUE(m.at("tileable").get<bool>());
  const double size = m.at("tile").at("size_m");
  EXPECT_NEAR(size, kTileMm * 1e-3, kPixel / 2);
  EXPECT_NEAR(m.at("grid").at("physical_size_m")[0].get<double>(), size, 1e-12);
  std::set<std::string> roles;
  for (const auto& f : m.at("files")) {
    EXPECT_TRUE(fs::exists(root_ / "tiled" / f.at("file").get<std::string>())) << f.dump();
    roles.insert(f.at("role"));
  }
  for (const char* r : {"height", "height removed", "normal", "albedo", "confidence", "mask", "ao",
                        "curvature", "cavity", "roughness", "contact sheet"})
    EXPECT_TRUE(roles.count(r)) << r;
  // --roughness 0.35: a uniform 8-bit map of that value.
  const ImageF rough = ReadImage(root_ / "tiled/metal_roughness.png");
  for (float v : rough.data()) ASSERT_NEAR(v, 0.35f, 0.5f / 255) << "roughness map";
  // Seam gradient statistics: both seams pooled against the interior within 10%, and each seam
  // no outlier among single interior columns/rows (within 2.5 of their standard deviations:
  // the hammer dents are ~40 px wide, so one column of 160 samples scatters by that much).
  const Json& tile = m.at("tile");
  const auto ratio = tile.at("seam_gradient_ratio");
  const auto spread = tile.at("interior_column_row_spread");
  std::cout << "seam/interior gradient RMS: pooled " << tile.at("seam_gradient_ratio_pooled")
            << ", x " << ratio[0] << ", y " << ratio[1] << " (interior columns scatter "
            << spread[0] << ", rows " << spread[1] << "); untiled crop "
            << tile.at("seam_gradient_ratio_untiled") << "\n";
  EXPECT_NEAR(tile.at("seam_gradient_ratio_pooled").get<double>(), 1.0, 0.10);
  EXPECT_NEAR(ratio[0].get<double>(), 1.0, 2.5 * spread[0].get<double>());
  EXPECT_NEAR(ratio[1].get<double>(), 1.0, 2.5 * spread[1].get<double>());
  // The same statistics measured on the written EXR (not the manifest's word).
  const ImageF z = ReadExrChannels(root_ / "tiled/metal_height.exr", {"Y"});
  SeamStats measured;
  {
    HeightField f;
    f.z = z;
    measured = MeasureSeams(z);
  }
  EXPECT_NEAR(measured.pooled_ratio(), tile.at("seam_gradient_ratio_pooled").get<double>(), 1e-3);
  EXPECT_EQ(m.at("fill").at("holes_left"), 1);  // the 2 mm hole
  EXPECT_GT(m.at("fill").at("holes_filled").get<int>(), 10);
  EXPECT_NE(log_.find("load in Blender: blender --python-expr"), std::string::npos) << log_;
  EXPECT_NE(log_.find("import_scene.mesoscan_maps(filepath='" +
                      fs::absolute(root_ / "tiled/manifest.json").lexically_normal().string()),
            std::string::npos);
}

// Flatten on the sample: the whole sample's flattened height is the truth's texture (the tilt
// and sag of objects.cc SampleShape removed) within 1% RMS; flattened + removed = the scan.
// The hammer dents are a random field of ~2 mm cells, so over the 28 mm sample they have a
// quadratic component of their own (~sqrt(6 / 200) of their RMS) that no flatten can tell from
// the sample's shape: the reference is the texture minus its own least-squares quadratic (the
// raw figure is printed too).
TEST_F(MapsCli, FlattenedHeightIsTheTexture) {
  ASSERT_EQ(whole_status_, 0) << log_;
  const ImageF z = ReadExrChannels(root_ / "whole/metal_height.exr", {"Y"});
  const ImageF removed = ReadExrChannels(root_ / "whole/metal_height_removed.exr", {"Y"});
  const HeightField& t = syn_->truth;
  ASSERT_EQ(z.width(), t.width());
  const ImageU8 mask = [&] {
    const ImageF mf = ReadImage(root_ / "whole/metal_mask.png");
    ImageU8 m(mf.width(), mf.height(), 1);
    for (size_t p = 0; p < m.pixels(); ++p) m.data()[p] = mf.data()[p] > 0.99f ? 1 : 0;  // measured
    return m;
  }();
  std::vector<double> tex(t.z.pixels(), 0.0);
  double mz = 0, mt = 0;
  int64_t cnt = 0;
  for (int j = 0; j < t.height(); ++j)
    for (int i = 0; i < t.width(); ++i) {
      const size_t p = static_cast<size_t>(j) * t.width() + i;
      const float s = syn_->scan.height.z.data()[p];
      if (!std::isfinite(s) || !mask.data()[p]) continue;
      ASSERT_NEAR(z.data()[p] + removed.data()[p], s, 1e-9);
      const double x = t.X(i), y = t.Y(j);
      const double shape = 0.8e-3 + 0.010 * x - 0.006 * y -
                           0.15e-3 * (x * x + y * y) / (kMaterialHalfM * kMaterialHalfM);
      tex[p] = t.z.data()[p] - shape;
      mz += z.data()[p], mt += tex[p], ++cnt;
    }
  mz /= cnt, mt /= cnt;
  // The texture's own quadratic, by plain least squares (one iteration: no robust weights).
  HeightField tf = t;
  for (size_t p = 0; p < tex.size(); ++p)
    tf.z.data()[p] = std::isfinite(syn_->scan.height.z.data()[p]) && mask.data()[p]
                         ? static_cast<float>(tex[p])
                         : NAN;
  FlattenOptions ls = ParseFlatten("poly:2");
  ls.irls_iterations = 1;
  const FlattenResult own = Flatten(tf, ImageU8(), ls);
  double mo = 0;
  for (size_t p = 0; p < tex.size(); ++p)
    if (std::isfinite(tf.z.data()[p])) mo += own.field.z.data()[p];
  mo /= cnt;
  double e2 = 0, t2 = 0, raw2 = 0;
  for (size_t p = 0; p < tex.size(); ++p) {
    if (!std::isfinite(tf.z.data()[p])) continue;
    e2 += std::pow((z.data()[p] - mz) - (own.field.z.data()[p] - mo), 2);
    raw2 += std::pow((z.data()[p] - mz) - (tex[p] - mt), 2);
    t2 += std::pow(tex[p] - mt, 2);
  }
  std::cout << "flattened vs texture: " << std::sqrt(e2 / t2) * 100
            << "% RMS (vs the raw texture with its "
            << "own quadratic: " << std::sqrt(raw2 / t2) * 100 << "%) over " << cnt << " px\n";
  EXPECT_LT(std::sqrt(e2 / t2), 0.01);
}

TEST_F(MapsCli, BadInputIsOneLineAndNoOutput) {
  std::string out;
  EXPECT_EQ(RunMesoscan("maps " + Q(root_ / "nope.scan") + " --out " + Q(root_ / "bad1"), &out), 3)
      << out;
  EXPECT_FALSE(fs::exists(root_ / "bad1"));
  EXPECT_EQ(RunMesoscan("maps " + Q(root_ / "metal.scan") + " --out " + Q(root_ / "bad2") +
                            " --flatten poly:9",
                        &out),
            2)
      << out;
  EXPECT_NE(out.find("--flatten"), std::string::npos) << out;
  EXPECT_EQ(
      RunMesoscan("maps " + Q(root_ / "metal.scan") + " --out " + Q(root_ / "bad3") + " --tile 200",
                  &out),
      3)
      << out;
  EXPECT_NE(out.find("--tile"), std::string::npos) << out;
  EXPECT_FALSE(fs::exists(root_ / "bad3"));
  EXPECT_EQ(RunMesoscan(
                "maps " + Q(root_ / "metal.scan") + " --out " + Q(root_ / "bad4") + " --fill cubic",
                &out),
            2)
      << out;
  EXPECT_EQ(RunMesoscan("maps " + Q(root_ / "metal.scan") + " --out " + Q(root_ / "bad5") +
                            " --maps height,gloss",
                        &out),
            2)
      << out;
}

// --size: every map of the tile (160 px native) resampled to 256 px on its period; the manifest
// keeps the physical size, the height keeps its RMS (the texture is sampled well above its
// detail, so band-limited resampling keeps its variance) and its seams stay those of the
// interior, as the native tile's are held to (10%). Untiled: the longest side is N.
TEST_F(MapsCli, SizeResamplesEveryMapToAPowerOfTwoKeepingThePhysicalSize) {
  std::string out;
  const std::string scan = Q(root_ / "metal.scan");
  ASSERT_EQ(
      RunMesoscan("-q maps " + scan + " --out " + Q(root_ / "sized") +
                      " --flatten poly:2 --tile 8 --size 256 --albedo " + Q(root_ / "albedo.exr"),
                  &out),
      0)
      << out;
  const Json m = ReadJsonFile(root_ / "sized/manifest.json");
  const Json native = ReadJsonFile(root_ / "tiled/manifest.json");
  const Json& g = m.at("grid");
  EXPECT_EQ(g.at("width_px"), 256);
  EXPECT_EQ(g.at("height_px"), 256);
  const double size = native.at("grid").at("physical_size_m")[0];
  EXPECT_NEAR(g.at("physical_size_m")[0].get<double>(), size, 1e-9);
  EXPECT_NEAR(g.at("pixel_size_m").get<double>() * 256, size, 1e-9);
  EXPECT_NEAR(m.at("tile").at("size_m").get<double>(), size, 1e-9);
  int maps = 0;
  for (const Json& f : m.at("files")) {
    const std::string role = f.at("role");
    if (role == "contact sheet" || role == "height sidecar" || role == "height removed") continue;
    const ImageInfo info = ReadImageInfo(root_ / "sized" / f.at("file").get<std::string>());
    EXPECT_EQ(info.width, 256) << f.dump();
    EXPECT_EQ(info.height, 256) << f.dump();
    ++maps;
  }
  EXPECT_GE(maps, 8);  // height x2, normal x2, albedo, confidence, mask, ao, curvature, cavity
  auto rms = [](const ImageF& z) {
    double s = 0, s2 = 0;
    for (float v : z.data()) s += v, s2 += static_cast<double>(v) * v;
    const double mean = s / z.pixels();
    return std::sqrt(s2 / z.pixels() - mean * mean);
  };
  const ImageF z = ReadExrChannels(root_ / "sized/metal_height.exr", {"Y"});
  const ImageF z0 = ReadExrChannels(root_ / "tiled/metal_height.exr", {"Y"});
  const SeamStats seams = MeasureSeams(z);
  std::cout << "256 px: height RMS " << rms(z) << " m (native 160 px: " << rms(z0)
            << "), seam/interior gradient RMS pooled " << seams.pooled_ratio() << "\n";
  EXPECT_NEAR(rms(z) / rms(z0), 1.0, 0.02);
  EXPECT_NEAR(seams.pooled_ratio(), 1.0, 0.10);
  // Untiled: the longest side N.
  ASSERT_EQ(RunMesoscan("-q maps " + scan + " --out " + Q(root_ / "sized_whole") +
                            " --size 64 --maps height",
                        &out),
            0)
      << out;
  const Json w = ReadJsonFile(root_ / "sized_whole/manifest.json").at("grid");
  EXPECT_EQ(std::max(w.at("width_px").get<int>(), w.at("height_px").get<int>()), 64) << w.dump();
  // Not a power of two: one line naming --size, exit 2, no output.
  EXPECT_EQ(RunMesoscan("maps " + scan + " --out " + Q(root_ / "bad_size") + " --size 300", &out),
            2)
      << out;
  EXPECT_NE(out.find("--size"), std::string::npos) << out;
  EXPECT_FALSE(fs::exists(root_ / "bad_size"));
}

TEST_F(MapsCli, ExportWritesTheMapSetNextToTheRawExports) {
  std::string out;
  ASSERT_EQ(RunMesoscan("export " + Q(root_ / "metal.scan") + " --out " + Q(root_ / "export") +
                            " --format exr,png16,glb --flatten plane --tile 6 --roughness 0.4",
                        &out),
            0)
      << out;
  EXPECT_TRUE(fs::exists(root_ / "export/manifest.json"));
  const Json m = ReadJsonFile(root_ / "export/maps/manifest.json");
  EXPECT_TRUE(m.at("tileable").get<bool>());
  EXPECT_NEAR(m.at("tile").at("size_m").get<double>(), 6e-3, kPixel / 2);
  // The GLB's material carries the set's roughness and an ambient-occlusion texture; the printed
  // Blender hint names the smooth shading the importer needs.
  std::ifstream glb(root_ / "export/metal.glb", std::ios::binary);
  ASSERT_TRUE(glb) << out;
  std::string bytes((std::istreambuf_iterator<char>(glb)), std::istreambuf_iterator<char>());
  ASSERT_GT(bytes.size(), 20u);
  uint32_t json_len = 0;
  std::memcpy(&json_len, bytes.data() + 12, 4);
  const Json g = Json::parse(bytes.substr(20, json_len));
  const Json& mat = g.at("materials").at(0);
  EXPECT_NEAR(mat.at("pbrMetallicRoughness").at("roughnessFactor").get<double>(), 0.4, 1e-9);
  ASSERT_TRUE(mat.contains("occlusionTexture")) << mat.dump();
  const int ao = mat.at("occlusionTexture").at("index");
  EXPECT_EQ(g.at("textures").at(ao).at("name"), "metal_ao");
  EXPECT_NE(out.find("import_shading='SMOOTH'"), std::string::npos) << out;
}

TEST_F(MapsCli, BlenderImportsTheSetAtTrueScaleAndTheTileHasNoSeam) {
  const std::string blender = FindOnPath("blender");
  if (blender.empty()) GTEST_SKIP() << "blender missing: " << kInstall;
  ASSERT_EQ(untiled_status_, 0) << log_;
  const fs::path zip = MESOSCAN_ADDON_ZIP;
  ASSERT_TRUE(fs::exists(zip)) << zip;
  const fs::path tmp = root_ / "blender";
  fs::create_directories(tmp / "user_scripts");
  const Json cfg = {{"addon_zip", zip.string()},
                    {"manifest", (root_ / "tiled/manifest.json").string()},
                    {"manifest_untiled", (root_ / "untiled/manifest.json").string()},
                    {"tmp", tmp.string()},
                    {"out", (tmp / "out.json").string()},
                    {"samples", 8},
                    {"render_px", 160}};
  WriteJsonFile(tmp / "cfg.json", cfg);
  std::string log;
  // The add-on is installed into a scratch user-scripts folder, not the user's own.
  const int status = RunCommand("BLENDER_USER_SCRIPTS=" + Q(tmp / "user_scripts") + " " + blender +
                                    " -b --factory-startup --python-exit-code 1 -P " +
                                    Q(kSource / "tests/consumers/blender_maps_checks.py") + " -- " +
                                    Q(tmp / "cfg.json"),
                                &log);
  ASSERT_EQ(status, 0) << log;
  const Json r = ReadJsonFile(tmp / "out.json");
  std::cout << r.dump(1) << "\n";
  const Json m = ReadJsonFile(root_ / "tiled/manifest.json");
  const double size = m.at("tile").at("size_m");
  // The plane is the tile's physical size; displacement true scale in world units.
  EXPECT_NEAR(r.at("dimensions")[0].get<double>(), size, 1e-6);
  EXPECT_NEAR(r.at("dimensions")[1].get<double>(), size, 1e-6);
  EXPECT_EQ(r.at("displacement").at("midlevel").get<double>(), 0.0);
  EXPECT_EQ(r.at("displacement").at("scale").get<double>(), 1.0);
  EXPECT_EQ(r.at("displacement").at("space"), "WORLD");
  EXPECT_EQ(r.at("displacement_method"), "DISPLACEMENT");
  const Json& links = r.at("links");
  auto has = [&](const std::string& l) {
    return std::find(links.begin(), links.end(), l) != links.end();
  };
  EXPECT_TRUE(has("height.Color->mesoscan displacement.Height")) << links.dump();
  EXPECT_TRUE(has("mesoscan displacement.Displacement->Material Output.Displacement"))
      << links.dump();
  EXPECT_TRUE(has("normal.Color->mesoscan normal map.Color")) << links.dump();
  EXPECT_TRUE(has("albedo.Color->mesoscan albedo x ao.Color1")) << links.dump();
  EXPECT_TRUE(has("ao.Color->mesoscan albedo x ao.Color2")) << links.dump();
  EXPECT_TRUE(has("mesoscan albedo x ao.Color->Principled BSDF.Base Color")) << links.dump();
  EXPECT_TRUE(has("roughness.Color->Principled BSDF.Roughness")) << links.dump();
  const Json& images = r.at("images");
  EXPECT_EQ(images.at("height").at("colorspace"), "Non-Color");
  EXPECT_EQ(images.at("albedo").at("colorspace"), "sRGB");
  EXPECT_EQ(images.at("height").at("extension"), "REPEAT");
  EXPECT_EQ(images.at("height").at("file"), "metal_height.exr");
  // Cycles' true displacement against the EXR-displaced reference (same seed, same samples):
  // the difference is a small fraction of what the relief itself changes in the image (the
  // same plane undisplaced), which is itself visible (> 0.5% of the mean).
  const Json& ren = r.at("render");
  EXPECT_GT(ren.at("addon_vs_flat_mean_abs").get<double>(), 0.005 * ren.at("mean").get<double>());
  EXPECT_LT(ren.at("addon_vs_reference_mean_abs").get<double>(),
            0.1 * ren.at("addon_vs_flat_mean_abs").get<double>());
  // The seam: the tile repeated 2 x 2 under raking light; the rendered change across the seam
  // is no outlier among the image's other columns (rows): |z| < 2, and its ratio to their mean
  // is within 0.6-1.4 (the dents are ~40 px wide, so single columns scatter widely); the
  // untiled crop's seam is at least 1.5x (measured: 3.3x along x).
  const Json& st = r.at("seam_tiled");
  const Json& su = r.at("seam_untiled");
  for (const char* a : {"x", "y"}) {
    EXPECT_LT(std::abs(st.at(std::string(a) + "_z").get<double>()), 2.0) << a;
    EXPECT_NEAR(st.at(std::string(a) + "_ratio").get<double>(), 1.0, 0.4) << a;
  }
  EXPECT_GT(std::max(su.at("x_ratio").get<double>(), su.at("y_ratio").get<double>()), 1.5);
}

// A corner of the woven fabric (assets/objects.h MakeFabric: a 30 mm square centred on the
// origin) with the bare mount around it, through the virtual rig: a 200 x 200 crop of the paper
// rig's camera (55 um on the mount) whose lower-right 85 x 85 px are fabric, reconstructed and
// made into a 4 mm (73 px) tile. The mount is flat and fully measured while the weave's steep
// flanks are rejected and filled, so "the square with the fewest filled pixels" took the mount
// (at (40, 63): entirely off the fabric).
class MapsTileCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = fs::temp_directory_path() / ("mesoscan_maps_tile_cli_test_" + std::to_string(getpid()));
    fs::remove_all(root_);
    fs::create_directories(root_);
    const std::string session = Q(root_ / "corner.session"), scan = Q(root_ / "corner.scan");
    std::string out;
    status_ = RunMesoscan(
        "-q simulate --object fabric --crop 700,330,200,200 --supersample 1 "
        "--object-pixel-size 40e-6 --ls-frames 20 --out " +
            session,
        &log_);
    if (status_ == 0) status_ = RunMesoscan("-q reconstruct " + session + " --out " + scan, &out);
    log_ += out;
    if (status_ == 0)
      status_ = RunMesoscan("maps " + scan + " --out " + Q(root_ / "tile") +
                                " --flatten poly:2 --tile 4 --maps height,albedo",
                            &auto_log_);
    log_ += auto_log_;
    if (status_ == 0)
      status_ = RunMesoscan("maps " + scan + " --out " + Q(root_ / "at") +
                                " --flatten poly:2 --tile 4 --tile-at 10,12 --maps height",
                            &at_log_);
    log_ += at_log_;
    // The whole grid untiled: its mask says which pixels were filled.
    if (status_ == 0)
      status_ = RunMesoscan(
          "-q maps " + scan + " --out " + Q(root_ / "whole") + " --maps height,confidence", &out);
    log_ += out;
  }
  static void TearDownTestSuite() {
    std::error_code ec;
    fs::remove_all(root_, ec);
  }
  void SetUp() override { ASSERT_EQ(status_, 0) << log_; }
  static inline fs::path root_;
  static inline int status_ = -1;
  static inline std::string log_, auto_log_, at_log_;
};

TEST_F(MapsTileCli, TheTileLiesOnTheSample) {
  const Json m = ReadJsonFile(root_ / "tile/manifest.json");
  const Json& t = m.at("tile");
  std::cout << auto_log_;
  EXPECT_EQ(t.at("source_chosen"), "on the sample");
  EXPECT_GE(t.at("on_sample_fraction").get<double>(), 0.95) << t.dump();
  // The flatten is fit on the fabric, not on the mount around it.
  const std::string region = m.at("flatten").value("fit_region", "");
  EXPECT_EQ(region.rfind("the sample's measured pixels", 0), 0u) << m.at("flatten").dump();
  // Ground truth: the source square (grid pixel centres x0 + i p, y0 - j p) lies on the fabric.
  const double p = m.at("grid").at("pixel_size_m"), x0 = m.at("grid").at("x0_m"),
               y0 = m.at("grid").at("y0_m");
  const int n = t.at("source_square_px")[2];
  EXPECT_GE(x0, -kMaterialHalfM);
  EXPECT_LE(x0 + (n - 1) * p, kMaterialHalfM);
  EXPECT_LE(y0, kMaterialHalfM);
  EXPECT_GE(y0 - (n - 1) * p, -kMaterialHalfM);
  // The printed square is the manifest's.
  const Json sq = t.at("source_square_height_grid_px");
  EXPECT_NE(auto_log_.find("px square at (" + std::to_string(sq[0].get<int>()) + ", " +
                           std::to_string(sq[1].get<int>()) + ") of the height grid"),
            std::string::npos);
  // Its filled fraction is the share of filled pixels (mask 128) of the whole grid's map set in
  // that square.
  const ImageF mask = ReadImage(root_ / "whole/corner_mask.png");
  int64_t filled = 0;
  for (int y = sq[1]; y < sq[1].get<int>() + n; ++y)
    for (int x = sq[0]; x < sq[0].get<int>() + n; ++x)
      filled += std::abs(mask(x, y) - 128 / 255.0f) < 1e-3f;
  EXPECT_NEAR(t.at("filled_fraction").get<double>(), static_cast<double>(filled) / (n * n), 1e-9);
  // As measured as the fabric is on average: the reconstruction rejects the weave's steep flanks
  // (mixed pixels), so a third of the fabric is filled and no square of it is 80% measured; the
  // tile is not allowed to be worse than the fabric's own measured share (its pixels 0.2 mm
  // inside the fabric's edge), less the 5-point band it is chosen from.
  const Json g = ReadJsonFile(root_ / "whole/manifest.json").at("grid");
  const double gp = g.at("pixel_size_m"), gx0 = g.at("x0_m"), gy0 = g.at("y0_m");
  int64_t inside = 0, measured = 0;
  for (int y = 0; y < mask.height(); ++y)
    for (int x = 0; x < mask.width(); ++x)
      if (std::abs(gx0 + x * gp) < kMaterialHalfM - 0.2e-3 &&
          std::abs(gy0 - y * gp) < kMaterialHalfM - 0.2e-3)
        ++inside, measured += mask(x, y) > 0.99f;
  ASSERT_GT(inside, n * n);
  const double fabric_measured = static_cast<double>(measured) / inside;
  std::cout << "tile: " << t.at("on_sample_fraction").get<double>() << " on the sample, "
            << t.at("measured_on_sample_fraction").get<double>()
            << " measured there; the fabric: " << fabric_measured << " measured\n";
  EXPECT_GE(t.at("measured_on_sample_fraction").get<double>(), fabric_measured - 0.05);
  // The contact sheet's first panel is the scan with the square in red, where it was taken
  // (the panel: 320 px wide at (8, 34), the 199 px grid scaled by 320 / 199).
  const ImageF sheet = ReadImage(root_ / "tile/corner_contact_sheet.png");
  const int gw = m.at("source_grid").at("width_px"), gh = m.at("source_grid").at("height_px");
  const double s = 320.0 / std::max(gw, gh);
  int rx0 = 1 << 30, ry0 = 1 << 30, rx1 = -1, ry1 = -1;
  for (int y = 34; y < 34 + 320; ++y)
    for (int x = 8; x < 8 + 320; ++x)
      if (sheet(x, y, 0) > 0.9f && sheet(x, y, 1) < 0.1f && sheet(x, y, 2) < 0.1f)
        rx0 = std::min(rx0, x), ry0 = std::min(ry0, y), rx1 = std::max(rx1, x),
        ry1 = std::max(ry1, y);
  ASSERT_GE(rx1, 0) << "no red square on the contact sheet";
  EXPECT_NEAR(rx0, 8 + sq[0].get<int>() * s, 2);
  EXPECT_NEAR(ry0, 34 + sq[1].get<int>() * s, 2);
  EXPECT_NEAR(rx1, 8 + (sq[0].get<int>() + n) * s, 3);
  EXPECT_NEAR(ry1, 34 + (sq[1].get<int>() + n) * s, 3);
}

TEST_F(MapsTileCli, TileAtOverridesAndATileOnTheMountIsWarnedAbout) {
  const Json t = ReadJsonFile(root_ / "at/manifest.json").at("tile");
  EXPECT_EQ(t.at("source_chosen"), "given");
  EXPECT_EQ(t.at("source_square_height_grid_px"), Json({10, 12, 73}));
  EXPECT_LT(t.at("on_sample_fraction").get<double>(), 0.05);  // the bare mount
  EXPECT_NE(at_log_.find("stands off the mount"), std::string::npos) << at_log_;
  EXPECT_EQ(auto_log_.find("stands off the mount"), std::string::npos) << auto_log_;
  // A square leaving the grid: one line naming --tile-at, exit 2, no output.
  std::string out;
  EXPECT_EQ(RunMesoscan("maps " + Q(root_ / "corner.scan") + " --out " + Q(root_ / "bad") +
                            " --tile 4 --tile-at 150,0",
                        &out),
            2)
      << out;
  EXPECT_NE(out.find("--tile-at"), std::string::npos) << out;
  EXPECT_FALSE(fs::exists(root_ / "bad"));
}

// The fabric's tile (4 mm, the whole map set) repeated 3 x 3 on the add-on's plane and rendered
// by Blender in Eevee and Cycles (tests/consumers/blender_seam_checks.py: top-down, about one
// pixel per texel, raking light): the mean change across each seam (where the repeats meet, or
// where the blend's shifted copies met inside the tile) against the interior columns' (rows')
// mean, in units of their own standard deviation. Asserted: |z| <= 1, no seam differs from the
// interior by more than the interior's own scatter (a crop forced to repeat has a seam several
// times the interior's change). Measured: repeats Eevee -0.72..-0.53, Cycles -0.69..-0.13;
// blend lines Eevee -0.92..+0.86, Cycles -0.58..-0.10 (the weave's flanks make single columns
// scatter; the wrap seam and the blend lines lie where the slope and the shading change are
// typical; Eevee shades with the normal map, Cycles displaces). Also the selected-object import
// on a sphere: box projection, the normal map unlinked.
TEST_F(MapsTileCli, BlenderRendersAThreeByThreeRepeatWithoutSeams) {
  const std::string blender = FindOnPath("blender");
  if (blender.empty()) GTEST_SKIP() << "blender missing: " << kInstall;
  const fs::path zip = MESOSCAN_ADDON_ZIP;
  ASSERT_TRUE(fs::exists(zip)) << zip;
  std::string out;
  ASSERT_EQ(RunMesoscan("-q maps " + Q(root_ / "corner.scan") + " --out " + Q(root_ / "set") +
                            " --flatten poly:2 --tile 4 --maps height,normal,albedo,ao",
                        &out),
            0)
      << out;
  const fs::path tmp = root_ / "blender_seams";
  fs::create_directories(tmp / "user_scripts");
  const Json cfg = {{"addon_zip", zip.string()},
                    {"manifest", (root_ / "set/manifest.json").string()},
                    {"tmp", tmp.string()},
                    {"out", (tmp / "out.json").string()},
                    {"engines", {"BLENDER_EEVEE", "CYCLES"}},
                    {"eevee_samples", 2},
                    {"cycles_samples", 4}};
  WriteJsonFile(tmp / "cfg.json", cfg);
  std::string log;
  const int status = RunCommand("BLENDER_USER_SCRIPTS=" + Q(tmp / "user_scripts") + " " + blender +
                                    " -b --factory-startup --python-exit-code 1 -P " +
                                    Q(kSource / "tests/consumers/blender_seam_checks.py") + " -- " +
                                    Q(tmp / "cfg.json"),
                                &log);
  ASSERT_EQ(status, 0) << log;
  const Json r = ReadJsonFile(tmp / "out.json");
  for (const char* engine : {"BLENDER_EEVEE", "CYCLES"}) {
    const Json& e = r.at(engine);
    if (e.contains("error")) {
      // Eevee needs an OpenGL context (Blender falls back to surfaceless EGL in background
      // mode); without one the Eevee half is reported, not asserted. Cycles always runs.
      std::cout << engine << " could not render: " << e.at("error") << "\n";
      EXPECT_STREQ(engine, "BLENDER_EEVEE");
      continue;
    }
    for (const char* seam : {"x_repeat", "y_repeat", "x_blend", "y_blend"}) {
      if (!e.contains(seam)) continue;
      const Json& sj = e.at(seam);
      std::cout << engine << " " << seam << ": z " << sj.at("z").dump() << " (interior "
                << sj.at("interior_mean").get<double>() << " +- "
                << sj.at("interior_std").get<double>() << ")\n";
      for (const auto& z : sj.at("z"))
        EXPECT_LE(std::abs(z.get<double>()), 1.0) << engine << " " << seam;
    }
  }
  const Json& sphere = r.at("sphere");
  EXPECT_EQ(sphere.at("projections"), Json::array({"BOX"})) << sphere.dump();
  EXPECT_FALSE(sphere.at("normal_linked").get<bool>());
  EXPECT_EQ(sphere.at("displacement_method"), "BOTH");
}

// The coin's rim and lettering through the virtual rig (a 140 x 140 crop at the coin's left
// edge, focused on the mount as scripts/demo does): the rim's flank and the letters' edges are
// rejected and filled in the height; the albedo there was left 0 (black outlines, min 0).
TEST(MapsAlbedoCli, TheAlbedoIsFilledWhereTheHeightIs) {
  const fs::path root =
      fs::temp_directory_path() / ("mesoscan_maps_albedo_cli_test_" + std::to_string(getpid()));
  fs::remove_all(root);
  fs::create_directories(root);
  std::string out;
  const std::string scan = Q(root / "rim.scan");
  ASSERT_EQ(RunMesoscan("-q simulate --object coin --crop 880,640,140,140 --focus-height 0 "
                        "--supersample 1 --object-pixel-size 20e-6 --ls-frames 20 --out " +
                            Q(root / "rim.session"),
                        &out),
            0)
      << out;
  ASSERT_EQ(RunMesoscan("-q reconstruct " + Q(root / "rim.session") + " --out " + scan, &out), 0)
      << out;
  ASSERT_EQ(
      RunMesoscan("-q export " + scan + " --out " + Q(root / "export") + " --format png16", &out),
      0)
      << out;
  ASSERT_EQ(RunMesoscan("-q maps " + scan + " --out " + Q(root / "maps") +
                            " --maps height,albedo,confidence",
                        &out),
            0)
      << out;
  for (const fs::path& dir : {root / "export", root / "maps"}) {
    const Json m = ReadJsonFile(dir / "manifest.json");
    const Json& fill = m.at("fill");
    ASSERT_GT(fill.at("pixels_filled").get<int64_t>(), 100) << fill.dump();  // holes to fill
    ASSERT_EQ(fill.at("pixels_left").get<int64_t>(), 0) << fill.dump();      // a height everywhere
    const ImageF albedo = ReadImage(dir / "rim_albedo.png");
    const ImageF conf = ReadImage(dir / "rim_confidence.png");
    // The measured albedo's 1st percentile, and the darkest pixel anywhere (filled ones included).
    std::vector<float> measured;
    float darkest = 1;
    for (size_t p = 0; p < albedo.pixels(); ++p) {
      darkest = std::min(darkest, albedo.data()[p]);
      if (conf.data()[p] > 0) measured.push_back(albedo.data()[p]);
    }
    ASSERT_FALSE(measured.empty());
    std::nth_element(measured.begin(), measured.begin() + measured.size() / 100, measured.end());
    const float p1 = measured[measured.size() / 100];
    std::cout << dir.filename() << ": albedo (sRGB) darkest " << darkest
              << ", measured 1st percentile " << p1 << "\n";
    EXPECT_GE(darkest, 0.5f * p1) << dir;
  }
  std::error_code ec;
  fs::remove_all(root, ec);
}

}  // namespace
}  // namespace mesoscan
