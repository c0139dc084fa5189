// The demo coin's exports, checked by their real consumers: the coin is
// simulated exactly as scripts/demo does (the paper rig, the 400 x 400 camera window around the
// coin: rim, bead ring, lettering and portrait), reconstructed, exported in every format, and
//  - gltf-transform validate: zero errors on the lossless and on a decimated GLB;
//  - Blender 3.4 imports the GLB: vertex count and bounding box in metres equal the height
//    field's within 1e-6 m, the mesh's heights at sampled points are the height field's, and the
//    coin's size and relief read off the imported mesh match the object that was simulated
//    (assets/objects.h MakeCoin: 19 mm across, field 1.2 mm, rim 1.3 mm, letters 40 um);
//  - a plane displaced in Blender by the EXR height (midlevel 0, scale 1) and by the 16-bit PNG
//    (the sidecar's midlevel and scale) lands on the scan's heights within 1 um;
//  - the OpenGL normal map read through a Normal Map node gives back the scan's normals, and
//    the rim's inner flank is lit from the side it faces;
//  - iinfo / oiiotool read every EXR with its channels and grid attributes;
//  - `mesoscan export` prints where the exports are and one "how to load" line per map.
// The consumer helpers are shared with tests/export_consumers_test.cc (tests/export_consumers.h).

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iostream>
#include <set>
#include <sstream>
#include <vector>

#include "assets/objects.h"
#include "core/image_io.h"
#include "core/json.h"
#include "core/numbers.h"
#include "core/scan_folder.h"
#include "tests/export_consumers.h"

namespace mesoscan {
namespace {
using namespace consumers;  // NOLINT: the shared consumer helpers of tests/export_consumers.h

// scripts/demo's simulate step, verbatim (DemoScriptSimulatesThisCoin keeps the two in step).
constexpr const char* kDemoSimulate =
    "simulate --object coin --rig paper --crop 400x400+888+517 --focus-height 0";
// The simulated coin (assets/objects.cc MakeCoin).
constexpr double kCoinRadius = 9.5e-3, kField = 1.2e-3, kRim = 1.3e-3, kLetters = 40e-6;
// Decimated GLB: a third of the lossless mesh's ~300k triangles.
constexpr int64_t kDecimatedTriangles = 100'000;

double Median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

class ExportCoin : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = fs::temp_directory_path() / ("mesoscan_export_coin_test_" + std::to_string(getpid()));
    fs::remove_all(root_);
    fs::create_directories(root_);
    const std::string session = Q(root_ / "coin.session"), scan = Q(root_ / "coin.scan");
    std::string out;
    status_ = RunMesoscan(std::string("-q ") + kDemoSimulate + " --out " + session, &out);
    log_ = out;
    if (status_ == 0) status_ = RunMesoscan("-q reconstruct " + session + " --out " + scan, &out);
    log_ += out;
    // A: every format, as `make demo` runs it (not quiet: its printout is checked).
    if (status_ == 0)
      status_ = RunMesoscan("export " + scan + " --out " + Q(root_ / "a"), &export_log_);
    log_ += export_log_;
    // C: the decimated mesh.
    if (status_ == 0)
      status_ =
          RunMesoscan("-q export " + scan + " --out " + Q(root_ / "c") +
                          " --format glb --max-triangles " + std::to_string(kDecimatedTriangles),
                      &out);
    log_ += out;
    if (status_ != 0) return;
    scan_ = new Scan(ReadScanFolder(root_ / "coin.scan"));
    // The surface the GLB covers: the scan's heights with its holes filled as the export fills
    // them (the height EXR; pixels left at hole_value_m are holes still).
    filled_ = new HeightField(FilledSurface(scan_->height, root_ / "a", "coin"));
    mesh_ = new LosslessMesh(LosslessMeshOf(*filled_));
  }
  static void TearDownTestSuite() {
    delete scan_;
    delete filled_;
    delete mesh_;
    scan_ = nullptr;
    mesh_ = nullptr;
    std::error_code ec;
    fs::remove_all(root_,
                   ec);  // each ctest case is its own process: do not leave its folder behind
  }
  void SetUp() override { ASSERT_EQ(status_, 0) << log_; }

