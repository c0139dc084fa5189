#include "maps/export.h"

#include <gtest/gtest.h>
#include <tiny_gltf.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <vector>

#include "core/error.h"
#include "core/fs.h"
#include "core/image_io.h"
#include "core/test_temp_dir.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) { return TestTempDir("export_test", name); }

// A 96 x 64 scan, 50 um pixels: a 200 um Gaussian bump on a slight ramp, a disk-shaped hole
// (a shadow) and a confidence falling off towards the edges.
Scan MakeScan(int w = 96, int h = 64) {
  Scan s;
  HeightField& hf = s.height;
  hf.pixel_size = 50e-6;
  hf.x0 = -2.4e-3;
  hf.y0 = 1.6e-3;
  hf.z = ImageF(w, h, 1);
  hf.confidence = ImageF(w, h, 1);
  for (int j = 0; j < h; ++j) {
    for (int i = 0; i < w; ++i) {
      const double x = hf.X(i), y = hf.Y(j);
      const double r2 = (x - 0.3e-3) * (x - 0.3e-3) + (y + 0.2e-3) * (y + 0.2e-3);
      double z = 0.2e-3 * std::exp(-r2 / (2 * 0.4e-3 * 0.4e-3)) + 0.01 * (x + 2.4e-3) + 30e-6;
      const double hx = i - 0.8 * w, hy = j - 0.3 * h;
      const bool hole = hx * hx + hy * hy < 36.0;
      hf.z(i, j) = hole ? std::nanf("") : static_cast<float>(z);
      hf.confidence(i, j) = hole ? 0.0f : static_cast<float>(1.0 - 0.5 * std::abs(i - w / 2.0) / w);
    }
  }
  s.normals = hf.Normals();
  return s;
}

ExportOptions SmallOptions(const std::string& name) {
  ExportOptions o;
  o.name = name;
  o.albedo_from_session = false;
  return o;
}

// Exports `scan` in `formats` (--format syntax) with prefix "s" into the fresh folder `folder`.
fs::path ExportOnly(const Scan& scan, const std::string& formats, const std::string& folder,
                    ExportOptions o = SmallOptions("s")) {
  ParseExportFormats(formats, &o);
  const fs::path dir = TempDir(folder);
  ExportScan(scan, o, dir);
  return dir;
}

// The GLB's glTF model (images left encoded: only the structure is checked).
tinygltf::Model LoadGlb(const fs::path& glb) {
  tinygltf::Model model;
  tinygltf::TinyGLTF loader;
  loader.SetImageLoader([](tinygltf::Image*, const int, std::string*, std::string*, int, int,
                           const unsigned char*, int, void*) { return true; },
                        nullptr);
  std::string err, warn;
  EXPECT_TRUE(loader.LoadBinaryFromFile(&model, &err, &warn, glb.string())) << glb << ": " << err;
  return model;
}

TEST(Export, WritesEveryFileAndAManifestAndNoTemporaries) {
  const Scan scan = MakeScan();
  const fs::path dir = TempDir("all");
  const ExportSummary sum = ExportScan(scan, SmallOptions("coin"), dir);
  for (const char* f :
       {"coin_height.exr", "coin_height.png", "coin_height.json", "coin_normal_gl.png",
        "coin_normal_gl.exr", "coin_confidence.png", "coin.glb", "coin.ply", "manifest.json"})
    EXPECT_TRUE(fs::exists(dir / f)) << f;
  EXPECT_EQ(sum.files.back(), dir / "manifest.json");
  for (const auto& e : fs::directory_iterator(dir))
    EXPECT_NE(e.path().filename().string()[0], '.') << "temporary left: " << e.path();
  const Json m = ReadJsonFile(dir / "manifest.json");
  EXPECT_EQ(m.at("format"), "mesoscan-export/1");
  EXPECT_EQ(m.at("units"), "m");
  EXPECT_EQ(m.at("files").size() + 1, sum.files.size());
  for (const auto& f : m.at("files"))
    EXPECT_TRUE(fs::exists(dir / f.at("file").get<std::string>()));
  EXPECT_DOUBLE_EQ(m.at("grid").at("pixel_size_m").get<double>(), 50e-6);
  EXPECT_DOUBLE_EQ(m.at("grid").at("physical_size_m")[0].get<double>(), 96 * 50e-6);
  EXPECT_EQ(m.at("albedo"), "none");  // none given, session lookup off
}

