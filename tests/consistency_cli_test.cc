// Captures that contradict their session.json, codes too coarse or too noisy for their stripes,
// through the real `mesoscan` binary on small simulated sessions with ground truth: either the
// capture is refused (exit 3, one line naming the frames), or every point kept lies within
// 100 um of the truth (report.json's ground truth: max |error| and the gross count, whose
// threshold is absolute), and `check` is as strict as `reconstruct`.

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <string>

#include "core/image_io.h"
#include "core/json.h"
#include "session/session.h"
#include "tests/cli_util.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

// Single-quoted for the shell.
std::string Q(const fs::path& p) {
  std::string q = "'";
  q += p.string();
  q += '\'';
  return q;
}

class Consistency : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    work_ = new fs::path(CliTempDir("consistency", "work"));
    fs::create_directories(*work_);
    session_ = new fs::path(*work_ / "S");
    const CliRun r =
        RunCli("simulate --object coin --crop 160x120+1000+700 --out " + Q(*session_), *work_);
    ASSERT_EQ(r.code, 0) << r.err;
  }
  static void TearDownTestSuite() {
    fs::remove_all(*work_);
    delete work_;
    delete session_;
  }
  static fs::path Copy(const std::string& name) {
    const fs::path d = *work_ / name;
    fs::remove_all(d);
    fs::copy(*session_, d, fs::copy_options::recursive);
    return d;
  }
  // The session's frame files of sine period `period` (in session order).
  static std::vector<std::string> SineFrames(const fs::path& s, double period) {
    std::vector<std::string> files;
    const Json session_json = ReadJsonFile(s / "session.json");
    for (const Json& f : session_json["frames"])
      if (f["pattern"]["type"] == "sine" && f["pattern"]["period_px"].get<double>() == period)
        files.push_back(f["file"]);
    return files;
  }
  // `reconstruct` (and `check`) of a session: refused naming one of `names`, or every point
  // kept within 100 um of the truth. Returns true if refused.
  static bool ExpectRefusedOrWithin100um(const fs::path& s, const std::vector<std::string>& names,
                                         const std::string& what) {
    const fs::path out = *work_ / ("SC_" + s.filename().string());
    const CliRun r = RunCli("reconstruct " + Q(s) + " --out " + Q(out), *work_);
    const CliRun c = RunCli("check " + Q(s), *work_);
    if (r.code != 0) {
      EXPECT_EQ(r.code, 3) << what << ": " << r.err;
      EXPECT_EQ(r.ErrLines(), 1) << what << ": " << r.err;
      bool named = false;
      for (const std::string& n : names) named = named || r.err.find(n) != std::string::npos;
      EXPECT_TRUE(named) << what << ": " << r.err;
      EXPECT_FALSE(fs::exists(out)) << what;
      EXPECT_EQ(c.code, 3) << what << ": check is weaker than reconstruct: " << c.out << c.err;
      std::printf("%-40s refused: %s", what.c_str(), r.err.c_str());
      return true;
    }
    EXPECT_EQ(c.code, 0) << what << ": " << c.err;
    const Json gt = ReadJsonFile(out / "report.json").at("ground_truth");
    const Json px = ReadJsonFile(out / "report.json").at("summary").at("pixels");
    std::printf("%-40s %lld points, max |error| %.1f um, gross %lld (threshold %.0f um)\n",
                what.c_str(), static_cast<long long>(gt["pixels_both"].get<int64_t>()),
                gt["max_abs_m"].get<double>() * 1e6,
                static_cast<long long>(gt["gross"].get<int64_t>()),
                gt["gross_threshold_m"].get<double>() * 1e6);
    EXPECT_LE(gt["max_abs_m"].get<double>(), 100e-6) << what << ": " << px.dump();
    EXPECT_EQ(gt["gross"].get<int64_t>(), 0) << what;
    EXPECT_DOUBLE_EQ(gt["gross_threshold_m"].get<double>(), 100e-6) << what;
    fs::remove_all(out);
    return false;
  }

  static fs::path* work_;
  static fs::path* session_;
};
fs::path* Consistency::work_ = nullptr;
fs::path* Consistency::session_ = nullptr;

