// Bad values through the real `mesoscan` binary: a damaged sample in a scan, nesting and numbers
// that crashed the readers or the fitters, sizes that tripped internal checks, temporaries that
// nothing removed, `check` weaker than the commands it precedes, and the messages and exit
// codes of the README. Each case: the exit code, one line on stderr naming what is wrong, no
// output, inputs untouched. The session is `simulate --object coin --crop 160x120+1000+700`.

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>

#include "core/fs.h"
#include "core/height_field.h"
#include "core/image_io.h"
#include "core/json.h"
#include "core/scan_folder.h"
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

class BadValues : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    work_ = new fs::path(CliTempDir("bad_values", "work"));
    fs::create_directories(*work_ / "in");
    session_ = new fs::path(*work_ / "in" / "S");
    scan_ = new fs::path(*work_ / "in" / "SC");
    CliRun r =
        RunCli("simulate --object coin --crop 160x120+1000+700 --out " + Q(*session_), *work_);
    ASSERT_EQ(r.code, 0) << r.err;
    r = RunCli("reconstruct " + Q(*session_) + " --out " + Q(*scan_), *work_);
    ASSERT_EQ(r.code, 0) << r.err;
  }
  static void TearDownTestSuite() {
    fs::remove_all(*work_);
    delete work_;
    delete session_;
    delete scan_;
  }
  void SetUp() override { before_ = FileSnapshot(*work_ / "in"); }
  void TearDown() override {
    EXPECT_EQ(FileSnapshot(*work_ / "in"), before_) << "an input changed";
  }
  static CliRun Cli(const std::string& args, const std::string& env = "") {
    return RunCli(args, *work_, "", env);
  }
  static void ExpectRefused(const CliRun& r, int code, const std::string& needle,
                            const std::string& what = "") {
    EXPECT_EQ(r.code, code) << what << ": " << r.err;
    EXPECT_EQ(r.ErrLines(), 1) << what << ": " << r.err;
    EXPECT_NE(r.err.find(needle), std::string::npos)
        << what << ": expected '" << needle << "' in " << r.err;
  }
  static fs::path CopyOf(const fs::path& src, const std::string& name) {
    const fs::path d = *work_ / name;
    fs::remove_all(d);
    fs::copy(src, d, fs::copy_options::recursive);
    return d;
  }

  static fs::path* work_;
  static fs::path* session_;
  static fs::path* scan_;
  std::map<std::string, std::pair<uintmax_t, int64_t>> before_;
};
fs::path* BadValues::work_ = nullptr;
fs::path* BadValues::session_ = nullptr;
fs::path* BadValues::scan_ = nullptr;

// One 1e30 in height.exr: check, export and maps refuse it naming the file and the sample (the
// PNG quantisation, the GLB vertex and the curvature it would poison).
TEST_F(BadValues, OneBadSampleIsRefused) {
  const fs::path bad = CopyOf(*scan_, "SC_1e30");
  HeightField h = ReadHeightExr(bad / "height.exr");
  int x = -1, y = -1;
  for (int j = 0; j < h.height() && x < 0; ++j)
    for (int i = 0; i < h.width(); ++i)
      if (std::isfinite(h.z(i, j))) {
        x = i, y = j;
        break;
      }
  ASSERT_GE(x, 0);
  h.z(x, y) = 1e30f;
  WriteHeightExr(bad / "height.exr", h);
  const std::string sample = "(" + std::to_string(x) + ", " + std::to_string(y) + ")";
  ExpectRefused(Cli("check " + Q(bad)), 3, sample, "check");
  ExpectRefused(Cli("export " + Q(bad) + " --out " + Q(*work_ / "E")), 3, sample, "export");
  ExpectRefused(Cli("maps " + Q(bad) + " --out " + Q(*work_ / "M")), 3, sample, "maps");
  EXPECT_FALSE(fs::exists(*work_ / "E"));
  EXPECT_FALSE(fs::exists(*work_ / "M"));
  fs::remove_all(bad);
}

