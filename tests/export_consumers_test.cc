// The exports checked by their real consumers (issue 4): `mesoscan export` on a synthetic
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
// with the command that installs it.

#include <unistd.h>

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "core/json.h"
#include "core/scan_folder.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

const fs::path kSource = MESOSCAN_SOURCE_DIR;
const fs::path kExe = MESOSCAN_EXE;
const fs::path kGltfTransform = kSource / "tools/node_modules/.bin/gltf-transform";
const fs::path kBlenderScript = kSource / "tests/consumers/blender_checks.py";
constexpr const char* kInstall = "run `bash scripts/install-deps --consumers`";

int RunCommand(const std::string& cmd, std::string* output) {
  output->clear();
  FILE* p = popen((cmd + " 2>&1").c_str(), "r");
  if (!p) return -1;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), p)) > 0) output->append(buf.data(), n);
  const int status = pclose(p);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

std::string FindOnPath(const std::string& name) {
  for (const char* dir : {"/usr/bin", "/usr/local/bin", "/bin"})
    if (fs::exists(fs::path(dir) / name)) return (fs::path(dir) / name).string();
  return {};
}

// Shell-quoted path. (Appending, not "'" + s + "'": GCC 12 reports a false -Wrestrict there.)
std::string Q(const fs::path& p) {
  std::string q(1, '\'');
  q.append(p.string());
  q.push_back('\'');
  return q;
}

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
    root_ = fs::temp_directory_path() /
            ("mesoscan_export_consumers_test_" + std::to_string(getpid()));
    fs::remove_all(root_);
    fs::create_directories(root_);
    scan_ = new Scan(MakeScan());
    WriteScanFolder(root_ / "synthetic.scan", *scan_);
    std::string out;
    // A: every format, OpenGL normals, lossless mesh. B: DirectX normals. C: decimated mesh.
    status_a_ = RunCommand(Q(kExe) + " -q export " + Q(root_ / "synthetic.scan") + " --out " + Q(root_ / "a"), &out);
    log_ = out;
    status_b_ = RunCommand(Q(kExe) + " -q export " + Q(root_ / "synthetic.scan") + " --out " + Q(root_ / "b") +
                        " --format png16 --normals dx",
                    &out);
    log_ += out;
    status_c_ = RunCommand(Q(kExe) + " -q export " + Q(root_ / "synthetic.scan") + " --out " + Q(root_ / "c") +
                        " --format glb --max-triangles 4000",
                    &out);
    log_ += out;
  }
  static void TearDownTestSuite() { delete scan_; }

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
    std::string out;
    const int status = RunCommand("NO_COLOR=1 " + Q(kGltfTransform) + " validate " + Q(glb), &out);
    // The report has one section per severity (ERROR, WARNING, INFO, HINT); an empty section
    // says "No errors found." / "No warnings found.".
    SCOPED_TRACE(out);
    EXPECT_EQ(status, 0);
    const size_t e = out.find("ERROR"), w = out.find("WARNING", e == std::string::npos ? 0 : e);
    ASSERT_NE(e, std::string::npos);
    ASSERT_NE(w, std::string::npos);
    EXPECT_NE(out.substr(e, w - e).find("No errors found."), std::string::npos) << glb;
    EXPECT_NE(out.find("No warnings found.", w), std::string::npos) << glb;
  }
}