// The good session stays good: exit 0, points within 100 um, the gross threshold absolute.
TEST_F(Consistency, GoodSessionKeepsItsPoints) {
  EXPECT_FALSE(ExpectRefusedOrWithin100um(*session_, {}, "good session"));
  const CliRun r = RunCli("reconstruct " + Q(*session_) + " --out " + Q(*work_ / "SC"), *work_);
  ASSERT_EQ(r.code, 0) << r.err;
  const Json gt = ReadJsonFile(*work_ / "SC" / "report.json").at("ground_truth");
  EXPECT_GT(gt["coverage"].get<double>(), 0.9);
  fs::remove_all(*work_ / "SC");
}

// Two phase frames swapped, a frame copied over another, a frame of another object, a frame in
// float 0..65535 units: refused naming the period's frames, or no point kept off the surface.
TEST_F(Consistency, MislabelledFramesAreRefusedOrRejected) {
  {
    const fs::path s = Copy("swapped");
    const auto f = SineFrames(s, 7);
    ASSERT_GE(f.size(), 3u);
    fs::rename(s / f[0], s / "tmp.png");
    fs::rename(s / f[1], s / f[0]);
    fs::rename(s / "tmp.png", s / f[1]);
    ExpectRefusedOrWithin100um(s, f, "two phase frames swapped");
  }
  {
    const fs::path s = Copy("copied");
    const auto f = SineFrames(s, 11);
    fs::copy_file(s / f[0], s / f[2], fs::copy_options::overwrite_existing);
    ExpectRefusedOrWithin100um(s, f, "a frame copied over another");
  }
  {
    const fs::path plane = *work_ / "plane";
    ASSERT_EQ(RunCli("simulate --object plane --crop 160x120+1000+700 --ls-frames 0 --no-white "
                     "--no-black --out " +
                         Q(plane),
                     *work_)
                  .code,
              0);
    const fs::path s = Copy("foreign");
    const auto f = SineFrames(s, 13);
    fs::copy_file(plane / f[1], s / f[1], fs::copy_options::overwrite_existing);
    ExpectRefusedOrWithin100um(s, f, "a frame of another object");
    fs::remove_all(plane);
  }
  {
    const fs::path s = Copy("units");
    const auto f = SineFrames(s, 7);
    ImageF im = ReadImage(s / f[2]);
    for (float& v : im.data()) v *= 65535.0f;
    const std::string exr = fs::path(f[2]).replace_extension(".exr").string();
    WriteExr(s / exr, im, {"Y"});
    Json j = ReadJsonFile(s / "session.json");
    for (Json& fr : j["frames"])
      if (fr["file"] == f[2]) fr["file"] = exr;
    WriteJsonFile(s / "session.json", j);
    std::vector<std::string> names = f;
    names.push_back(exr);
    ExpectRefusedOrWithin100um(s, names, "a float frame in 0..65535 units");
  }
}

// session.json that does not describe its frames: two periods' labels swapped, the phases of a
// period listed out of order.
TEST_F(Consistency, SessionJsonThatContradictsTheFrames) {
  {
    const fs::path s = Copy("labels");
    Json j = ReadJsonFile(s / "session.json");
    for (Json& fr : j["frames"]) {
      if (fr["pattern"]["type"] != "sine") continue;
      const double p = fr["pattern"]["period_px"];
      if (p == 7) fr["pattern"]["period_px"] = 11.0;
      if (p == 11) fr["pattern"]["period_px"] = 7.0;
    }
    WriteJsonFile(s / "session.json", j);
    std::vector<std::string> names = SineFrames(*session_, 7);
    for (const auto& n : SineFrames(*session_, 11)) names.push_back(n);
    ExpectRefusedOrWithin100um(s, names, "two periods' labels swapped");
  }
  {
    const fs::path s = Copy("phases");
    Json j = ReadJsonFile(s / "session.json");
    std::vector<Json*> p13;
    for (Json& fr : j["frames"])
      if (fr["pattern"]["type"] == "sine" && fr["pattern"]["period_px"].get<double>() == 13)
        p13.push_back(&fr);
    ASSERT_GE(p13.size(), 3u);
    std::swap((*p13[0])["pattern"]["phase"], (*p13[2])["pattern"]["phase"]);
    WriteJsonFile(s / "session.json", j);
    ExpectRefusedOrWithin100um(s, SineFrames(s, 13), "phases listed out of order");
  }
}

