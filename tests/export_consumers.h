#pragma once
// The real consumers of mesoscan's exports, shared by the pipeline tests that run
// them: tests/export_consumers_test.cc (a synthetic scan) and tests/export_coin_test.cc (the
// demo coin, simulated and reconstructed). Consumers are installed by
// `scripts/install-deps --consumers`; a test whose consumer is missing skips with kInstall.
//  - gltf-transform validate (the Khronos glTF validator), tools/node_modules;
//  - Blender 3.4 in background mode running tests/consumers/blender_checks.py on a JSON
//    config; its measurements come back as JSON and the C++ tests compare them with the scan;
//  - OpenImageIO's iinfo / oiiotool.

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "core/height_field.h"
#include "core/image.h"
#include "core/image_io.h"
#include "core/json.h"

namespace mesoscan::consumers {

namespace fs = std::filesystem;

inline const fs::path kSource = MESOSCAN_SOURCE_DIR;
inline const fs::path kExe = MESOSCAN_EXE;
inline const fs::path kGltfTransform = kSource / "tools/node_modules/.bin/gltf-transform";
inline const fs::path kBlenderScript = kSource / "tests/consumers/blender_checks.py";
inline constexpr const char* kInstall = "run `bash scripts/install-deps --consumers`";

// Runs `cmd` through the shell; stdout + stderr into `output`. Returns the exit code (-1 if the
// process did not exit normally).
inline int RunCommand(const std::string& cmd, std::string* output) {
  output->clear();
  FILE* p = popen((cmd + " 2>&1").c_str(), "r");
  if (!p) return -1;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), p)) > 0) output->append(buf.data(), n);
  const int status = pclose(p);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

// The consumer's path in the system folders, or "" if it is not installed.
inline std::string FindOnPath(const std::string& name) {
  for (const char* dir : {"/usr/bin", "/usr/local/bin", "/bin"})
    if (fs::exists(fs::path(dir) / name)) return (fs::path(dir) / name).string();
  return {};
}

// Shell-quoted path. (Appending, not "'" + s + "'": GCC 12 reports a false -Wrestrict there.)
inline std::string Q(const fs::path& p) {
  std::string q(1, '\'');
  q.append(p.string());
  q.push_back('\'');
  return q;
}

// `mesoscan <args>` (args already quoted), output into `log`; returns the exit code.
inline int RunMesoscan(const std::string& args, std::string* log) {
  return RunCommand(Q(kExe) + " " + args, log);
}

// gltf-transform validate on `glb`: exit code 0, and its report's ERROR section says "No errors
// found." (its sections: ERROR, WARNING, INFO, HINT; an empty one says "No <severity>s
// found."). Warnings are returned for the caller to expect none.
struct GltfValidation {
  bool no_errors = false, no_warnings = false;
  std::string report;
};
inline GltfValidation ValidateGlb(const fs::path& glb) {
  GltfValidation v;
  const int status =
      RunCommand("NO_COLOR=1 " + Q(kGltfTransform) + " validate " + Q(glb), &v.report);
  const size_t e = v.report.find("ERROR");
  const size_t w = v.report.find("WARNING", e == std::string::npos ? 0 : e);
  if (status != 0 || e == std::string::npos || w == std::string::npos) return v;
  v.no_errors = v.report.substr(e, w - e).find("No errors found.") != std::string::npos;
  v.no_warnings = v.report.find("No warnings found.", w) != std::string::npos;
  return v;
}

// A numeric attribute as iinfo -v prints it ("    name: value"), NaN if absent.
inline double IinfoNumber(const std::string& out, const std::string& name) {
  const size_t at = out.find(name + ": ");
  return at == std::string::npos ? std::nan("") : std::stod(out.substr(at + name.size() + 2));
}

// iinfo reads an export's EXR with the grid's size, the expected channels, float pixels and
// the grid attributes (printed with 6 significant digits); a height EXR also with its units,
// midlevel 0 and scale 1.
inline void ExpectIinfoReadsExr(const fs::path& exr, const HeightField& grid,
                                const std::string& channels, bool height) {
  const std::string iinfo = FindOnPath("iinfo");
  ASSERT_FALSE(iinfo.empty());
  std::string out;
  ASSERT_EQ(RunCommand(iinfo + " -v " + Q(exr), &out), 0) << out;
  SCOPED_TRACE(out);
  const int n = static_cast<int>(std::count(channels.begin(), channels.end(), ',')) + 1;
  char dims[96];
  std::snprintf(dims, sizeof dims, "%4d x %4d, %d channel, float openexr", grid.width(),
                grid.height(), n);
  EXPECT_NE(out.find(dims), std::string::npos) << dims;
  EXPECT_NE(out.find("channel list: " + channels + "\n"), std::string::npos);
  EXPECT_NEAR(IinfoNumber(out, "mesoscan:pixel_size"), grid.pixel_size, 1e-5 * grid.pixel_size);
  EXPECT_NEAR(IinfoNumber(out, "mesoscan:x0"), grid.x0, 1e-5 * std::abs(grid.x0) + 1e-12);
  EXPECT_NEAR(IinfoNumber(out, "mesoscan:y0"), grid.y0, 1e-5 * std::abs(grid.y0) + 1e-12);
  if (height) {
    EXPECT_NE(out.find("mesoscan:units: \"m\""), std::string::npos);
    EXPECT_EQ(IinfoNumber(out, "mesoscan:midlevel"), 0.0);
    EXPECT_EQ(IinfoNumber(out, "mesoscan:scale"), 1.0);
  }
}