// Nesting 150,000 deep in session.json, a rig file and report.json: refused with one line (the
// copy of unknown keys recursed once per level and overflowed the stack).
TEST_F(BadValues, DeeplyNestedJsonIsRefused) {
  std::string deep = "{\"deep\": ";
  for (int i = 0; i < 150000; ++i) deep += "[";
  for (int i = 0; i < 150000; ++i) deep += "]";
  deep += "}";
  const fs::path s = CopyOf(*session_, "S_deep");
  std::string text = ReadTextFile(s / "session.json");
  text.insert(text.find('{') + 1, "\"unknown\": " + deep + ",");
  std::ofstream(s / "session.json", std::ios::trunc) << text;
  ExpectRefused(Cli("check --quick " + Q(s)), 3, "nested deeper", "check");
  ExpectRefused(Cli("reconstruct " + Q(s) + " --out " + Q(*work_ / "SC_deep")), 3, "nested deeper",
                "reconstruct");
  Json rig = ReadJsonFile(*session_ / "session.json")["rig"];
  std::string rig_text = Json{{"rig", rig}}.dump();
  rig_text.insert(rig_text.find('{') + 1, "\"x\": " + deep + ",");
  std::ofstream(*work_ / "deep_rig.json") << rig_text;
  ExpectRefused(Cli("simulate --object plane --crop 32x24+1000+700 --rig " +
                    Q(*work_ / "deep_rig.json") + " --out " + Q(*work_ / "S_rig")),
                3, "nested deeper", "simulate --rig");
  EXPECT_FALSE(fs::exists(*work_ / "SC_deep"));
  EXPECT_FALSE(fs::exists(*work_ / "S_rig"));
  fs::remove_all(s);
  fs::remove(*work_ / "deep_rig.json");
}

// Lens-shifter numbers that crashed the batch fitter: refused naming the key.
TEST_F(BadValues, LensShifterNumbersAreRefused) {
  for (const auto& [key, value] : std::vector<std::pair<std::string, std::string>>{
           {"steps_per_px", "1e-6"}, {"range", "1070000000"}, {"range", "-1070000000"}}) {
    const fs::path s = CopyOf(*session_, "S_shift");
    Json j = ReadJsonFile(s / "session.json");
    Json& ls = j["rig"]["lens_shifter"];
    if (key == "steps_per_px") {
      ls["steps_per_px"] = std::stod(value);
    } else {
      const int64_t v = std::stoll(value);
      ls["range_steps"] = {std::min<int64_t>(v, -2048), std::max<int64_t>(v, 2048)};
      for (Json& f : j["frames"])
        if (f["pattern"]["type"] == "stripes" && f["shift_steps"].get<int64_t>() > 0 && v > 0)
          f["shift_steps"] = v;
        else if (f["pattern"]["type"] == "stripes" && f["shift_steps"].get<int64_t>() < 0 && v < 0)
          f["shift_steps"] = v;
    }
    WriteJsonFile(s / "session.json", j);
    ExpectRefused(Cli("check --quick " + Q(s)), 3, "rig.lens_shifter", key + " " + value);
    ExpectRefused(Cli("reconstruct " + Q(s) + " --out " + Q(*work_ / "SC_shift")), 3,
                  "rig.lens_shifter", key + " " + value);
    EXPECT_FALSE(fs::exists(*work_ / "SC_shift"));
    fs::remove_all(s);
  }
}

// Sizes that tripped internal checks (exit 70): a 1-row ROI, a camera beyond the memory budget.
TEST_F(BadValues, SizesThatWereInternalErrors) {
  ExpectRefused(
      Cli("reconstruct " + Q(*session_) + " --out " + Q(*work_ / "R1") + " --roi 0,60,160,1"), 2,
      "--roi");
  ExpectRefused(
      Cli("reconstruct " + Q(*session_) + " --out " + Q(*work_ / "R1") + " --roi 0,0,160,2"), 2,
      "--roi");
  EXPECT_FALSE(fs::exists(*work_ / "R1"));
  Json rig = ReadJsonFile(*session_ / "session.json")["rig"];
  rig["camera"]["width"] = 8000;
  rig["camera"]["height"] = 8000;
  rig["camera"]["K"][0][2] = 3999.5;
  rig["camera"]["K"][1][2] = 3999.5;
  WriteJsonFile(*work_ / "big_rig.json", Json{{"rig", rig}});
  const CliRun r = Cli("simulate --object plane --rig " + Q(*work_ / "big_rig.json") + " --out " +
                           Q(*work_ / "S_big"),
                       "MESOSCAN_MEMORY_BUDGET_MB=2000");
  ExpectRefused(r, 3, "memory budget", "8000x8000 camera");
  EXPECT_LT(r.seconds, 20.0);
  EXPECT_FALSE(fs::exists(*work_ / "S_big"));
  fs::remove(*work_ / "big_rig.json");
}

