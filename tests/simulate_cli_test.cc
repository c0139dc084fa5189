// `mesoscan simulate` end to end: the binary writes a session that the session reader accepts,
// with ground truth; bad values exit 2 (usage) or 3 (bad input) with one line.

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <string>

#include "core/image_io.h"
#include "core/scan_folder.h"
#include "session/session.h"
#include "tests/cli_util.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) { return CliTempDir("simcli", name); }

int Lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n';
  return n;
}

TEST(SimulateCli, WritesAReadableSessionWithGroundTruth) {
  const fs::path out = TempDir("coin");
  const CliResult r = RunMesoscan("-q simulate --object coin --rig paper --out " + out.string() +
                                  " --crop 64x48+1200+690 --ls-frames 8 --supersample 2 --seed 3"
                                  " --object-pixel-size 40e-6");
  ASSERT_EQ(r.code, 0) << r.output;
  const Session s = ReadSession(out);
  EXPECT_EQ(s.frames.size(), 9u + 8u + 2u);
  EXPECT_EQ(s.rig.camera.width, 64);
  EXPECT_EQ(s.rig.camera.height, 48);
  EXPECT_NEAR(s.rig.camera.K(0, 2), 1087.5 - 1200, 1e-12);
  ASSERT_TRUE(s.ground_truth.has_value());
  const ImageF pts = ReadExrChannels(out / s.ground_truth->points, {"X", "Y", "Z"});
  EXPECT_EQ(pts.width(), 64);
  const HeightField gt = ReadHeightExr(out / s.ground_truth->height);
  EXPECT_EQ(gt.width(), 64);
  EXPECT_EQ(gt.height(), 48);
  // The frames are 16-bit and differ between phases.
  ImageInfo info;
  const ImageF a = ReadImageGrey(s.FramePath(0), &info);
  const ImageF b = ReadImageGrey(s.FramePath(1));
  EXPECT_EQ(info.bits_per_sample, 16);
  double diff = 0;
  for (size_t k = 0; k < a.pixels(); ++k) diff += std::abs(a.data()[k] - b.data()[k]);
  EXPECT_GT(diff / a.pixels(), 0.01);
  // No temporary folders are left next to the output.
  for (const auto& e : fs::directory_iterator(out.parent_path()))
    EXPECT_EQ(e.path().filename().string().find(".mesoscan_simcli_" + std::to_string(getpid())),
              std::string::npos);
  fs::remove_all(out);
}

TEST(SimulateCli, ProjectorGammaIsRecorded) {
  const fs::path out = TempDir("gamma");
  const CliResult r =
      RunMesoscan("-q simulate --object plane --out " + out.string() +
                  " --crop 16x16+1080+700 --ls-frames 0 --projector-gamma 2.2 --noise 0");
  ASSERT_EQ(r.code, 0) << r.output;
  const Session s = ReadSession(out);
  EXPECT_EQ(s.rig.projector_response.kind, Response::Kind::kGamma);
  EXPECT_DOUBLE_EQ(s.rig.projector_response.gamma, 2.2);
  fs::remove_all(out);
}

TEST(SimulateCli, RigFileRoundTrip) {
  // A RIG.json holding the rig of a simulated session reproduces it.
  const fs::path first = TempDir("rig1"), second = TempDir("rig2");
  ASSERT_EQ(RunMesoscan("-q simulate --object plane --out " + first.string() +
                        " --crop 16x16+1080+700 --ls-frames 0 --noise 0 --supersample 1")
                .code,
            0);
  const Session s1 = ReadSession(first);
  const fs::path rig_file = TempDir("rig.json");
  {
    Json j = SessionToJson(s1);
    FILE* f = fopen(rig_file.c_str(), "w");
    ASSERT_NE(f, nullptr);
    const std::string text = Json{{"rig", j["rig"]}}.dump(2);
    fwrite(text.data(), 1, text.size(), f);
    fclose(f);
  }
  const CliResult r =
      RunMesoscan("-q simulate --object plane --rig " + rig_file.string() + " --out " +
                  second.string() + " --ls-frames 0 --noise 0 --supersample 1");
  ASSERT_EQ(r.code, 0) << r.output;
  const Session s2 = ReadSession(second);
  EXPECT_EQ(s2.rig.camera.width, 16);
  EXPECT_LT((s2.rig.camera.K - s1.rig.camera.K).norm(), 1e-9);
  // Same scene, same rig, no noise: identical frames.
  const ImageF a = ReadImageGrey(s1.FramePath(0)), b = ReadImageGrey(s2.FramePath(0));
  for (size_t k = 0; k < a.pixels(); ++k) ASSERT_EQ(a.data()[k], b.data()[k]);
  fs::remove_all(first);
  fs::remove_all(second);
  fs::remove(rig_file);
}

TEST(SimulateCli, BadValuesExitWithOneLine) {
  const fs::path out = TempDir("bad");
  struct Case {
    std::string args;
    int code;
    std::string mentions;
  };
  const Case cases[] = {
      {"--object coin --supersample 0", 2, "--supersample"},
      {"--object coin --crop 10x10", 2, "--crop"},
      {"--object coin --crop 100x100+2100+0", 2, "--crop"},
      {"--object coin --ps-periods 7,x", 2, "--ps-periods"},
      {"--object coin --ps-phases 2", 2, "--ps-phases"},
      {"--object coin --ls-frames 2", 2, "--ls-frames"},
      {"--object teapot", 3, "--object"},
      {"--object /nonexistent/height.exr", 3, "height.exr"},
      {"--object coin --rig /nonexistent/rig.json", 3, "rig.json"},
      {"--object coin --noise -1", 2, "--noise"},
  };
  for (const Case& c : cases) {
    const CliResult r = RunMesoscan("-q simulate --out " + out.string() + " " + c.args);
    EXPECT_EQ(r.code, c.code) << c.args << ": " << r.output;
    EXPECT_EQ(Lines(r.output), 1) << c.args << ": " << r.output;
    EXPECT_NE(r.output.find(c.mentions), std::string::npos) << c.args << ": " << r.output;
    EXPECT_FALSE(fs::exists(out)) << c.args;
  }
}

TEST(SimulateCli, HelpDescribesTheOptions) {
  const CliResult r = RunMesoscan("simulate --help");
  EXPECT_EQ(r.code, 0);
  for (const char* opt :
       {"--object", "--rig", "--out", "--ps-periods", "--ps-phases", "--ls-frames", "--noise",
        "--seed", "--crop", "--supersample", "--projector-gamma"})
    EXPECT_NE(r.output.find(opt), std::string::npos) << opt;
}

}  // namespace
}  // namespace mesoscan