// oiiotool --stats of a height EXR: min and max equal the height field's in metres (printed
// with 6 decimals: 5e-7 m). Holes are filled with the minimum, so neither moves.
inline void ExpectOiiotoolStatsMatch(const fs::path& exr, const HeightField& hf) {
  const std::string oiiotool = FindOnPath("oiiotool");
  if (oiiotool.empty()) return;
  std::string out;
  ASSERT_EQ(RunCommand(oiiotool + " --stats " + Q(exr), &out), 0) << out;
  double zmin = INFINITY, zmax = -INFINITY;
  for (float v : hf.z.data())
    if (std::isfinite(v)) zmin = std::min<double>(zmin, v), zmax = std::max<double>(zmax, v);
  for (const auto& [key, expected] :
       {std::pair{"Stats Min: ", zmin}, std::pair{"Stats Max: ", zmax}}) {
    const size_t at = out.find(key);
    ASSERT_NE(at, std::string::npos) << out;
    EXPECT_NEAR(std::stod(out.substr(at + 11)), expected, 5.01e-7) << key << out;
  }
}

// blender_checks.py's config for the export of `name` in `dir` (every format, OpenGL normals)
// on the grid `hf`, at the sample pixels `samples` ([[i, j], ...]).
inline Json BlenderConfig(const fs::path& dir, const std::string& name, const HeightField& hf,
                          const Json& samples) {
  const Json side = ReadJsonFile(dir / (name + "_height.json"));
  return {{"glb", (dir / (name + ".glb")).string()},
          {"height_exr", (dir / (name + "_height.exr")).string()},
          {"height_png", (dir / (name + "_height.png")).string()},
          {"png_midlevel", side.at("midlevel")},
          {"png_scale", side.at("scale")},
          {"normal_gl", (dir / (name + "_normal_gl.png")).string()},
          {"width", hf.width()},
          {"height", hf.height()},
          {"x0", hf.x0},
          {"y0", hf.y0},
          {"pixel_size", hf.pixel_size},
          {"samples", samples}};
}

// Runs blender_checks.py with `cfg` (written to dir/blender_cfg.json; "out" is set to
// dir/blender_out.json) and returns its measurements; a failure is reported and null returned.
inline Json RunBlenderChecks(const std::string& blender, const fs::path& dir, Json cfg) {
  cfg["out"] = (dir / "blender_out.json").string();
  WriteJsonFile(dir / "blender_cfg.json", cfg);
  std::string out;
  const int status = RunCommand(blender + " -b --factory-startup --python-exit-code 1 -P " +
                                    Q(kBlenderScript) + " -- " + Q(dir / "blender_cfg.json"),
                                &out);
  if (status != 0) {
    ADD_FAILURE() << "blender exited with " << status << ":\n" << out;
    return Json();
  }
  Json r = ReadJsonFile(dir / "blender_out.json");
  EXPECT_EQ(r.at("blender_version").get<std::string>().substr(0, 3), "3.4");
  return r;
}

// The samples of the lossless GLB mesh (maps/export_mesh.h): a sample is a vertex iff
// it is a corner of a unit triangle (half a grid cell, split along the 4-8 mesh diagonal)
// whose three corners are all valid. Computed here from that definition, independently of
// the exporter. Also the vertices' bounding box (world metres, z up).
// The surface an export's GLB covers: the scan's heights with its holes filled as the export
// filled them (the export's height EXR; samples left at its manifest's hole_value_m are holes).
inline HeightField FilledSurface(const HeightField& scan, const fs::path& export_dir,
                                 const std::string& name) {
  HeightField f = scan;
  const float hole_value =
      ReadJsonFile(export_dir / "manifest.json").at("hole_value_m").get<float>();
  const ImageF z = ReadExrChannels(export_dir / (name + "_height.exr"), {"Y"});
  for (size_t p = 0; p < z.pixels(); ++p)
    if (!std::isfinite(f.z.data()[p]))
      f.z.data()[p] = z.data()[p] == hole_value ? std::nanf("") : z.data()[p];
  return f;
}