// Temporaries of killed runs that nothing removed: a nested staging folder, and a backup left
// between the two renames of a replacement without RENAME_EXCHANGE (the old output is under
// its backup name): the next command on that path restores or removes them.
TEST_F(BadValues, TemporariesOfKilledRunsAreRecovered) {
  // A process id that is gone.
  const pid_t child = fork();
  if (child == 0) _exit(0);
  int status = 0;
  waitpid(child, &status, 0);
  const std::string dead = std::to_string(child);
  // Nested staging folders of a killed `maps` / `simulate`.
  const fs::path m = *work_ / "M";
  const fs::path nested = *work_ / ("..M.mesoscan-tmp." + dead + ".0.mesoscan-tmp." + dead + ".1");
  fs::create_directories(nested / "deep");
  std::ofstream(nested / "deep" / "half.png") << "x";
  ASSERT_EQ(Cli("maps " + Q(*scan_) + " --out " + Q(m)).code, 0);
  EXPECT_FALSE(fs::exists(nested)) << "a nested temporary was left";
  // An interrupted replacement: the scan lies under its backup name only.
  const fs::path sc = CopyOf(*scan_, "SC_moved");
  const fs::path backup = *work_ / (".SC_moved.mesoscan-old." + dead + ".0");
  fs::rename(sc, backup);
  const CliRun c = Cli("check " + Q(sc));
  EXPECT_EQ(c.code, 0) << c.err;
  EXPECT_TRUE(fs::exists(sc / "height.exr"));
  EXPECT_FALSE(fs::exists(backup));
  fs::remove_all(sc);
  fs::remove_all(m);
  // A killed `simulate` and `maps` leave no nested temporary behind their next run.
  for (const std::string& cmd :
       {"simulate --object coin --crop 160x120+1000+700 --out " + Q(*work_ / "S_kill"),
        "maps " + Q(*scan_) + " --out " + Q(*work_ / "M_kill")}) {
    for (const int ms : {300, 700, 1200}) {
      const pid_t pid = fork();
      if (pid == 0) {
        const std::string sh = "exec " + MesoscanExe() + " -q " + cmd + " >/dev/null 2>&1";
        execl("/bin/sh", "sh", "-c", sh.c_str(), static_cast<char*>(nullptr));
        _exit(127);
      }
      usleep(ms * 1000);
      kill(pid, SIGKILL);
      waitpid(pid, &status, 0);
    }
    ASSERT_EQ(Cli(cmd).code, 0) << cmd;
  }
  EXPECT_TRUE(TemporariesIn(*work_).empty()) << TemporariesIn(*work_).front();
  fs::remove_all(*work_ / "S_kill");
  fs::remove_all(*work_ / "M_kill");
}

// `check` refuses what the commands it precedes refuse: rigs reconstruct cannot use, sessions
// with no point to reconstruct, scans export cannot export.
TEST_F(BadValues, CheckIsAsStrictAsTheCommands) {
  const auto rig_case = [&](const std::string& what, const std::function<void(Json&)>& edit,
                            const std::string& needle) {
    const fs::path s = CopyOf(*session_, "S_rig");
    Json j = ReadJsonFile(s / "session.json");
    edit(j["rig"]);
    WriteJsonFile(s / "session.json", j);
    ExpectRefused(Cli("check --quick " + Q(s)), 3, needle, what + " (check --quick)");
    ExpectRefused(Cli("check " + Q(s)), 3, needle, what + " (check)");
    ExpectRefused(Cli("reconstruct " + Q(s) + " --out " + Q(*work_ / "SC_rig")), 3, needle,
                  what + " (reconstruct)");
    fs::remove_all(s);
  };
  rig_case(
      "K skew 1e6", [](Json& r) { r["camera"]["K"][0][1] = 1e6; }, "rig.camera.K");
  rig_case(
      "k1 1e300", [](Json& r) { r["projector"]["distortion"][0] = 1e300; },
      "rig.projector.distortion");
  rig_case(
      "gamma 1e6",
      [](Json& r) {
        r["projector"]["response"] = {{"gamma", 1e6}};
      },
      "rig.projector.response");
  rig_case(
      "camera below the mount", [](Json& r) { r["camera"]["world_from_device"][2][3] = -0.2; },
      "rig.camera.world_from_device");
  rig_case(
      "projector below the mount",
      [](Json& r) { r["projector"]["world_from_device"][2][3] = -0.2; },
      "rig.projector.world_from_device");
  rig_case(
      "projector at the camera",
      [](Json& r) { r["projector"]["world_from_device"] = r["camera"]["world_from_device"]; },
      "rig.projector.world_from_device");
  // A dark session (every frame black): reconstruct finds no point, and so does check.
  {
    const fs::path s = CopyOf(*session_, "S_dark");
    const Json session_json = ReadJsonFile(s / "session.json");
    for (const Json& f : session_json["frames"]) {
      ImageF im = ReadImage(s / f["file"].get<std::string>());
      for (float& v : im.data()) v *= 0.002f;
      ImageU16 out(im.width(), im.height(), 1);
      for (size_t i = 0; i < im.pixels(); ++i)
        out.data()[i] = static_cast<uint16_t>(std::lround(im.data()[i] * 65535));
      WritePng16(s / f["file"].get<std::string>(), out);
    }
    const CliRun r = Cli("reconstruct " + Q(s) + " --out " + Q(*work_ / "SC_dark"));
    ExpectRefused(r, 3, "session.json", "dark (reconstruct)");
    ExpectRefused(Cli("check " + Q(s)), 3, "session.json", "dark (check)");
    fs::remove_all(s);
  }
  // Scans export refuses: one sample, a 1-px strip, 99% holes.
  const HeightField base = ReadHeightExr(*scan_ / "height.exr");
  const auto scan_case = [&](const std::string& what, const std::function<void(HeightField&)>& e) {
    const fs::path bad = CopyOf(*scan_, "SC_holes");
    HeightField h = base;
    e(h);
    WriteHeightExr(bad / "height.exr", h);
    const CliRun ex = Cli("export " + Q(bad) + " --out " + Q(*work_ / "E_holes"));
    EXPECT_EQ(ex.code, 3) << what << ": " << ex.err;
    ExpectRefused(Cli("check " + Q(bad)), 3, "height.exr", what + " (check)");
    fs::remove_all(bad);
    fs::remove_all(*work_ / "E_holes");
  };
  scan_case("one sample", [](HeightField& h) {
    for (float& z : h.z.data()) z = std::numeric_limits<float>::quiet_NaN();
    h.z(h.width() / 2, h.height() / 2) = 0.001f;
  });
  scan_case("99% holes", [](HeightField& h) {
    size_t k = 0;
    for (float& z : h.z.data())
      if (k++ % 100 != 0) z = std::numeric_limits<float>::quiet_NaN();
  });
}

