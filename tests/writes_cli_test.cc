// Outputs through the real `mesoscan` binary: no command overwrites its inputs or an unrelated
// file without --force (calibrate included), every write is checked (a write that fails as on a
// full disk is an error naming the file, exit 3, and leaves no partial output), and temporaries
// of interrupted runs are cleaned up. A full disk is played by RLIMIT_FSIZE with SIGXFSZ ignored
// (`ulimit -f N; trap '' XFSZ`): every write past N KB of one file fails with EFBIG.

#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>

#include "core/fs.h"
#include "core/json.h"
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

// Writes past `kb` KB of any one file fail with EFBIG.
std::string FullDisk(int kb) { return "ulimit -f " + std::to_string(kb) + "; trap '' XFSZ;"; }

class Writes : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    work_ = new fs::path(CliTempDir("writes", "work"));
    fs::create_directories(*work_);
    session_ = new fs::path(*work_ / "in" / "S");
    scan_ = new fs::path(*work_ / "in" / "SC");
    CliRun r =
        RunCli("simulate --object coin --crop 160x120+1000+700 --out " + Q(*session_), *work_);
    ASSERT_EQ(r.code, 0) << r.err;
    r = RunCli("reconstruct " + Q(*session_) + " --out " + Q(*scan_), *work_);
    ASSERT_EQ(r.code, 0) << r.err;
    r = RunCli("brdf tabulate --alpha 0.3 --out " + Q(*work_ / "in" / "t.binary"), *work_);
    ASSERT_EQ(r.code, 0) << r.err;
  }
  static void TearDownTestSuite() {
    fs::remove_all(*work_);
    delete work_;
    delete session_;
    delete scan_;
  }
  void SetUp() override { inputs_before_ = FileSnapshot(*work_ / "in"); }
  void TearDown() override {
    EXPECT_EQ(FileSnapshot(*work_ / "in"), inputs_before_) << "an input changed";
    EXPECT_TRUE(TemporariesIn(*work_).empty()) << TemporariesIn(*work_).front();
  }
  static CliRun Cli(const std::string& args, const std::string& prefix = "") {
    return RunCli(args, *work_, prefix);
  }
  // A refusal: the exit code, one line on stderr containing `needle`.
  static void ExpectRefused(const CliRun& r, int code, const std::string& needle) {
    EXPECT_EQ(r.code, code) << r.err;
    EXPECT_EQ(r.ErrLines(), 1) << r.err;
    EXPECT_NE(r.err.find(needle), std::string::npos) << "expected '" << needle << "' in " << r.err;
  }
  // A failed write: exit 3, one line naming the file being written and the system's reason.
  static void ExpectWriteFailed(const CliRun& r, const std::string& what) {
    EXPECT_EQ(r.code, 3) << what << ": " << r.err;
    EXPECT_EQ(r.ErrLines(), 1) << what << ": " << r.err;
    EXPECT_NE(r.err.find("cannot write"), std::string::npos) << what << ": " << r.err;
    EXPECT_NE(r.err.find("File too large"), std::string::npos) << what << ": " << r.err;
  }

  static fs::path* work_;
  static fs::path* session_;
  static fs::path* scan_;
  std::map<std::string, std::pair<uintmax_t, int64_t>> inputs_before_;
};
fs::path* Writes::work_ = nullptr;
fs::path* Writes::session_ = nullptr;
fs::path* Writes::scan_ = nullptr;