TEST_F(ExportConsumers, OiioReadsEveryExrWithItsChannelsAndAttributes) {
  const std::string iinfo = FindOnPath("iinfo");
  if (iinfo.empty()) GTEST_SKIP() << "iinfo missing: apt-get install openimageio-tools";
  struct Expect {
    std::string file, channels;
  };
  for (const Expect& e : {Expect{"synthetic_height.exr", "Y"}, Expect{"synthetic_normal_gl.exr", "R, G, B"}}) {
    std::string out;
    ASSERT_EQ(RunCommand(iinfo + " -v " + Q(root_ / "a" / e.file), &out), 0) << out;
    SCOPED_TRACE(out);
    EXPECT_NE(out.find("160 x  120, " + std::to_string(e.channels == "Y" ? 1 : 3) + " channel, float openexr"),
              std::string::npos);
    EXPECT_NE(out.find("channel list: " + e.channels + "\n"), std::string::npos);
    EXPECT_NE(out.find("mesoscan:pixel_size: 5e-05"), std::string::npos);
    EXPECT_NE(out.find("mesoscan:x0: -0.004"), std::string::npos);
    if (e.channels == "Y") {
      EXPECT_NE(out.find("mesoscan:units: \"m\""), std::string::npos);
      EXPECT_NE(out.find("mesoscan:midlevel: 0"), std::string::npos);
      EXPECT_NE(out.find("mesoscan:scale: 1"), std::string::npos);
    }
  }
  // oiiotool's statistics of the height: min and max equal the scan's in metres (printed with
  // 6 decimals: 5e-7 m).
  const std::string oiiotool = FindOnPath("oiiotool");
  if (oiiotool.empty()) return;
  std::string out;
  ASSERT_EQ(RunCommand(oiiotool + " --stats " + Q(root_ / "a/synthetic_height.exr"), &out), 0) << out;
  double zmin = INFINITY, zmax = -INFINITY;
  for (float v : scan_->height.z.data())
    if (std::isfinite(v)) zmin = std::min<double>(zmin, v), zmax = std::max<double>(zmax, v);
  const size_t at = out.find("Stats Min: ");
  ASSERT_NE(at, std::string::npos) << out;
  EXPECT_NEAR(std::stod(out.substr(at + 11)), zmin, 5.01e-7) << out;
  const size_t at2 = out.find("Stats Max: ");
  ASSERT_NE(at2, std::string::npos) << out;
  EXPECT_NEAR(std::stod(out.substr(at2 + 11)), zmax, 5.01e-7) << out;
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
  const Json cfg = {{"glb", (root_ / "a/synthetic.glb").string()},
                    {"height_exr", (root_ / "a/synthetic_height.exr").string()},
                    {"height_png", (root_ / "a/synthetic_height.png").string()},
                    {"png_midlevel", side.at("midlevel")},
                    {"png_scale", side.at("scale")},
                    {"normal_gl", (root_ / "a/synthetic_normal_gl.png").string()},
                    {"normal_dx", (root_ / "b/synthetic_normal_dx.png").string()},
                    {"width", hf.width()},
                    {"height", hf.height()},
                    {"x0", hf.x0},
                    {"y0", hf.y0},
                    {"pixel_size", hf.pixel_size},
                    {"samples", samples},
                    {"out", (root_ / "blender_out.json").string()}};
  WriteJsonFile(root_ / "blender_cfg.json", cfg);
  std::string out;
  const int status = RunCommand(blender + " -b --factory-startup --python-exit-code 1 -P " + Q(kBlenderScript) +
                             " -- " + Q(root_ / "blender_cfg.json"),
                         &out);
  ASSERT_EQ(status, 0) << out;
  const Json r = ReadJsonFile(root_ / "blender_out.json");
  EXPECT_EQ(r.at("blender_version").get<std::string>().substr(0, 3), "3.4");

  // 1. GLB: the lossless mesh's vertices are the samples that belong to a triangle (a cell's
  // triangle needs its 3 corners); bounding box of those samples, in metres, z up.
  int64_t expected_vertices = 0;
  double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  auto ok = [&](int i, int j) { return i >= 0 && j >= 0 && i < hf.width() && j < hf.height() && std::isfinite(hf.z(i, j)); };
  for (int j = 0; j < hf.height(); ++j) {
    for (int i = 0; i < hf.width(); ++i) {
      if (!ok(i, j)) continue;
      // A sample is a vertex of the lossless mesh iff it is a corner of a unit triangle (half a
      // grid cell, split along the 4-8 mesh diagonal of heightfield/export_mesh.h) whose three
      // corners are all valid.
      bool used = false;
      for (int cj = j - 1; cj <= j && !used; ++cj) {
        for (int ci = i - 1; ci <= i && !used; ++ci) {
          if (ci < 0 || cj < 0 || ci + 1 >= hf.width() || cj + 1 >= hf.height()) continue;
          const bool main = ((ci + cj) & 1) == 0;  // the 4-8 mesh's diagonal of this cell
          const std::array<std::array<int, 6>, 2> tris =
              main ? std::array<std::array<int, 6>, 2>{{{ci, cj, ci + 1, cj + 1, ci + 1, cj},
                                                        {ci, cj, ci + 1, cj + 1, ci, cj + 1}}}
                   : std::array<std::array<int, 6>, 2>{{{ci, cj + 1, ci + 1, cj, ci, cj},
                                                        {ci, cj + 1, ci + 1, cj, ci + 1, cj + 1}}};
          for (const auto& t : tris) {
            const bool has = (t[0] == i && t[1] == j) || (t[2] == i && t[3] == j) || (t[4] == i && t[5] == j);
            if (has && ok(t[0], t[1]) && ok(t[2], t[3]) && ok(t[4], t[5])) used = true;
          }
        }
      }
      if (!used) continue;
      ++expected_vertices;
      const double p[3] = {hf.X(i), hf.Y(j), hf.z(i, j)};
      for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], p[k]), hi[k] = std::max(hi[k], p[k]);
    }
  }
  const Json& g = r.at("glb");
  EXPECT_EQ(g.at("objects"), 1);
  EXPECT_EQ(g.at("vertices").get<int64_t>(), expected_vertices);
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(g.at("bbox_min")[k].get<double>(), lo[k], 1e-6) << "axis " << k;
    EXPECT_NEAR(g.at("bbox_max")[k].get<double>(), hi[k], 1e-6) << "axis " << k;
  }
  EXPECT_EQ(g.at("extras").at("height_map"), "synthetic_height.exr");
  EXPECT_EQ(g.at("extras").at("units"), "m");
  bool normal_map_wired = false;
  for (const auto& l : g.at("material_links"))
    if (l[0] == "TEX_IMAGE" && l[1] == "NORMAL_MAP") normal_map_wired = true;
  EXPECT_TRUE(normal_map_wired) << g.at("material_links").dump();

  // 2. Displacement: within 1 um of the scan's heights (the bound; the EXR is exact in
  // float32, the PNG within half a quantisation step of (max - min) / 65535).
  const double step = side.at("scale").get<double>() / 65535.0;
  double max_exr = 0, max_png = 0;
  ASSERT_EQ(r.at("displace_exr").size(), samples.size());
  ASSERT_EQ(r.at("displace_png").size(), samples.size());
  for (size_t k = 0; k < samples.size(); ++k) {
    const double z = hf.z(samples[k][0].get<int>(), samples[k][1].get<int>());
    max_exr = std::max(max_exr, std::abs(r.at("displace_exr")[k].get<double>() - z));
    max_png = std::max(max_png, std::abs(r.at("displace_png")[k].get<double>() - z));
  }
  EXPECT_LT(max_exr, 1e-6);
  EXPECT_LT(max_png, 1e-6);
  // Blender's image texture applies brightness/contrast as (v - 0.5) * 1 + 0.5 in float32: the
  // metre values (~1e-4) are rounded to the float32 grid at 0.5, one ulp = 2^-24 = 6e-8 m.
  EXPECT_LT(max_exr, 6e-8);
  EXPECT_LT(max_png, 0.5 * step + 1e-9);
  RecordProperty("blender_max_displacement_error_exr_m", std::to_string(max_exr));
  RecordProperty("blender_max_displacement_error_png_m", std::to_string(max_png));
  // The one-channel EXR (channel Y) is read as grey: R = G = B = the height.
  const auto& rgba = r.at("exr_first_sample_rgba");
  const double z0 = hf.z(samples[0][0].get<int>(), samples[0][1].get<int>());
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(rgba[k].get<double>(), z0, 1e-9) << "channel " << k;

  // 3. Normal maps. Baked shading normals against the scan's normals, pixel by pixel.
  auto compare = [&](const Json& bake, double y_sign) {
    EXPECT_EQ(bake.at("width"), hf.width());
    EXPECT_EQ(bake.at("height"), hf.height());
    double worst = 0;
    const auto& n = bake.at("normals");
    for (int j = 0; j < hf.height(); ++j) {
      for (int i = 0; i < hf.width(); ++i) {
        if (!std::isfinite(hf.z(i, j))) continue;
        const auto& b = n[static_cast<size_t>(j) * hf.width() + i];
        const double e[3] = {scan_->normals(i, j, 0), y_sign * scan_->normals(i, j, 1), scan_->normals(i, j, 2)};
        for (int k = 0; k < 3; ++k) worst = std::max(worst, std::abs(b[k].get<double>() - e[k]));
      }
    }
    return worst;
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
    const int i = static_cast<int>(std::lround(hf.I(x))), j = static_cast<int>(std::lround(hf.J(y)));
    const auto& b = bake.at("normals")[static_cast<size_t>(j) * hf.width() + i];
    return (b[0].get<double>() + b[1].get<double>() + b[2].get<double>()) / std::sqrt(3.0);
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