// Messages and exit codes: the memory budget variable, option values.
TEST_F(BadValues, MessagesAndExitCodes) {
  for (const char* v : {"1e20", "abc", "-5", "0"}) {
    const CliRun r =
        Cli("check --quick " + Q(*session_), std::string("MESOSCAN_MEMORY_BUDGET_MB=") + v);
    if (std::string(v) == "1e20") {
      EXPECT_EQ(r.code, 0) << v << ": " << r.err;
    } else {
      ExpectRefused(r, 2, "MESOSCAN_MEMORY_BUDGET_MB", v);
    }
  }
  for (const char* opt : {"--tile nan", "--fill-max-radius-mm nan", "--ao-radius-mm nan"})
    ExpectRefused(Cli("maps " + Q(*scan_) + " --out " + Q(*work_ / "M11") + " " + opt), 2,
                  std::string(opt).substr(0, std::string(opt).find(' ')), opt);
  EXPECT_FALSE(fs::exists(*work_ / "M11"));
  const std::string render =
      "render " + Q(*scan_) + " --out " + Q(*work_ / "R11") + " --size 32x24 --spp 1 --min-spp 1";
  ExpectRefused(Cli(render + " --env-scale -1"), 2, "--env-scale");
  const CliRun t = Cli(render + " --threads -1");
  EXPECT_EQ(t.code, 2) << t.err;
  EXPECT_LT(t.err.size(), 200u) << t.err;
  // A NaN or negative environment map is named.
  ImageF env(8, 4, 3, 1.0f);
  env(2, 1, 0) = std::numeric_limits<float>::quiet_NaN();
  WriteExr(*work_ / "nan_env.exr", env, {"R", "G", "B"});
  ExpectRefused(Cli(render + " --env " + Q(*work_ / "nan_env.exr")), 3, "nan_env.exr");
  env(2, 1, 0) = -1.0f;
  WriteExr(*work_ / "neg_env.exr", env, {"R", "G", "B"});
  ExpectRefused(Cli(render + " --env " + Q(*work_ / "neg_env.exr")), 3, "neg_env.exr");
  EXPECT_FALSE(fs::exists(*work_ / "R11"));
  // Periods that cannot unwrap: refused before simulating, naming the option.
  const CliRun p = Cli("simulate --object coin --crop 160x120+1000+700 --ps-periods 13 --out " +
                       Q(*work_ / "S13"));
  ExpectRefused(p, 2, "--ps-periods");
  EXPECT_EQ(p.err.find(".mesoscan-tmp"), std::string::npos) << p.err;
  EXPECT_LT(p.seconds, 5.0);
  EXPECT_FALSE(fs::exists(*work_ / "S13"));
  // A 1x1 ROI: the message counts the pixels tried (1), not the camera's.
  const CliRun roi =
      Cli("reconstruct " + Q(*session_) + " --out " + Q(*work_ / "SC11") + " --roi 0,0,1,1");
  EXPECT_NE(roi.code, 0);
  EXPECT_EQ(roi.err.find("160x120"), std::string::npos) << roi.err;
  EXPECT_FALSE(fs::exists(*work_ / "SC11"));
}

}  // namespace
}  // namespace mesoscan