TEST(Export, HeightExrIsMetresInChannelYWithTheGridAttributes) {
  const Scan scan = MakeScan();
  const fs::path dir = ExportOnly(scan, "exr", "exr");
  ImageInfo info = ReadImageInfo(dir / "s_height.exr");
  ASSERT_EQ(info.channel_names, std::vector<std::string>{"Y"});
  EXPECT_TRUE(info.is_float);
  EXPECT_NEAR(info.float_attributes.at("mesoscan:pixel_size"), 50e-6, 5e-12);  // float32
  EXPECT_NEAR(info.float_attributes.at("mesoscan:x0"), -2.4e-3, 2e-10);        // float32 attribute
  EXPECT_EQ(info.float_attributes.at("mesoscan:midlevel"), 0.0);
  EXPECT_EQ(info.float_attributes.at("mesoscan:scale"), 1.0);
  const ImageF y = ReadExrChannels(dir / "s_height.exr", {"Y"});
  // The disk-shaped hole is bounded by surface: filled harmonically, so every filled
  // height lies within its border's range (no trench down to the lowest height).
  const HeightField& hf = scan.height;
  float lo = INFINITY, hi = -INFINITY;
  std::vector<bool> near_hole(y.pixels(), false);
  for (int j = 0; j < hf.height(); ++j)
    for (int i = 0; i < hf.width(); ++i) {
      if (std::isfinite(hf.z(i, j))) continue;
      for (int dj = -1; dj <= 1; ++dj)
        for (int di = -1; di <= 1; ++di) {
          const int x = i + di, yy = j + dj;
          if (x < 0 || yy < 0 || x >= hf.width() || yy >= hf.height()) continue;
          near_hole[static_cast<size_t>(yy) * hf.width() + x] = true;
          if (std::isfinite(hf.z(x, yy)))
            lo = std::min(lo, hf.z(x, yy)), hi = std::max(hi, hf.z(x, yy));
        }
    }
  for (size_t p = 0; p < y.pixels(); ++p) {
    const float z = scan.height.z.data()[p];
    ASSERT_TRUE(std::isfinite(y.data()[p]));
    if (std::isfinite(z)) {
      EXPECT_EQ(y.data()[p], z);  // float32 both: exact
    } else {
      EXPECT_GE(y.data()[p], lo);
      EXPECT_LE(y.data()[p], hi);
    }
  }
  // Normals: the scan's, except in and next to the filled hole (from the filled surface there).
  const ImageF n = ReadExrChannels(dir / "s_normal_gl.exr", {"R", "G", "B"});
  for (size_t p = 0; p < n.pixels(); ++p) {
    if (!std::isfinite(scan.normals.data()[p]) || near_hole[p]) continue;
    for (int k = 0; k < 3; ++k)
      EXPECT_NEAR(2 * n.channel(k)[p] - 1, scan.normals.channel(k)[p], 1e-6);
  }
}

TEST(Export, Png16HeightDecodesWithTheSidecarWithinHalfAStep) {
  const Scan scan = MakeScan();
  const fs::path dir = ExportOnly(scan, "png16", "png");
  const Json side = ReadJsonFile(dir / "s_height.json");
  const double mid = side.at("midlevel"), scale = side.at("scale");
  EXPECT_EQ(side.at("units"), "m");
  EXPECT_DOUBLE_EQ(side.at("blender").at("midlevel").get<double>(), mid);
  EXPECT_DOUBLE_EQ(side.at("arnold").at("height").get<double>(), scale);
  ImageInfo info;
  const ImageF v = ReadImage(dir / "s_height.png", &info);
  ASSERT_EQ(info.bits_per_sample, 16);
  ASSERT_EQ(v.channels(), 1);
  // Quantisation: half a step of scale / 65535, plus float rounding of the decode.
  const double tol = 0.5 * scale / 65535.0 + 1e-9;
  for (size_t p = 0; p < v.pixels(); ++p) {
    const float z = scan.height.z.data()[p];
    if (!std::isfinite(z)) continue;
    EXPECT_NEAR((v.data()[p] - mid) * scale, z, tol);
  }
}

TEST(Export, NormalMapConventionsDifferOnlyInGreen) {
  const Scan scan = MakeScan();
  const fs::path dir = ExportOnly(scan, "png16", "normals");
  ExportOptions o = SmallOptions("s");
  ParseExportFormats("png16", &o);
  o.normals = NormalConvention::kDirectX;
  ExportScan(scan, o, dir);
  const ImageF gl = ReadImage(dir / "s_normal_gl.png"), dx = ReadImage(dir / "s_normal_dx.png");
  const double q = 1.0 / 65535;
  int checked = 0;
  // Next to the filled hole the normals come from the filled surface: skipped.
  auto near_hole = [&](int i, int j) {
    for (int dj = -1; dj <= 1; ++dj)
      for (int di = -1; di <= 1; ++di) {
        const int x = i + di, y = j + dj;
        if (x >= 0 && y >= 0 && x < gl.width() && y < gl.height() &&
            !std::isfinite(scan.height.z(x, y)))
          return true;
      }
    return false;
  };
  for (int j = 0; j < gl.height(); ++j) {
    for (int i = 0; i < gl.width(); ++i) {
      if (!std::isfinite(scan.height.z(i, j)) || near_hole(i, j)) continue;
      for (int k = 0; k < 3; ++k) {
        const double sign = k == 1 ? -1 : 1;
        EXPECT_NEAR(2 * gl(i, j, k) - 1, scan.normals(i, j, k), 2 * q);
        EXPECT_NEAR(2 * dx(i, j, k) - 1, sign * scan.normals(i, j, k), 2 * q);
      }
      ++checked;
    }
  }
  EXPECT_GT(checked, 5000);
  // The bump's +y flank (above its centre in the image: smaller row) has a +Y (green > 0.5)
  // OpenGL normal. Bump centre: x = 0.3 mm -> i = 54, y = -0.2 mm -> j = 36; flank 8 rows up.
  EXPECT_GT(gl(54, 28, 1), 0.55);
  EXPECT_LT(dx(54, 28, 1), 0.45);
}