// A one-period cue as wide as the projector (800 px), or two such (1000, 1100), cannot fix the
// 2-px stripes' period at this noise: refused with the reason, or no point off the surface.
TEST_F(Consistency, CueOnlyPeriodsWithLensShift) {
  for (const std::string periods : {"800", "1000,1100"}) {
    const fs::path s = *work_ / ("cue_" + periods);
    ASSERT_EQ(RunCli("simulate --object coin --crop 160x120+1000+700 --ps-periods " + periods +
                         " --out " + Q(s),
                     *work_)
                  .code,
              0);
    if (ExpectRefusedOrWithin100um(s, {"session.json"}, "cue only, periods " + periods)) {
      const CliRun r = RunCli("reconstruct " + Q(s) + " --out " + Q(*work_ / "x"), *work_);
      EXPECT_NE(r.err.find("shorter periods"), std::string::npos) << r.err;
    }
    fs::remove_all(s);
  }
}

// Dark captures: 8-bit, exposure 0.08, blur 1, ambient 10, gain jitter 0.02, seeds 1-3; and
// 16-bit at exposure 0.08, ambient 10.
TEST_F(Consistency, DarkCapturesKeepNoWrongPoint) {
  for (const int seed : {1, 2, 3}) {
    const fs::path s = *work_ / ("dark8_" + std::to_string(seed));
    ASSERT_EQ(RunCli("simulate --object coin --crop 160x120+1000+700 --adc-bits 8 --exposure 0.08 "
                     "--blur 1.0 --ambient 10 --gain-jitter 0.02 --seed " +
                         std::to_string(seed) + " --out " + Q(s),
                     *work_)
                  .code,
              0);
    ExpectRefusedOrWithin100um(s, {"session.json"}, "dark, 8-bit, seed " + std::to_string(seed));
    fs::remove_all(s);
  }
  const fs::path s = *work_ / "dark16";
  ASSERT_EQ(RunCli("simulate --object coin --crop 160x120+1000+700 --adc-bits 16 --exposure 0.08 "
                   "--ambient 10 --out " +
                       Q(s),
                   *work_)
                .code,
            0);
  ExpectRefusedOrWithin100um(s, {"session.json"}, "dark, 16-bit");
  fs::remove_all(s);
}

