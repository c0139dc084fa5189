// mesoscan brdf info|plot|tabulate through the executable: every shared RGL file gets an info line
// and a readable plot; a MERL-layout table written by `tabulate` reads back; bad input is one line
// and exit code 3.

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "core/image_io.h"
#include "core/test_temp_dir.h"

namespace {
namespace fs = std::filesystem;

const fs::path kDataDir = fs::path(MESOSCAN_SHARED_DIR) / "data" / "brdf";

struct CliRun {
  int code = -1;
  std::string out;  // stdout and stderr together
};

CliRun Mesoscan(const std::string& args) {
  const std::string cmd = std::string(MESOSCAN_EXE) + " -q " + args + " 2>&1";
  CliRun r;
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) return r;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), p)) > 0) r.out.append(buf.data(), n);
  const int status = pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

fs::path TempDir(const std::string& name) { return mesoscan::TestTempDir("brdf_cli_test", name); }

TEST(BrdfCli, InfoAndPlotForEverySharedFile) {
  if (!fs::is_directory(kDataDir)) GTEST_SKIP() << kDataDir << " is absent";
  const fs::path out = TempDir("plots");
  int files = 0;
  for (const auto& e : fs::directory_iterator(kDataDir)) {
    if (e.path().extension() != ".bsdf") continue;
    ++files;
    const CliRun info = Mesoscan("brdf info " + e.path().string());
    ASSERT_EQ(info.code, 0) << info.out;
    EXPECT_NE(info.out.find("RGL tensor_file"), std::string::npos) << info.out;
    EXPECT_NE(info.out.find("8 theta_i"), std::string::npos) << info.out;
    EXPECT_NE(info.out.find("albedo:"), std::string::npos) << info.out;
    // Energy: satin_rosaline's grazing slices reflect up to 1.155 and are clamped; the rest
    // conserve energy. -q hides the load warning, the info line stays.
    if (e.path().filename() == "satin_rosaline_rgb.bsdf") {
      EXPECT_NE(info.out.find("energy:      clamped: 2 of 8 incident slices"), std::string::npos)
          << info.out;
      EXPECT_NE(info.out.find("max albedo before 1.15"), std::string::npos) << info.out;
    } else {
      EXPECT_NE(info.out.find("energy:      conserving"), std::string::npos) << info.out;
    }
    const fs::path png = out / (e.path().stem().string() + ".png");
    const CliRun plot = Mesoscan("brdf plot " + e.path().string() + " --out " + png.string());
    ASSERT_EQ(plot.code, 0) << plot.out;
    mesoscan::ImageInfo ii;
    const mesoscan::ImageF im = mesoscan::ReadImage(png, &ii);
    EXPECT_EQ(ii.channels, 3);
    EXPECT_EQ(ii.bits_per_sample, 8);
    EXPECT_EQ(im.width(), 4 * 360);
    EXPECT_GT(im.height(), 500);
  }
  EXPECT_EQ(files, 7);
  fs::remove_all(out);
}

TEST(BrdfCli, TabulatedMerlReadsBack) {
  const fs::path dir = TempDir("merl");
  const fs::path merl = dir / "ggx.binary";
  const CliRun tab = Mesoscan(
      "brdf tabulate --alpha 0.25 --fresnel conductor --diffuse 0.2 0.1 0.05 "
      "--out " +
      merl.string());
  ASSERT_EQ(tab.code, 0) << tab.out;
  EXPECT_EQ(fs::file_size(merl), 34992012u);
  const CliRun info = Mesoscan("brdf info " + merl.string());
  ASSERT_EQ(info.code, 0) << info.out;
  EXPECT_NE(info.out.find("MERL binary"), std::string::npos) << info.out;
  // Copper GGX plus a Lambertian base of albedo 0.2 reflects more than 1 in red: clamped, and the
  // load warning is one line when not quiet.
  EXPECT_NE(info.out.find("energy:      clamped:"), std::string::npos) << info.out;
  const std::string loud =
      std::string(MESOSCAN_EXE) + " brdf info " + merl.string() + " 2>&1 >/dev/null";
  FILE* p = popen(loud.c_str(), "r");
  ASSERT_TRUE(p);
  std::string err;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), p)) > 0) err.append(buf.data(), n);
  pclose(p);
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
  EXPECT_NE(err.find("warning: " + merl.string() + ": directional albedo exceeds 1"),
            std::string::npos)
      << err;
  const CliRun plot =
      Mesoscan("brdf plot " + merl.string() + " --theta 0 60 --out " + (dir / "merl.png").string());
  ASSERT_EQ(plot.code, 0) << plot.out;
  EXPECT_TRUE(fs::exists(dir / "merl.png"));
  fs::remove_all(dir);
}

TEST(BrdfCli, BadInputIsOneLineAndExitCode3) {
  const fs::path dir = TempDir("bad");
  std::ofstream(dir / "junk.binary", std::ios::binary) << "not a brdf";
  const CliRun r = Mesoscan("brdf info " + (dir / "junk.binary").string());
  EXPECT_EQ(r.code, 3) << r.out;
  EXPECT_NE(r.out.find("junk.binary"), std::string::npos) << r.out;
  EXPECT_EQ(std::count(r.out.begin(), r.out.end(), '\n'), 1) << r.out;
  const CliRun missing = Mesoscan("brdf plot " + (dir / "none.bsdf").string() + " --out x.png");
  EXPECT_EQ(missing.code, 3) << missing.out;
  const CliRun usage = Mesoscan("brdf plot");
  EXPECT_EQ(usage.code, 2) << usage.out;
  fs::remove_all(dir);
}

}  // namespace