TEST(Export, GlbHoldsTheHeightFieldInMetresYUpWithExtras) {
  const Scan scan = MakeScan();
  const fs::path dir = TempDir("glb");
  ExportOptions o = SmallOptions("s");
  o.ply = false;
  const ExportSummary sum = ExportScan(scan, o, dir);
  const tinygltf::Model model = LoadGlb(dir / "s.glb");
  ASSERT_EQ(model.meshes.size(), 1u);
  const auto& prim = model.meshes[0].primitives[0];
  for (const char* a : {"POSITION", "NORMAL", "TANGENT", "TEXCOORD_0", "_FILLED"})
    ASSERT_TRUE(prim.attributes.count(a)) << a;
  const auto& pa = model.accessors[prim.attributes.at("POSITION")];
  const auto& pv = model.bufferViews[pa.bufferView];
  const float* pos = reinterpret_cast<const float*>(model.buffers[0].data.data() + pv.byteOffset);
  EXPECT_EQ(static_cast<int64_t>(pa.count), sum.vertices);
  // Lossless at this size (budget 1M): every sample with a triangle is a vertex, at its height.
  const HeightField& hf = scan.height;
  const int w = hf.width();
  for (size_t v = 0; v < pa.count; ++v) {
    const double x = pos[3 * v], y = -pos[3 * v + 2], z = pos[3 * v + 1];
    const int i = static_cast<int>(std::lround(hf.I(x))),
              j = static_cast<int>(std::lround(hf.J(y)));
    ASSERT_NEAR(hf.X(i), x, 1e-9);
    ASSERT_NEAR(hf.Y(j), y, 1e-9);
    // Measured samples at their height; filled ones (the GLB covers the hole-filled surface)
    // finite.
    if (std::isfinite(hf.z(i, j)))
      ASSERT_EQ(z, hf.z(i, j)) << i << "," << j;
    else
      ASSERT_TRUE(std::isfinite(z)) << i << "," << j;
  }
  EXPECT_EQ(sum.max_height_error_m, 0.0);
  ASSERT_EQ(pa.minValues.size(), 3u);
  EXPECT_NEAR(pa.minValues[0], hf.X(0), 1e-9);
  EXPECT_NEAR(pa.maxValues[0], hf.X(w - 1), 1e-9);
  EXPECT_NEAR(-pa.minValues[2], hf.Y(0), 1e-9);  // glTF z = -world y
  // Material: normal texture (and no base colour without an albedo); extras name the map.
  ASSERT_EQ(model.materials.size(), 1u);
  EXPECT_GE(model.materials[0].normalTexture.index, 0);
  EXPECT_EQ(model.materials[0].pbrMetallicRoughness.baseColorTexture.index, -1);
  const auto& extras = model.nodes[0].extras;
  ASSERT_TRUE(extras.IsObject());
  EXPECT_EQ(extras.Get("height_map").Get<std::string>(), "s_height.exr");
  EXPECT_EQ(extras.Get("units").Get<std::string>(), "m");
  EXPECT_EQ(extras.Get("height_zero_m").GetNumberAsDouble(), 0.0);
  EXPECT_EQ(extras.Get("height_scale").GetNumberAsDouble(), 1.0);
}