// A code too coarse for the promised 100 um (a 50-px period over an 800-px cue, no lens shift)
// is refused with that reason, not blamed on dark frames; a dim 16-bit capture that keeps fewer
// than half of its lit pixels says so with the reason.
TEST_F(Consistency, CoarseCodeAndDimCaptureSayWhy) {
  const fs::path coarse = *work_ / "coarse";
  ASSERT_EQ(RunCli("simulate --object coin --crop 160x120+1000+700 --ls-frames 0 "
                   "--ps-periods 800,50 --out " +
                       Q(coarse),
                   *work_)
                .code,
            0);
  const CliRun r = RunCli("reconstruct " + Q(coarse) + " --out " + Q(*work_ / "coarse_sc"), *work_);
  EXPECT_EQ(r.code, 3) << r.err;
  EXPECT_NE(r.err.find("predicted depth sigma exceeds 20 um"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("add shorter sine periods"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("dark"), std::string::npos) << r.err;
  fs::remove_all(coarse);

  const fs::path dim = *work_ / "dim16";
  ASSERT_EQ(RunCli("simulate --object coin --crop 160x120+1000+700 --adc-bits 16 --exposure 0.08 "
                   "--out " +
                       Q(dim),
                   *work_)
                .code,
            0);
  const fs::path out = *work_ / "dim16_sc";
  const CliRun d = RunCli("reconstruct " + Q(dim) + " --out " + Q(out), *work_);
  ASSERT_EQ(d.code, 0) << d.err;
  const Json px = ReadJsonFile(out / "report.json").at("summary").at("pixels");
  const int64_t valid = px["valid"].get<int64_t>(), lit = px["lit"].get<int64_t>();
  std::printf("dim 16-bit capture: %lld of %lld lit pixels kept\n", static_cast<long long>(valid),
              static_cast<long long>(lit));
  // The warning (stderr without -q) is also in report.json.
  const Json report = ReadJsonFile(out / "report.json");
  if (valid * 2 < lit) {
    ASSERT_TRUE(report.contains("warnings")) << report.dump();
    const std::string w = report["warnings"].at(0).get<std::string>();
    EXPECT_NE(w.find("lit pixels gave a point"), std::string::npos) << w;
    EXPECT_NE(w.find("too noisy"), std::string::npos) << w;
  } else {
    EXPECT_FALSE(report.contains("warnings")) << report.dump();
  }
  fs::remove_all(dim);
  fs::remove_all(out);
}

// A coarser rig (a 640x480 camera, 250 um footprint) with a common three-frequency set (42, 45,
// 48 px, three steps, 8-bit, no lens shift): its points' depth noise (~30 um) is what its own
// sampling allows, so they are kept (before: all refused as over 20 um), at their predicted
// noise and without blunders.
TEST_F(Consistency, CoarseRigKeepsItsOwnPrecision) {
  Json rig = ReadJsonFile(*session_ / "session.json").at("rig");
  rig["camera"]["K"] =
      Json::array({Json::array({1000.0, 0.0, 319.5}), Json::array({0.0, 1000.0, 239.5}),
                   Json::array({0.0, 0.0, 1.0})});
  rig["camera"]["width"] = 640;
  rig["camera"]["height"] = 480;
  const fs::path rig_file = *work_ / "coarse_rig.json";
  WriteJsonFile(rig_file, Json{{"rig", rig}});
  const fs::path s = *work_ / "coarse_rig", out = *work_ / "coarse_rig_sc";
  ASSERT_EQ(RunCli("simulate --object coin --rig " + Q(rig_file) +
                       " --crop 200x150+220+165 --ps-periods 42,45,48 --ls-frames 0 --adc-bits 8 "
                       "--out " +
                       Q(s),
                   *work_)
                .code,
            0);
  const CliRun r = RunCli("reconstruct " + Q(s) + " --out " + Q(out), *work_);
  ASSERT_EQ(r.code, 0) << r.err;
  const Json report = ReadJsonFile(out / "report.json");
  const Json& gt = report.at("ground_truth");
  const double predicted = report.at("summary").at("predicted_depth_rms_m").get<double>();
  std::printf(
      "coarse rig, 42/45/48 x 3, 8-bit: coverage %.4f, RMS %.1f um (predicted %.1f um), "
      "max %.1f um\n",
      gt["coverage"].get<double>(), gt["rms_m"].get<double>() * 1e6, predicted * 1e6,
      gt["max_abs_m"].get<double>() * 1e6);
  EXPECT_GE(gt["coverage"].get<double>(), 0.98);
  EXPECT_LE(gt["rms_m"].get<double>(), 1.5 * predicted);
  EXPECT_LE(gt["max_abs_m"].get<double>(), 10 * predicted);
  fs::remove_all(s);
  fs::remove_all(out);
}

}  // namespace
}  // namespace mesoscan