// calibrate's --out and --report go through the same checks as every other command's --out,
// before any work: not an input, not inside one, not an unrelated file or folder without
// --force, not inside each other. (The sessions here hold no board: a calibrate that got past
// the checks would fail later with exit 3, or, on a real board, write over the input.)
TEST_F(Writes, CalibrateRefusesItsInputsAndForeignFiles) {
  const fs::path s = *session_;
  const std::string sessions = Q(s) + " " + Q(s) + " " + Q(s) + " --board checker:5x4:10";
  ExpectRefused(Cli("calibrate " + sessions + " --out " + Q(s / "session.json")), 2,
                "lies inside the input");
  ExpectRefused(Cli("calibrate " + sessions + " --out " + Q(s / "frames" / "ps07_0.png")), 2,
                "lies inside the input");
  ExpectRefused(Cli("calibrate " + sessions + " --out " + Q(s)), 2, "is the input");
  ExpectRefused(
      Cli("calibrate " + sessions + " --out " + Q(*work_ / "r.json") + " --report " + Q(s)), 2,
      "is the input");
  ExpectRefused(Cli("calibrate " + sessions + " --out " + Q(*work_ / "r.json") + " --report " +
                    Q(*work_ / "in")),
                2, "contains the input");
  // An unrelated file or folder is not replaced without --force.
  std::ofstream(*work_ / "notes.json") << "{\"precious\": true}\n";
  ExpectRefused(Cli("calibrate " + sessions + " --out " + Q(*work_ / "notes.json")), 2, "--force");
  fs::create_directories(*work_ / "thesis");
  std::ofstream(*work_ / "thesis" / "chapter1.tex") << "years of work";
  ExpectRefused(Cli("calibrate " + sessions + " --out " + Q(*work_ / "r.json") + " --report " +
                    Q(*work_ / "thesis")),
                2, "--force");
  // --out inside --report (the report's swap would delete it).
  ExpectRefused(Cli("calibrate " + sessions + " --out " + Q(*work_ / "rep" / "rig.json") +
                    " --report " + Q(*work_ / "rep")),
                2, "--report");
  EXPECT_EQ(ReadTextFile(*work_ / "notes.json"), "{\"precious\": true}\n");
  EXPECT_EQ(ReadTextFile(*work_ / "thesis" / "chapter1.tex"), "years of work");
  EXPECT_FALSE(fs::exists(*work_ / "r.json"));
  EXPECT_FALSE(fs::exists(*work_ / "rep"));
  // An earlier rig file is replaced without --force (checked up to the board search: exit 3).
  std::ofstream(*work_ / "old_rig.json") << Json{{"rig", Json::object()}}.dump();
  const CliRun again = Cli("calibrate " + sessions + " --out " + Q(*work_ / "old_rig.json"));
  EXPECT_EQ(again.code, 3) << again.err;
  EXPECT_EQ(again.err.find("--force"), std::string::npos) << again.err;
  fs::remove_all(*work_ / "thesis");
  fs::remove(*work_ / "notes.json");
  fs::remove(*work_ / "old_rig.json");
}

// Writes that fail (as on a full disk) are errors naming the file, and leave nothing behind:
// brdf plot's PNG, brdf tabulate's table, export's files, reconstruct's scan, maps, simulate.
TEST_F(Writes, FailedWritesAreErrorsAndLeaveNoPartialOutput) {
  const fs::path table = *work_ / "in" / "t.binary";
  const fs::path plot = *work_ / "plot.png";
  ExpectWriteFailed(Cli("brdf plot " + Q(table) + " --out " + Q(plot), FullDisk(80)), "brdf plot");
  EXPECT_NE(Cli("brdf plot " + Q(table) + " --out " + Q(plot), FullDisk(80)).err.find("plot.png"),
            std::string::npos);
  EXPECT_FALSE(fs::exists(plot));
  ExpectWriteFailed(
      Cli("brdf tabulate --alpha 0.3 --out " + Q(*work_ / "t2.binary"), FullDisk(1000)),
      "brdf tabulate");
  EXPECT_FALSE(fs::exists(*work_ / "t2.binary"));
  // Each file size limit stops a different file of the export.
  for (const int kb : {1, 16, 64, 200, 400}) {
    const CliRun r = Cli("export " + Q(*scan_) + " --out " + Q(*work_ / "E"), FullDisk(kb));
    ExpectWriteFailed(r, "export, " + std::to_string(kb) + " KB");
    EXPECT_FALSE(fs::exists(*work_ / "E")) << kb << " KB";
  }
  ExpectWriteFailed(
      Cli("reconstruct " + Q(*session_) + " --out " + Q(*work_ / "SC2"), FullDisk(64)),
      "reconstruct");
  EXPECT_FALSE(fs::exists(*work_ / "SC2"));
  ExpectWriteFailed(Cli("maps " + Q(*scan_) + " --out " + Q(*work_ / "M"), FullDisk(16)), "maps");
  EXPECT_FALSE(fs::exists(*work_ / "M"));
  ExpectWriteFailed(
      Cli("simulate --object coin --crop 160x120+1000+700 --ls-frames 8 --out " + Q(*work_ / "S2"),
          FullDisk(20)),
      "simulate");
  EXPECT_FALSE(fs::exists(*work_ / "S2"));
}

}  // namespace
}  // namespace mesoscan