struct LosslessMesh {
  std::vector<bool> vertex;  // per pixel j * width + i
  int64_t vertices = 0;
  std::array<double, 3> lo{INFINITY, INFINITY, INFINITY}, hi{-INFINITY, -INFINITY, -INFINITY};
};
inline LosslessMesh LosslessMeshOf(const HeightField& hf) {
  LosslessMesh m;
  const int w = hf.width(), h = hf.height();
  m.vertex.assign(static_cast<size_t>(w) * h, false);
  auto ok = [&](int i, int j) {
    return i >= 0 && j >= 0 && i < w && j < h && std::isfinite(hf.z(i, j));
  };
  for (int cj = 0; cj + 1 < h; ++cj) {
    for (int ci = 0; ci + 1 < w; ++ci) {
      const bool main = ((ci + cj) & 1) == 0;  // the 4-8 mesh's diagonal of this cell
      const std::array<std::array<int, 6>, 2> tris =
          main ? std::array<std::array<int, 6>, 2>{{{ci, cj, ci + 1, cj + 1, ci + 1, cj},
                                                    {ci, cj, ci + 1, cj + 1, ci, cj + 1}}}
               : std::array<std::array<int, 6>, 2>{
                     {{ci, cj + 1, ci + 1, cj, ci, cj}, {ci, cj + 1, ci + 1, cj, ci + 1, cj + 1}}};
      for (const auto& t : tris) {
        if (!ok(t[0], t[1]) || !ok(t[2], t[3]) || !ok(t[4], t[5])) continue;
        for (int k = 0; k < 6; k += 2) m.vertex[static_cast<size_t>(t[k + 1]) * w + t[k]] = true;
      }
    }
  }
  for (int j = 0; j < h; ++j) {
    for (int i = 0; i < w; ++i) {
      if (!m.vertex[static_cast<size_t>(j) * w + i]) continue;
      ++m.vertices;
      const double p[3] = {hf.X(i), hf.Y(j), hf.z(i, j)};
      for (int k = 0; k < 3; ++k)
        m.lo[k] = std::min(m.lo[k], p[k]), m.hi[k] = std::max(m.hi[k], p[k]);
    }
  }
  return m;
}

// Blender's GLB import: one mesh object with the lossless mesh's vertex count and bounding box
// within 1e-6 m (the required bound), the node extras naming the height map in metres, and a
// Normal Map node fed by an image texture.
inline void ExpectGlbImportMatches(const Json& g, const LosslessMesh& mesh,
                                   const std::string& height_map) {
  EXPECT_EQ(g.at("objects"), 1);
  EXPECT_EQ(g.at("vertices").get<int64_t>(), mesh.vertices);
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(g.at("bbox_min")[k].get<double>(), mesh.lo[k], 1e-6) << "axis " << k;
    EXPECT_NEAR(g.at("bbox_max")[k].get<double>(), mesh.hi[k], 1e-6) << "axis " << k;
  }
  EXPECT_EQ(g.at("extras").at("height_map"), height_map);
  EXPECT_EQ(g.at("extras").at("units"), "m");
  bool normal_map_wired = false;
  for (const auto& l : g.at("material_links"))
    if (l[0] == "TEX_IMAGE" && l[1] == "NORMAL_MAP") normal_map_wired = true;
  EXPECT_TRUE(normal_map_wired) << g.at("material_links").dump();
}

// Largest |measured - expected(sample k)| over the samples (Blender's list `measured`).
template <typename F>
double MaxDeviation(const Json& measured, size_t samples, F expected) {
  EXPECT_EQ(measured.size(), samples);
  double worst = 0;
  for (size_t k = 0; k < std::min(samples, measured.size()); ++k)
    worst = std::max(worst, std::abs(measured[k].get<double>() - expected(k)));
  return worst;
}

// The shading normal Blender baked at pixel (i, j) of a normal map (bake_normal_map's output).
inline std::array<double, 3> BakedNormal(const Json& bake, int i, int j) {
  const auto& b = bake.at("normals")[static_cast<size_t>(j) * bake.at("width").get<int>() + i];
  return {b[0].get<double>(), b[1].get<double>(), b[2].get<double>()};
}

// Largest component difference between the baked shading normals and the scan's normals
// (y mirrored by y_sign) over the valid samples of `hf`.
inline double MaxBakedNormalError(const Json& bake, const HeightField& hf, const ImageF& normals,
                                  double y_sign) {
  EXPECT_EQ(bake.at("width"), hf.width());
  EXPECT_EQ(bake.at("height"), hf.height());
  double worst = 0;
  for (int j = 0; j < hf.height(); ++j) {
    for (int i = 0; i < hf.width(); ++i) {
      if (!std::isfinite(hf.z(i, j))) continue;
      // Next to a filled hole the exported normal comes from the filled surface.
      bool near_hole = false;
      for (int dj = -1; dj <= 1; ++dj)
        for (int di = -1; di <= 1; ++di) {
          const int x = i + di, y = j + dj;
          near_hole = near_hole || (x >= 0 && y >= 0 && x < hf.width() && y < hf.height() &&
                                    !std::isfinite(hf.z(x, y)));
        }
      if (near_hole) continue;
      const std::array<double, 3> b = BakedNormal(bake, i, j);
      const double e[3] = {normals(i, j, 0), y_sign * normals(i, j, 1), normals(i, j, 2)};
      for (int k = 0; k < 3; ++k) worst = std::max(worst, std::abs(b[k] - e[k]));
    }
  }
  return worst;
}

}  // namespace mesoscan::consumers