  void ExpectExportPrintsWhereAndOneLoadLinePerMap();
  void ExpectGltfTransformValidatesTheLosslessAndTheDecimatedGlb();
  void ExpectOiioReadsEveryExrWithItsChannelsAndAttributes();
  void ExpectDecimatedGlbMeetsItsBudgetWithAStatedError();
  void ExpectFilledHolesWithinTheirBorderRange();

  static Json MeshEntry(const fs::path& manifest) {
    const Json m = ReadJsonFile(manifest);
    for (const auto& f : m.at("files"))
      if (f.at("role") == "mesh") return f;
    return Json();
  }

  static inline fs::path root_;
  static inline Scan* scan_ = nullptr;
  static inline HeightField* filled_ = nullptr;
  static inline LosslessMesh* mesh_ = nullptr;
  static inline int status_ = -1;
  static inline std::string log_, export_log_;
};

TEST(ExportCoinDemo, DemoScriptSimulatesThisCoin) {
  std::ifstream in(kSource / "scripts/demo");
  std::stringstream demo;
  demo << in.rdbuf();
  EXPECT_NE(demo.str().find(std::string("\"$M\" ") + kDemoSimulate + " "), std::string::npos)
      << "scripts/demo no longer simulates `" << kDemoSimulate << "`: update kDemoSimulate";
  // The demo's export step is not quiet, so it prints the lines ExportPrintsOneLoadLinePerMap
  // checks.
  EXPECT_NE(demo.str().find("\"$M\" export "), std::string::npos);
}

// ctest runs each case in its own process, and each would simulate and reconstruct the coin
// again (~20 s of CPU): the checks that need no Blender share one case, as fixture methods.
void ExportCoin::ExpectExportPrintsWhereAndOneLoadLinePerMap() {
  const Json m = ReadJsonFile(root_ / "a/manifest.json");
  EXPECT_NE(export_log_.find("exports in " + fs::absolute(root_ / "a").lexically_normal().string() +
                             ":\n"),
            std::string::npos)
      << export_log_;
  std::set<std::string> roles;
  for (const auto& f : m.at("files")) {
    const std::string file = f.at("file"), role = f.at("role");
    roles.insert(role);
    if (role == "height sidecar") continue;  // named by the 16-bit height's line
    const std::string consumer = role == "points" ? "MeshLab" : "Blender: ";
    const size_t at = export_log_.find("\n  " + file + ": ");
    ASSERT_NE(at, std::string::npos) << file << " has no line in:\n" << export_log_;
    const std::string line = export_log_.substr(at + 1, export_log_.find('\n', at + 1) - at - 1);
    EXPECT_NE(line.find(consumer), std::string::npos) << line;
    if (role == "height" && f.at("format") == "png") {
      EXPECT_NE(line.find(f.at("sidecar").get<std::string>()), std::string::npos) << line;
    }
  }
  // Every map, the albedo from the session's white frame included.
  for (const char* r :
       {"height", "height sidecar", "normal", "confidence", "albedo", "mesh", "points"})
    EXPECT_TRUE(roles.count(r)) << r;
}

void ExportCoin::ExpectGltfTransformValidatesTheLosslessAndTheDecimatedGlb() {
  for (const fs::path& glb : {root_ / "a/coin.glb", root_ / "c/coin.glb"}) {
    const GltfValidation v = ValidateGlb(glb);
    EXPECT_TRUE(v.no_errors) << glb << "\n" << v.report;
    EXPECT_TRUE(v.no_warnings) << glb << "\n" << v.report;
  }
}

