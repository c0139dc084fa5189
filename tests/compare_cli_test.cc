// `mesoscan compare` as a user runs it: synthetic scan folders (a relief of scattered bumps, B the
// same relief re-placed), the comparison folder it writes, and one clear line with a distinct
// exit code for each bad input.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include "core/image_io.h"
#include "core/json.h"
#include "core/scan_folder.h"
#include "core/transform.h"
#include "sim/synthetic_scan.h"
#include "tests/cli_util.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

// A 12 x 12 mm plate 1 mm high with 60 bumps (10-25 um, 1-1.8 mm wide) in world frame
// `world_from_object` (a rotation about z and a shift), sampled on a 300 x 300 grid of 55 um,
// with noise.
Scan Relief(double angle_deg, double tx, double ty, uint64_t seed, bool empty = false) {
  std::mt19937 rng(7);  // the same bumps in every scan
  std::uniform_real_distribution<double> u(0, 1);
  struct Bump {
    double x, y, r, h;
  };
  std::vector<Bump> bumps;
  for (int k = 0; k < 60; ++k)
    bumps.push_back({(u(rng) - 0.5) * 10e-3, (u(rng) - 0.5) * 10e-3, 0.5e-3 + 0.4e-3 * u(rng),
                     10e-6 + 15e-6 * u(rng)});
  const double a = angle_deg * 3.14159265358979323846 / 180.0;
  SyntheticScanOptions o;
  o.width = o.height = 300;
  o.seed = seed;
  o.confidence = 0.9f;
  return SyntheticScan(
      [&](double wx0, double wy0) {
        // Object coordinates of the world point (inverse of rotation a then shift).
        const double wx = wx0 - tx, wy = wy0 - ty;
        const double x = std::cos(a) * wx + std::sin(a) * wy,
                     y = -std::sin(a) * wx + std::cos(a) * wy;
        // Off the plate: no sample (as a scan drops its steep sides), or the empty mount.
        if (empty) return 0.0;
        if (std::abs(x) >= 6e-3 || std::abs(y) >= 6e-3) return std::nan("");
        double z = 1e-3 + 15e-6 * std::sin(x / 0.7e-3) * std::cos(y / 0.9e-3);
        for (const Bump& b : bumps) {
          const double q = (std::pow(x - b.x, 2) + std::pow(y - b.y, 2)) / (b.r * b.r);
          if (q < 1) z += b.h * (1 - q) * (1 - q);
        }
        return z;
      },
      o);
}

