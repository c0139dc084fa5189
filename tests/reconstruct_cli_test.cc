// `mesoscan reconstruct` end to end: the independent implementation's coin-edge example
// (shared/spec/examples/coin-edge, scored as its README says: against gt_points.exr over pixels
// valid in both) and the CLI's error contract.

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <string>

#include "core/json.h"
#include "core/scan_folder.h"
#include "tests/cli_util.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) { return CliTempDir("reconcli", name); }

const fs::path kCoinEdge = fs::path(MESOSCAN_SHARED_DIR) / "spec/examples/coin-edge";

TEST(ReconstructCli, CoinEdgeBeatsThePlainDecoder) {
  if (!fs::exists(kCoinEdge / "session.json")) GTEST_SKIP() << "no example at " << kCoinEdge;
  const fs::path out = TempDir("coin_edge.scan");
  const CliResult r =
      RunMesoscan("-q reconstruct " + kCoinEdge.string() + " --out " + out.string());
  ASSERT_EQ(r.code, 0) << r.output;
  for (const char* f : {"points.exr", "height.exr", "normal.exr", "report.json", "error_map.png"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  const Json report = ReadJsonFile(out / "report.json");
  const Json& gt = report.at("ground_truth");
  // The examples README: a plain decoder reaches coverage 100%, RMS 2.7 um, no gross errors.
  EXPECT_GE(gt.at("coverage").get<double>(), 0.99);
  EXPECT_LT(gt.at("rms_m").get<double>(), 2.7e-6);
  EXPECT_LT(gt.at("gross_fraction").get<double>(), 1e-3);
  EXPECT_GT(report.at("summary").at("timings_s").at("decode").get<double>(), 0.0);
  // points.exr: camera grid, NaN exactly where confidence is 0.
  const Scan scan = ReadScanFolder(out);
  EXPECT_EQ(scan.points.xyz.width(), 192);
  EXPECT_EQ(scan.points.xyz.height(), 144);
  int64_t bad = 0;
  for (size_t i = 0; i < scan.points.confidence.pixels(); ++i) {
    const bool finite = std::isfinite(scan.points.xyz.channel(2)[i]);
    const float c = scan.points.confidence.data()[i];
    bad += finite != (c > 0) || c < 0 || c > 1;
  }
  EXPECT_EQ(bad, 0);
  EXPECT_GT(scan.height.width(), 0);
  fs::remove_all(out);
}

TEST(ReconstructCli, RoiAndPhaseShiftOnly) {
  if (!fs::exists(kCoinEdge / "session.json")) GTEST_SKIP() << "no example at " << kCoinEdge;
  const fs::path out = TempDir("roi.scan");
  const CliResult r = RunMesoscan("-q reconstruct " + kCoinEdge.string() + " --out " +
                                  out.string() + " --roi 40,30,64,48 --no-lens-shift --threads 1");
  ASSERT_EQ(r.code, 0) << r.output;
  const Json report = ReadJsonFile(out / "report.json");
  EXPECT_EQ(report.at("summary").at("pixels").at("roi").get<int64_t>(), 64 * 48);
  EXPECT_FALSE(report.at("summary").at("used_lens_shift").get<bool>());
  // Phase shifting alone (9 frames) is several times noisier than with lens shift, but finds
  // the surface: coverage within the ROI.
  EXPECT_GE(report.at("ground_truth").at("coverage").get<double>(), 0.95);
  fs::remove_all(out);
}

// `reconstruct --export` writes the same exports as `mesoscan export`, from the scan in memory.
TEST(ReconstructCli, ExportFromReconstruct) {
  if (!fs::exists(kCoinEdge / "session.json")) GTEST_SKIP() << "no example at " << kCoinEdge;
  const fs::path out = TempDir("export.scan");
  const CliResult r = RunMesoscan("-q reconstruct " + kCoinEdge.string() + " --out " +
                                  out.string() + " --roi 40,30,64,48 --export glb,png16");
  ASSERT_EQ(r.code, 0) << r.output;
  // Files named after the scan folder without ".scan", as `mesoscan export` names them.
  const std::string n = out.stem().string();
  for (const std::string& f :
       {n + ".glb", n + "_height.png", n + "_height.json", std::string("manifest.json")})
    EXPECT_TRUE(fs::exists(out / "export" / f)) << f;
  EXPECT_FALSE(fs::exists(out / "export/scan.glb"));
  EXPECT_FALSE(fs::exists(out / "export" / (n + "_height.exr")));  // only the formats asked for
  const CliResult bad = RunMesoscan("-q reconstruct " + kCoinEdge.string() + " --out " +
                                    out.string() + "2 --export tiff");
  EXPECT_EQ(bad.code, 2) << bad.output;
  EXPECT_FALSE(fs::exists(out.string() + "2"));  // refused before any work
  fs::remove_all(out);
}

TEST(ReconstructCli, ErrorsAreOneLineWithExitCodes) {
  const fs::path out = TempDir("err.scan");
  CliResult r = RunMesoscan("reconstruct /nonexistent/session --out " + out.string());
  EXPECT_EQ(r.code, 3) << r.output;
  EXPECT_NE(r.output.find("session.json"), std::string::npos) << r.output;
  r = RunMesoscan("reconstruct " + kCoinEdge.string() + " --out " + out.string() +
                  " --roi 1,2,three,4");
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_NE(r.output.find("--roi"), std::string::npos) << r.output;
  r = RunMesoscan("reconstruct " + kCoinEdge.string() + " --out " + out.string() +
                  " --fitter magic");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("--fitter"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(out));
}

}  // namespace
}  // namespace mesoscan