void ExportCoin::ExpectOiioReadsEveryExrWithItsChannelsAndAttributes() {
  int exrs = 0;
  const Json m = ReadJsonFile(root_ / "a/manifest.json");
  for (const auto& f : m.at("files")) {
    if (f.at("format") != "exr") continue;
    ++exrs;
    const bool height = f.at("role") == "height";
    ExpectIinfoReadsExr(root_ / "a" / f.at("file").get<std::string>(), scan_->height,
                        height ? "Y" : "R, G, B", height);
  }
  EXPECT_EQ(exrs, 2);  // the height and the OpenGL normal map
  ExpectOiiotoolStatsMatch(root_ / "a/coin_height.exr", scan_->height);
}

void ExportCoin::ExpectDecimatedGlbMeetsItsBudgetWithAStatedError() {
  const Json lossless = MeshEntry(root_ / "a/manifest.json"),
             dec = MeshEntry(root_ / "c/manifest.json");
  ASSERT_FALSE(lossless.is_null());
  ASSERT_FALSE(dec.is_null());
  // Lossless: every sample of a complete triangle of the filled surface is a vertex, no height
  // error. The demo coin's holes (around every letter, the rim's shadow) are all filled: the
  // mesh has no gap, and its filled vertices are flagged.
  EXPECT_EQ(lossless.at("vertices").get<int64_t>(), mesh_->vertices);
  int64_t measured = 0, holes_left = 0;
  for (size_t p = 0; p < filled_->z.pixels(); ++p) {
    measured += std::isfinite(scan_->height.z.data()[p]);
    holes_left += !std::isfinite(filled_->z.data()[p]);
  }
  EXPECT_EQ(holes_left, 0);
  EXPECT_EQ(mesh_->vertices, static_cast<int64_t>(filled_->z.pixels()));
  EXPECT_EQ(lossless.at("filled_vertices").get<int64_t>(), mesh_->vertices - measured);
  EXPECT_GT(lossless.at("filled_vertices").get<int64_t>(), 0);
  EXPECT_EQ(lossless.at("max_height_error_m").get<double>(), 0.0);
  EXPECT_LE(dec.at("triangles").get<int64_t>(), kDecimatedTriangles);
  EXPECT_TRUE(dec.at("budget_met").get<bool>());
  const double err = dec.at("max_height_error_m");
  EXPECT_GT(err, 0.0);
  RecordProperty("lossless_triangles", std::to_string(lossless.at("triangles").get<int64_t>()));
  RecordProperty("lossless_vertices", std::to_string(lossless.at("vertices").get<int64_t>()));
  RecordProperty("decimated_triangles", std::to_string(dec.at("triangles").get<int64_t>()));
  RecordProperty("decimated_vertices", std::to_string(dec.at("vertices").get<int64_t>()));
  RecordProperty("decimated_max_height_error_m", std::to_string(err));
  std::cout << "coin GLB: lossless " << lossless.at("triangles") << " triangles, "
            << lossless.at("vertices") << " vertices; decimated " << dec.at("triangles")
            << " triangles, " << dec.at("vertices") << " vertices, max height error " << err * 1e6
            << " um; filled vertices " << lossless.at("filled_vertices") << " of "
            << lossless.at("vertices") << ", holes left " << holes_left << "\n";
}