class CompareCli : public ::testing::Test {
 protected:
  void SetUp() override {
    work_ = TestTempPath("compare_cli",
                         ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(work_);
    WriteScanFolder(work_ / "a.scan", Relief(0, 0, 0, 1));
    WriteScanFolder(work_ / "b.scan", Relief(5, 0.4e-3, -0.3e-3, 2));
  }
  // 'WORK/name', quoted for the shell (built by append: GCC 12's -Wrestrict misfires on +).
  std::string P(const std::string& name) const {
    std::string q = "'";
    q += (work_ / name).string();
    q += "'";
    return q;
  }
  fs::path work_;
};

TEST_F(CompareCli, WritesTheComparisonFolder) {
  const CliRun r =
      RunCli("compare " + P("a.scan") + " " + P("b.scan") + " --out " + P("ab"), work_);
  ASSERT_EQ(r.code, 0) << r.err;
  for (const char* f : {"deviation.exr", "deviation.png", "report.json", ".mesoscan-output"})
    EXPECT_TRUE(fs::is_regular_file(work_ / "ab" / f)) << f;
  const Json rep = ReadJsonFile(work_ / "ab" / "report.json");
  EXPECT_NEAR(rep.at("b_to_a_rotation_deg").get<double>(), 5.0, 0.01);
  // The plate's points, 1 um of noise in each scan (and B's grid interpolated at A's points
  // re-placed: the coin pairs of compare_test.cc hold the accuracy figures).
  EXPECT_LT(rep.at("deviation_rms_um").get<double>(), 2.0);
  EXPECT_LE(rep.at("changed_fraction").get<double>(), 1e-2);
  const ImageF dev = ReadImage(work_ / "ab" / "deviation.exr");  // Z, sigma, changed
  EXPECT_EQ(dev.width(), 300);
  EXPECT_EQ(dev.channels(), 3);
  // Run again onto its own earlier output: replaced.
  EXPECT_EQ(RunCli("compare " + P("a.scan") + " " + P("b.scan") + " --out " + P("ab"), work_).code,
            0);
}

// CloudCompare (command line, the reference the field uses) on the pair as registered by compare:
// the cloud-to-cloud distance of A's compared points to B moved by b_to_a (a local plane through
// 8 neighbours, -MODEL LS KNN 8) has the median of our deviation's magnitude within 1 um.
TEST_F(CompareCli, CloudCompareDistanceAgreesWithTheDeviation) {
  ASSERT_EQ(std::system("command -v CloudCompare >/dev/null && command -v xvfb-run >/dev/null"), 0)
      << "CloudCompare and xvfb-run are needed (scripts/install-deps: cloudcompare, xvfb)";
  const CliRun r =
      RunCli("compare " + P("a.scan") + " " + P("b.scan") + " --out " + P("ab"), work_);
  ASSERT_EQ(r.code, 0) << r.err;
  const Json rep = ReadJsonFile(work_ / "ab" / "report.json");
  Mat4d t;
  for (int k = 0; k < 16; ++k) t(k / 4, k % 4) = rep.at("b_to_a")[k / 4][k % 4].get<double>();
  const ImageF dev = ReadImage(work_ / "ab" / "deviation.exr");
  const Scan a = ReadScanFolder(work_ / "a.scan"), b = ReadScanFolder(work_ / "b.scan");
  // A's compared points, and B's points in A's frame, as ASCII x y z.
  std::vector<double> ours;
  {
    std::ofstream fa(work_ / "a.xyz"), fb(work_ / "b.xyz");
    fa.precision(10);
    fb.precision(10);
    const HeightField& ha = a.height;
    for (int j = 0; j < ha.height(); ++j)
      for (int i = 0; i < ha.width(); ++i)
        if (std::isfinite(dev(i, j, 0))) {
          fa << ha.X(i) << " " << ha.Y(j) << " " << ha.z(i, j) << "\n";
          ours.push_back(std::abs(dev(i, j, 0)));
        }
    const HeightField& hb = b.height;
    for (int j = 0; j < hb.height(); ++j)
      for (int i = 0; i < hb.width(); ++i)
        if (std::isfinite(hb.z(i, j))) {
          const Vec4d q = t * Vec4d(hb.X(i), hb.Y(j), hb.z(i, j), 1);
          fb << q.x() << " " << q.y() << " " << q.z() << "\n";
        }
  }
  ASSERT_GT(ours.size(), 20000u);
  std::string cc = "cd ";
  cc += P("");
  cc +=
      " && xvfb-run -a CloudCompare -SILENT -AUTO_SAVE OFF -C_EXPORT_FMT ASC -PREC 9 -O a.xyz "
      "-O b.xyz -C2C_DIST -MODEL LS KNN 8 -SAVE_CLOUDS FILE 'a_c2c.asc b_c2c.asc' >cc.log 2>&1";
  ASSERT_EQ(std::system(cc.c_str()), 0) << "CloudCompare failed: see " << (work_ / "cc.log");
  std::vector<double> theirs;
  {
    std::ifstream in(work_ / "a_c2c.asc");
    double x, y, z, d;
    while (in >> x >> y >> z >> d) theirs.push_back(d);
  }
  ASSERT_EQ(theirs.size(), ours.size());
  auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  };
  const double m_ours = median(ours), m_cc = median(theirs);
  std::printf("median |deviation| %.3f um; CloudCompare C2C (LS, 8 neighbours) median %.3f um\n",
              m_ours * 1e6, m_cc * 1e6);
  // Both see the noise of two scans (1 um each): a median of a few tenths of a micrometre.
  EXPECT_GT(m_cc, 0.1e-6);
  EXPECT_LT(m_cc, 3e-6);
  EXPECT_NEAR(m_ours, m_cc, 1e-6);
}