TEST(Export, PlyHasEveryValidSampleWithNormalAndConfidence) {
  const Scan scan = MakeScan();
  const fs::path dir = ExportOnly(scan, "ply", "ply");
  std::ifstream in(dir / "s.ply", std::ios::binary);
  std::string line;
  int64_t n = -1;
  int props = 0;
  while (std::getline(in, line) && line != "end_header") {
    if (line.rfind("element vertex ", 0) == 0) n = std::stoll(line.substr(15));
    if (line.rfind("property float ", 0) == 0) ++props;
  }
  ASSERT_EQ(props, 7);
  int64_t valid = 0;
  for (float v : scan.height.z.data()) valid += std::isfinite(v);
  ASSERT_EQ(n, valid);
  std::vector<float> rec(7);
  in.read(reinterpret_cast<char*>(rec.data()), 7 * sizeof(float));
  ASSERT_TRUE(in);
  // First valid sample is pixel (0, 0).
  EXPECT_FLOAT_EQ(rec[0], static_cast<float>(scan.height.X(0)));
  EXPECT_FLOAT_EQ(rec[1], static_cast<float>(scan.height.Y(0)));
  EXPECT_FLOAT_EQ(rec[2], scan.height.z(0, 0));
  EXPECT_FLOAT_EQ(rec[5], scan.normals(0, 0, 2));
  EXPECT_FLOAT_EQ(rec[6], scan.height.confidence(0, 0));
}

TEST(Export, CropAndPixelSizeKeepWorldPositions) {
  Scan scan = MakeScan();
  // A plane, so resampled heights are exact: z = a x + b y + c.
  HeightField& hf = scan.height;
  for (int j = 0; j < hf.height(); ++j)
    for (int i = 0; i < hf.width(); ++i)
      hf.z(i, j) = static_cast<float>(0.02 * hf.X(i) - 0.01 * hf.Y(j) + 1e-4);
  PixelRect crop{10, 6, 40, 30};
  const HeightField c = CropAndResample(hf, crop, 0.0);
  EXPECT_EQ(c.width(), 40);
  EXPECT_DOUBLE_EQ(c.x0, hf.X(10));
  EXPECT_DOUBLE_EQ(c.y0, hf.Y(6));
  EXPECT_EQ(c.z(0, 0), hf.z(10, 6));
  for (double p : {100e-6, 30e-6}) {  // box average down, bilinear up
    const HeightField r = CropAndResample(hf, crop, p);
    EXPECT_EQ(r.width(), static_cast<int>(std::floor(39 * 50e-6 / p + 1e-9)) + 1);
    for (int j = 0; j < r.height(); j += 3) {
      for (int i = 0; i < r.width(); i += 3) {
        if (!std::isfinite(r.z(i, j))) continue;
        EXPECT_NEAR(r.z(i, j), 0.02 * r.X(i) - 0.01 * r.Y(j) + 1e-4, 1e-9) << p;
      }
    }
  }
  EXPECT_THROW(CropAndResample(hf, PixelRect{90, 0, 10, 10}, 0.0), Error);
}

TEST(Export, ParsesFormatsAndCropsAndRefusesBadOnes) {
  ExportOptions o;
  ParseExportFormats("glb,exr", &o);
  EXPECT_TRUE(o.glb && o.exr && !o.png16 && !o.ply);
  try {
    ParseExportFormats("exr,obj", &o);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kUsage);
    EXPECT_NE(std::string(e.what()).find("'obj'"), std::string::npos);
  }
}

TEST(Export, AlbedoIsWrittenAsSrgbAndTexturesTheGlb) {
  const Scan scan = MakeScan();
  ExportOptions o = SmallOptions("s");
  o.albedo = ImageF(scan.height.width(), scan.height.height(), 1);
  for (int j = 0; j < o.albedo.height(); ++j)
    for (int i = 0; i < o.albedo.width(); ++i) o.albedo(i, j) = 0.2f + 0.6f * i / o.albedo.width();
  const fs::path dir = ExportOnly(scan, "png16,glb", "albedo", o);
  ImageInfo info;
  const ImageF a = ReadImage(dir / "s_albedo.png", &info);
  EXPECT_EQ(info.bits_per_sample, 8);
  // Scaled so the 99th percentile is 1, then sRGB-encoded: decode and compare shapes.
  const double scale = 1.0 / (0.2 + 0.6 * 95 / 96.0);
  auto decode = [](double v) {
    return v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4);
  };
  EXPECT_NEAR(decode(a(10, 10)), (0.2 + 0.6 * 10 / 96.0) * scale, 0.01);
  const tinygltf::Model model = LoadGlb(dir / "s.glb");
  ASSERT_EQ(model.materials.size(), 1u);
  EXPECT_GE(model.materials[0].pbrMetallicRoughness.baseColorTexture.index, 0);
}

TEST(Export, RefusesAnEmptyRegionAndBadOptions) {
  Scan scan = MakeScan(8, 8);
  scan.height.z.Fill(std::nanf(""));
  EXPECT_THROW(ExportScan(scan, SmallOptions("s"), TempDir("empty")), Error);
  ExportOptions o;
  o.name = "a/b";
  EXPECT_THROW(o.Check(), Error);
  o = ExportOptions();
  o.exr = o.png16 = o.glb = o.ply = false;
  EXPECT_THROW(o.Check(), Error);
}

}  // namespace
}  // namespace mesoscan