// The displacement has no trench where the coin's wall shadowed the projector. Every
// hole the export filled (a NaN of the scan, not holding hole_value_m in the EXR height) lies
// within the range of the measured heights bordering it, and the shadowed rim is among them.
void ExportCoin::ExpectFilledHolesWithinTheirBorderRange() {
  const Json m = ReadJsonFile(root_ / "a/manifest.json");
  const std::string name = m.at("name");
  const float hole_value = m.at("hole_value_m").get<float>();
  const ImageF h = ReadExrChannels(root_ / "a" / (name + "_height.exr"), {"Y"});
  const HeightField& s = scan_->height;
  ASSERT_EQ(h.width(), s.width());
  const int w = s.width(), ht = s.height();
  // 4-connected regions of filled pixels, each with the range of its measured border.
  std::vector<int> label(static_cast<size_t>(w) * ht, -1);
  int64_t filled = 0, regions = 0, outside = 0, near_rim = 0;
  for (int start = 0; start < w * ht; ++start) {
    if (std::isfinite(s.z.data()[start]) || h.data()[start] == hole_value || label[start] >= 0)
      continue;
    std::vector<int> stack{start}, pixels;
    label[start] = static_cast<int>(regions);
    float lo = 1e9f, hi = -1e9f;
    while (!stack.empty()) {
      const int p = stack.back();
      stack.pop_back();
      pixels.push_back(p);
      const int x = p % w, y = p / w;
      for (auto [dx, dy] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}}) {
        const int nx = x + dx, ny = y + dy;
        if (nx < 0 || ny < 0 || nx >= w || ny >= ht) continue;
        const int q = ny * w + nx;
        if (std::isfinite(s.z.data()[q])) {
          lo = std::min(lo, s.z.data()[q]), hi = std::max(hi, s.z.data()[q]);
        } else if (label[q] < 0) {
          label[q] = static_cast<int>(regions);
          stack.push_back(q);
        }
      }
    }
    ++regions;
    filled += static_cast<int64_t>(pixels.size());
    for (int p : pixels) {
      const float v = h.data()[p];
      if (v < lo - 1e-9f || v > hi + 1e-9f) ++outside;
      const double r = std::hypot(s.X(p % w), s.Y(p / w));
      if (r > kCoinRadius - 0.5e-3 && r < kCoinRadius + 1.5e-3) ++near_rim;
    }
  }
  std::cout << "coin export: " << filled << " filled pixels in " << regions << " holes, "
            << near_rim << " at the rim; outside their border's range: " << outside << "\n";
  EXPECT_EQ(outside, 0);
  EXPECT_GT(near_rim, 50);  // the wall's shadow at the rim is filled, not a trench
  EXPECT_EQ(m.at("fill").at("method"), "harmonic");
}

TEST_F(ExportCoin, ExportsAreAnnouncedDecimatedWithAStatedErrorAndReadByGltfTransformAndOiio) {
  ExpectFilledHolesWithinTheirBorderRange();
  ExpectExportPrintsWhereAndOneLoadLinePerMap();
  ExpectDecimatedGlbMeetsItsBudgetWithAStatedError();
  std::string missing;
  if (fs::exists(kGltfTransform))
    ExpectGltfTransformValidatesTheLosslessAndTheDecimatedGlb();
  else
    missing += kGltfTransform.string() + " (" + kInstall + ") ";
  if (!FindOnPath("iinfo").empty())
    ExpectOiioReadsEveryExrWithItsChannelsAndAttributes();
  else
    missing += "iinfo (apt-get install openimageio-tools)";
  if (!missing.empty()) GTEST_SKIP() << "missing: " << missing;
}