// Another scanner's mesh instead of B: B re-placed, exported by `mesoscan export` as a GLB (the
// hole-filled surface as triangles, glTF +Y up), registered onto A and compared on A's grid.
TEST_F(CompareCli, ComparesWithAReferenceMesh) {
  CliRun r = RunCli("export " + P("b.scan") + " --format glb --out " + P("bexp"), work_);
  ASSERT_EQ(r.code, 0) << r.err;
  fs::path glb;
  for (const auto& e : fs::directory_iterator(work_ / "bexp"))
    if (e.path().extension() == ".glb") glb = e.path();
  ASSERT_FALSE(glb.empty());
  r = RunCli("compare " + P("a.scan") + " --reference '" + glb.string() + "' --out " + P("am"),
             work_);
  ASSERT_EQ(r.code, 0) << r.err;
  const Json rep = ReadJsonFile(work_ / "am" / "report.json");
  std::printf("reference mesh: rotation %.4f deg (true 5), deviation RMS %.3f um\n",
              rep.at("b_to_a_rotation_deg").get<double>(),
              rep.at("deviation_rms_um").get<double>());
  EXPECT_NEAR(rep.at("b_to_a_rotation_deg").get<double>(), 5.0, 0.02);
  // B's 1 um noise on its vertices and A's: as the scan pair's.
  EXPECT_LT(rep.at("deviation_rms_um").get<double>(), 2.0);
  EXPECT_TRUE(rep.at("changed_fraction").is_null());  // a mesh carries no predicted noise
  const ImageF dev = ReadImage(work_ / "am" / "deviation.exr");
  EXPECT_EQ(dev.width(), 300);
  // Both B and --reference, or neither: usage.
  r = RunCli("compare " + P("a.scan") + " " + P("b.scan") + " --reference '" + glb.string() +
                 "' --out " + P("x"),
             work_);
  EXPECT_EQ(r.code, 2) << r.err;
  // A file that is not a mesh: bad input naming it.
  r = RunCli(
      "compare " + P("a.scan") + " --reference " + P("a.scan/report.json") + " --out " + P("x"),
      work_);
  EXPECT_EQ(r.code, 3) << r.err;
  EXPECT_NE(r.err.find("report.json"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(work_ / "x"));
}

TEST_F(CompareCli, BadInputsSayOneLineWithTheirExitCode) {
  // A missing scan folder: bad input naming it, nothing written.
  CliRun r = RunCli("compare " + P("a.scan") + " " + P("nope.scan") + " --out " + P("x"), work_);
  EXPECT_EQ(r.code, 3) << r.err;
  EXPECT_EQ(r.ErrLines(), 1) << r.err;
  EXPECT_NE(r.err.find("nope.scan"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(work_ / "x"));
  // --out inside an input: usage.
  r = RunCli("compare " + P("a.scan") + " " + P("b.scan") + " --out " + P("a.scan/cmp"), work_);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_EQ(r.ErrLines(), 1) << r.err;
  // A bad option value names its flag.
  r = RunCli("compare " + P("a.scan") + " " + P("b.scan") + " --window 4 --out " + P("x"), work_);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("--window"), std::string::npos) << r.err;
  // A scan of the empty mount has no object to register: bad input naming it.
  WriteScanFolder(work_ / "empty.scan", Relief(0, 0, 0, 3, /*empty=*/true));
  r = RunCli("compare " + P("a.scan") + " " + P("empty.scan") + " --out " + P("x"), work_);
  EXPECT_EQ(r.code, 3) << r.err;
  EXPECT_EQ(r.ErrLines(), 1) << r.err;
  EXPECT_NE(r.err.find("empty.scan"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(work_ / "x"));
}

}  // namespace
}  // namespace mesoscan