TEST_F(ExportCoin, BlenderOpensTheCoinAtItsSizeAndReliefAndDisplacesAndShadesIt) {
  const std::string blender = FindOnPath("blender");
  if (blender.empty()) GTEST_SKIP() << "blender missing: " << kInstall;
  const HeightField& hf = *filled_;
  const int w = hf.width(), h = hf.height();
  const Json side = ReadJsonFile(root_ / "a/coin_height.json");
  // Sample pixels (mesh vertices): every 3rd of every 3rd row, and the whole rows and columns
  // through the coin's centre (its diameter along x and y).
  const int ci = static_cast<int>(std::lround(hf.I(0.0))),
            cj = static_cast<int>(std::lround(hf.J(0.0)));
  std::vector<std::pair<int, int>> pixels;
  for (int j = 0; j < h; ++j)
    for (int i = 0; i < w; ++i)
      if (mesh_->vertex[static_cast<size_t>(j) * w + i] &&
          ((i % 3 == 0 && j % 3 == 0) || i == ci || j == cj))
        pixels.emplace_back(i, j);
  Json samples = Json::array(), points = Json::array();
  for (const auto& [i, j] : pixels) {
    samples.push_back({i, j});
    points.push_back({hf.X(i), hf.Y(j)});
  }
  Json cfg = BlenderConfig(root_ / "a", "coin", hf, samples);
  cfg["glb_points"] = points;
  const Json r = RunBlenderChecks(blender, root_, cfg);
  ASSERT_FALSE(r.is_null());

  // 1. The GLB as Blender imports it: vertices and bounding box of the lossless mesh.
  const Json& g = r.at("glb");
  ExpectGlbImportMatches(g, *mesh_, "coin_height.exr");
  const double size_x = g.at("bbox_max")[0].get<double>() - g.at("bbox_min")[0].get<double>();
  const double relief = g.at("bbox_max")[2].get<double>() - g.at("bbox_min")[2].get<double>();
  EXPECT_NEAR(relief, mesh_->hi[2] - mesh_->lo[2], 1e-6);
  // The imported mesh's heights at the sample points are the height field's.
  const Json& at = g.at("points");
  ASSERT_EQ(at.size(), pixels.size());
  std::vector<double> z_blender(pixels.size());
  double worst_xy = 0, worst_z = 0;
  for (size_t k = 0; k < pixels.size(); ++k) {
    const auto [i, j] = pixels[k];
    z_blender[k] = at[k][2].get<double>();
    worst_xy = std::max({worst_xy, std::abs(at[k][0].get<double>() - hf.X(i)),
                         std::abs(at[k][1].get<double>() - hf.Y(j))});
    worst_z = std::max(worst_z, std::abs(z_blender[k] - hf.z(i, j)));
  }
  EXPECT_LT(worst_xy, 1e-6);
  EXPECT_LT(worst_z, 1e-6);

  // 2. Size and relief of the coin read off Blender's mesh, against the simulated object. The
  // classes are taken from the true surface where a whole pixel footprint (+-1 px) is flat:
  // mount (0), field (1.2 mm), rim top (1.3 mm), letters (+40 um), the field between letters.
  const SceneObject coin = MakeObject("coin");
  const double px = hf.pixel_size;
  auto flat_at = [&](double x, double y, double z) {
    for (double dy : {-px, 0.0, px})
      for (double dx : {-px, 0.0, px})
        if (std::abs(coin.SurfaceZ(x + dx, y + dy) - z) > 1e-9) return false;
    return true;
  };
  std::vector<double> mount, field, rim, letters, between;
  for (size_t k = 0; k < pixels.size(); ++k) {
    const double x = hf.X(pixels[k].first), y = hf.Y(pixels[k].second), rr = std::hypot(x, y);
    if (rr > kCoinRadius + 3 * px && flat_at(x, y, 0.0)) mount.push_back(z_blender[k]);
    if (rr > 8.7e-3 && rr < 9.3e-3 && flat_at(x, y, kRim)) rim.push_back(z_blender[k]);
    if (rr > 5.8e-3 && rr < 6.6e-3 && flat_at(x, y, kField)) field.push_back(z_blender[k]);
    if (rr > 6.8e-3 && rr < 8.3e-3) {
      if (flat_at(x, y, kField + kLetters)) letters.push_back(z_blender[k]);
      if (flat_at(x, y, kField)) between.push_back(z_blender[k]);
    }
  }
  for (const auto* v : {&mount, &field, &rim, &letters, &between}) ASSERT_GE(v->size(), 50u);
  const double predicted =
      ReadJsonFile(root_ / "coin.scan/report.json").at("summary").at("predicted_depth_rms_m");
  const double z_mount = Median(mount), z_field = Median(field), z_rim = Median(rim);
  const double letter_relief = Median(letters) - Median(between);
  std::cout << "coin in Blender: size " << size_x * 1e3 << " mm, relief " << relief * 1e6
            << " um; medians: mount " << z_mount * 1e6 << " um, field " << z_field * 1e6
            << " um, rim " << z_rim * 1e6 << " um, letters " << letter_relief * 1e6
            << " um above the field (" << letters.size() << " / " << between.size()
            << " samples); predicted depth rms " << predicted * 1e6 << " um\n";
  // Each a median over >= 50 samples of noise predicted_depth_rms: well within one rms.
  EXPECT_NEAR(z_mount, 0.0, predicted);
  EXPECT_NEAR(z_field, kField, predicted);
  EXPECT_NEAR(z_rim, kRim, predicted);
  EXPECT_NEAR(letter_relief, kLetters, predicted);
  // Diameter along the central row and column, bracketed by the imported mesh's samples: the
  // outermost samples above half the field height (inner) and the first ones below it beyond
  // them (outer). The reconstruction drops the edge itself (rounded over its last 0.1 mm, too
  // steep: the discontinuity filter), at most 0.1 mm + 1 px a side (also on the mount's side);
  // along x, on the side away from the projector, the mount is in the coin's shadow for about
  // 1.3 mm * tan(20 deg) = 0.47 mm.
  auto diameter = [&](bool along_x) {
    std::vector<std::pair<double, double>> profile;  // (position, z)
    for (size_t k = 0; k < pixels.size(); ++k) {
      const auto [i, j] = pixels[k];
      if (!std::isfinite(scan_->height.z(i, j))) continue;  // measured samples only
      if (along_x ? j == cj : i == ci)
        profile.emplace_back(along_x ? hf.X(i) : hf.Y(j), z_blender[k]);
    }
    std::sort(profile.begin(), profile.end());
    size_t first = profile.size(), last = 0;
    for (size_t k = 0; k < profile.size(); ++k) {
      if (profile[k].second < kField / 2) continue;
      first = std::min(first, k);
      last = k;
    }
    EXPECT_TRUE(first > 0 && last + 1 < profile.size());
    if (first == 0 || last + 1 >= profile.size()) return std::pair{0.0, 0.0};
    return std::pair{profile[last].first - profile[first].first,
                     profile[last + 1].first - profile[first - 1].first};
  };
  const double shadow = 1.3e-3 * std::tan(20.0 * kPi / 180);
  for (const bool along_x : {true, false}) {
    const auto [inner, outer] = diameter(along_x);
    std::cout << "coin diameter in Blender along " << (along_x ? "x" : "y") << ": between "
              << inner * 1e3 << " and " << outer * 1e3 << " mm\n";
    EXPECT_LE(inner, 2 * kCoinRadius);
    EXPECT_GE(inner, 2 * kCoinRadius - 2 * (0.1e-3 + px));
    EXPECT_GE(outer, 2 * kCoinRadius);
    EXPECT_LE(outer, 2 * kCoinRadius + 2 * (0.1e-3 + px) + (along_x ? shadow : 0.0));
    RecordProperty(along_x ? "blender_coin_diameter_x_inner_m" : "blender_coin_diameter_y_inner_m",
                   std::to_string(inner));
  }
  RecordProperty("blender_rim_m", std::to_string(z_rim));
  RecordProperty("blender_letter_relief_m", std::to_string(letter_relief));

  // 3. Displacement of a plane by the height maps, at the sample pixels. EXR through Geometry
  // Nodes: the float itself. EXR through the Displace modifier: Blender's image texture clamps
  // values below 0 (the mount's noise), float32-rounded at 0.5 (6e-8 m); export.cc's hint
  // says so. PNG: within half its quantisation step.
  auto scan_z = [&](size_t k) {
    return static_cast<double>(hf.z(pixels[k].first, pixels[k].second));
  };
  const double step = side.at("quantisation_step_m");
  EXPECT_DOUBLE_EQ(step, side.at("scale").get<double>() / 65535.0);
  const double max_nodes = MaxDeviation(r.at("displace_exr_nodes"), pixels.size(), scan_z);
  const double max_png = MaxDeviation(r.at("displace_png"), pixels.size(), scan_z);
  const double max_exr = MaxDeviation(r.at("displace_exr"), pixels.size(), scan_z);
  const double max_clamped = MaxDeviation(r.at("displace_exr"), pixels.size(),
                                          [&](size_t k) { return std::max(0.0, scan_z(k)); });
  std::cout << "coin displacement in Blender (" << pixels.size() << " samples): EXR (nodes) "
            << max_nodes * 1e6 << " um, 16-bit PNG " << max_png * 1e6 << " um (step " << step * 1e6
            << " um), EXR (Displace modifier) " << max_exr * 1e6 << " um, " << max_clamped * 1e6
            << " um from max(z, 0)\n";
  EXPECT_LT(max_nodes, 1e-9);
  EXPECT_LT(max_png, 0.5 * step + 1e-9);
  EXPECT_LT(max_png, 1e-6);
  EXPECT_LT(max_clamped, 6e-8);
  RecordProperty("blender_max_displacement_error_exr_m", std::to_string(max_nodes));
  RecordProperty("blender_max_displacement_error_png_m", std::to_string(max_png));

  // 4. The OpenGL normal map through a Normal Map node: the scan's normals (16-bit
  // quantisation and Cycles' float shading: 1e-3), and the rim lit from the side it faces.
  const Json& bake = r.at("bake_gl");
  const double normal_error = MaxBakedNormalError(bake, scan_->height, scan_->normals, 1.0);
  EXPECT_LT(normal_error, 1e-3);
  // Mean baked normal over a flank: the valid samples at radii [r0, r1] within 30 degrees of
  // a direction whose scan normal is tilted by more than 0.2 (in any direction: the slope, not
  // its side, selects them).
  auto flank = [&](double r0, double r1, double dir_x, double dir_y) {
    double sum[3] = {0, 0, 0};
    int n = 0;
    for (int j = 0; j < h; ++j) {
      for (int i = 0; i < w; ++i) {
        const double x = hf.X(i), y = hf.Y(j), rr = std::hypot(x, y);
        if (!std::isfinite(hf.z(i, j)) || rr < r0 || rr > r1 ||
            x * dir_x + y * dir_y < rr * std::cos(kPi / 6) ||
            std::hypot(scan_->normals(i, j, 0), scan_->normals(i, j, 1)) < 0.2)
          continue;
        const std::array<double, 3> b = BakedNormal(bake, i, j);
        for (int k = 0; k < 3; ++k) sum[k] += b[k];
        ++n;
      }
    }
    EXPECT_GE(n, 10) << r0 << " " << dir_x << " " << dir_y;
    return std::array<double, 3>{sum[0] / n, sum[1] / n, sum[2] / n};
  };
  // The rim's inner flank (8.45 - 8.6 mm, 0.1 mm high) faces the centre. (Its outer slope, the
  // edge, is not in the scan: see the diameter above.) Lit by a light from (lx, ly, 1), the
  // side of the flank that faces the light is the brighter one, and its normal leans towards it.
  struct Flank {
    const char* name;
    double r0, r1, outwards;
  };
  for (const Flank& f : {Flank{"rim's inner flank", 8.4e-3, 8.65e-3, -1.0}}) {
    for (const auto& light : {std::pair{1.0, 0.0}, std::pair{0.0, 1.0}}) {
      const double lx = light.first, ly = light.second;
      const auto facing = flank(f.r0, f.r1, f.outwards * lx, f.outwards * ly);
      const auto away = flank(f.r0, f.r1, -f.outwards * lx, -f.outwards * ly);
      auto lit = [&](const std::array<double, 3>& n) {
        return (lx * n[0] + ly * n[1] + n[2]) / std::sqrt(2.0);
      };
      std::cout << "coin " << f.name << ", light from (" << lx << ", " << ly
                << ", 1): facing side lit " << lit(facing) << ", far side " << lit(away) << "\n";
      EXPECT_GT(lit(facing), lit(away) + 0.1) << f.name << " light (" << lx << ", " << ly << ")";
      EXPECT_GT(lx * facing[0] + ly * facing[1], 0.1) << f.name;
      EXPECT_LT(lx * away[0] + ly * away[1], -0.1) << f.name;
    }
  }
}

}  // namespace
}  // namespace mesoscan
