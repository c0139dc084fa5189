// Every hostile or careless case through the real `mesoscan` binary: the exit code,
// one line on stderr naming what is wrong, inputs untouched, no partial output, and bounded
// time (each run is wrapped in `timeout`, so a hang fails as exit 124) and memory (`ulimit -v`).
// The session: `simulate --object coin --crop 160x120+1000+700`, reconstructed.

#include <gtest/gtest.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <sstream>
#include <thread>
#include <vector>

#include "core/fs.h"
#include "core/image_io.h"
#include "core/json.h"
#include "core/output_dir.h"
#include "core/scan_folder.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

struct Result {
  int code = -1;         // exit code; -1: killed by a signal (an abort is a failure here)
  std::string out, err;  // stdout, stderr
  double seconds = 0;
  int ErrLines() const {
    int n = 0;
    for (char c : err) n += c == '\n';
    return n;
  }
};

fs::path Work() {
  static const fs::path w =
      fs::temp_directory_path() / ("mesoscan_hostile_" + std::to_string(getpid()));
  return w;
}

// The binary under test: MESOSCAN_TEST_EXE overrides the one built here (to run these cases
// against an older build and see them fail).
std::string Exe() {
  const char* e = std::getenv("MESOSCAN_TEST_EXE");
  return e && *e ? e : MESOSCAN_EXE;
}

// `mesoscan <args>` with a 60 s timeout (a hang is killed: exit -1) and a 6 GB address space.
Result Cli(const std::string& args, const std::string& env = "") {
  const fs::path out = Work() / "stdout.txt", err = Work() / "stderr.txt";
  const std::string cmd = "ulimit -v 6000000; " + env + " timeout -s KILL 60 " + Exe() + " -q " +
                          args + " >" + out.string() + " 2>" + err.string();
  const auto t0 = std::chrono::steady_clock::now();
  const int status = std::system(cmd.c_str());
  Result r;
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = ReadTextFile(out);
  r.err = ReadTextFile(err);
  return r;
}

// Every file below `dir` with its size and modification time: "untouched" means equal maps.
std::map<std::string, std::pair<uintmax_t, int64_t>> Snapshot(const fs::path& dir) {
  std::map<std::string, std::pair<uintmax_t, int64_t>> m;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    if (!e.is_regular_file()) continue;
    m[fs::relative(e.path(), dir).string()] = {e.file_size(),
                                               e.last_write_time().time_since_epoch().count()};
  }
  return m;
}

std::string Q(const fs::path& p) {
  std::string q = "'";
  q.append(p.string()).append("'");
  return q;
}

class Hostile : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    fs::remove_all(Work());
    fs::create_directories(Work() / "base");
    session_ = new fs::path(Work() / "base" / "S");
    scan_ = new fs::path(Work() / "SC");
    Result r = Cli("simulate --object coin --crop 160x120+1000+700 --out " + Q(*session_));
    ASSERT_EQ(r.code, 0) << r.err;
    r = Cli("reconstruct " + Q(*session_) + " --out " + Q(*scan_));
    ASSERT_EQ(r.code, 0) << r.err;
    std::ofstream(Work() / "base" / "sibling.txt") << "keep me";
  }
  static void TearDownTestSuite() {
    fs::remove_all(Work());
    delete session_;
    delete scan_;
  }
  void SetUp() override {
    ASSERT_TRUE(fs::exists(*session_ / "session.json"));
    session_before_ = Snapshot(Work() / "base");
    scan_before_ = Snapshot(*scan_);
  }
  void TearDown() override {
    // Inputs are never touched, whatever the case did.
    EXPECT_EQ(Snapshot(Work() / "base"), session_before_) << "the session folder changed";
    EXPECT_EQ(Snapshot(*scan_), scan_before_) << "the scan folder changed";
  }

  // A copy of the session to mutate.
  static fs::path CopySession(const std::string& name) {
    const fs::path d = Work() / name;
    fs::remove_all(d);
    fs::copy(*session_, d, fs::copy_options::recursive);
    return d;
  }
  static fs::path CopyScan(const std::string& name) {
    const fs::path d = Work() / name;
    fs::remove_all(d);
    fs::copy(*scan_, d, fs::copy_options::recursive);
    return d;
  }
  static std::string FirstFrame(const fs::path& session) {
    return ReadJsonFile(session / "session.json").at("frames").at(0).at("file").get<std::string>();
  }
  // Expects a refusal: exit code, exactly one line on stderr containing `needle`.
  static void ExpectRefused(const Result& r, int code, const std::string& needle) {
    EXPECT_EQ(r.code, code) << r.err;
    EXPECT_EQ(r.ErrLines(), 1) << r.err;
    EXPECT_NE(r.err.find(needle), std::string::npos) << "expected '" << needle << "' in: " << r.err;
    EXPECT_LT(r.seconds, 30.0);
  }

  static fs::path* session_;
  static fs::path* scan_;
  std::map<std::string, std::pair<uintmax_t, int64_t>> session_before_, scan_before_;
};
fs::path* Hostile::session_ = nullptr;
fs::path* Hostile::scan_ = nullptr;

// ---- 1. Data loss -------------------------------------------------------------------------

TEST_F(Hostile, Item1_ReconstructOutIsTheSession) {
  ExpectRefused(Cli("reconstruct " + Q(*session_) + " --out " + Q(*session_)), 2, "is the input");
  // Spelled differently: trailing slash, `..`, a symlink to it.
  ExpectRefused(Cli("reconstruct " + Q(*session_) + " --out " + Q(*session_ / "frames" / "..")), 2,
                "is the input");
  fs::create_symlink(*session_, Work() / "link_to_S");
  ExpectRefused(Cli("reconstruct " + Q(*session_) + " --out " + Q(Work() / "link_to_S")), 2,
                "is the input");
  fs::remove(Work() / "link_to_S");
}

TEST_F(Hostile, Item1_ReconstructOutContainsOrLiesInsideTheSession) {
  ExpectRefused(Cli("reconstruct " + Q(*session_) + " --out " + Q(Work() / "base")), 2,
                "contains the input");
  ExpectRefused(Cli("reconstruct " + Q(*session_) + " --out " + Q(*session_ / "frames")), 2,
                "lies inside the input");
  ExpectRefused(Cli("reconstruct " + Q(*session_) + " --out " + Q(*session_ / "new" / "scan")), 2,
                "lies inside the input");
  EXPECT_FALSE(fs::exists(*session_ / "new"));
}

TEST_F(Hostile, Item1_ExportRenderAndSimulateRefuseTheirInputs) {
  ExpectRefused(Cli("export " + Q(*scan_) + " --out " + Q(*scan_)), 2, "is the input");
  ExpectRefused(Cli("export " + Q(*scan_) + " --out " + Q(*session_)), 2, "is the input");
  ExpectRefused(Cli("export " + Q(*scan_) + " --out " + Q(Work())), 2, "contains the input");
  ExpectRefused(
      Cli("render " + Q(*scan_) + " --out " + Q(*scan_) + " --size 32x24 --spp 1 --min-spp 1"), 2,
      "is the input");
  ExpectRefused(Cli("render " + Q(*scan_) + " --out " + Q(*scan_ / "r") +
                    " --size 32x24 --spp 1 --min-spp 1"),
                2, "lies inside the input");
  EXPECT_FALSE(fs::exists(*scan_ / "r"));
  // simulate --object FILE.exr --out (a folder around it)
  ExpectRefused(Cli("simulate --object " + Q(*scan_ / "height.exr") + " --out " + Q(*scan_)), 2,
                "contains the input");
}

TEST_F(Hostile, Item1_BrdfOutputsRefuseTheirInputAndForeignFiles) {
  const fs::path tab = Work() / "t.binary";
  ASSERT_EQ(Cli("brdf tabulate --alpha 0.3 --out " + Q(tab)).code, 0);
  const auto size = fs::file_size(tab);
  ExpectRefused(Cli("brdf plot " + Q(tab) + " --out " + Q(tab)), 2, "is the input");
  EXPECT_EQ(fs::file_size(tab), size);
  // A file that is not an earlier output is not overwritten without --force.
  std::ofstream(Work() / "notes.txt") << "precious";
  ExpectRefused(Cli("brdf tabulate --alpha 0.3 --out " + Q(Work() / "notes.txt")), 2, "--force");
  ExpectRefused(Cli("brdf plot " + Q(tab) + " --out " + Q(Work() / "notes.txt")), 2, "--force");
  EXPECT_EQ(ReadTextFile(Work() / "notes.txt"), "precious");
  // Re-running onto its own earlier output is fine.
  EXPECT_EQ(Cli("brdf tabulate --alpha 0.3 --out " + Q(tab)).code, 0);
  fs::remove(tab);
  fs::remove(Work() / "notes.txt");
}

TEST_F(Hostile, Item1_ExistingForeignFolderNeedsForce) {
  const fs::path foreign = Work() / "foreign";
  fs::create_directories(foreign);
  std::ofstream(foreign / "thesis.tex") << "years of work";
  for (const std::string& cmd : {"reconstruct " + Q(*session_), "export " + Q(*scan_),
                                 "render " + Q(*scan_) + " --size 32x24 --spp 1 --min-spp 1",
                                 std::string("simulate --object plane --crop 32x24+1000+700")})
    ExpectRefused(Cli(cmd + " --out " + Q(foreign)), 2, "--force");
  EXPECT_EQ(ReadTextFile(foreign / "thesis.tex"), "years of work");
  // --force replaces it; a second run replaces its own output without --force.
  ASSERT_EQ(Cli("export " + Q(*scan_) + " --out " + Q(foreign) + " --force").code, 0);
  EXPECT_FALSE(fs::exists(foreign / "thesis.tex"));
  ASSERT_EQ(Cli("export " + Q(*scan_) + " --out " + Q(foreign) + " --format exr").code, 0);
  EXPECT_TRUE(fs::exists(foreign / "manifest.json"));
  fs::remove_all(foreign);
}

TEST_F(Hostile, Item1_RerunsOfEveryCommandReplaceTheirOwnOutput) {
  const fs::path e = Work() / "rerun_E", r = Work() / "rerun_R", sc = Work() / "rerun_SC";
  for (int i = 0; i < 2; ++i) {
    EXPECT_EQ(Cli("export " + Q(*scan_) + " --out " + Q(e) + " --format exr").code, 0);
    EXPECT_EQ(
        Cli("render " + Q(*scan_) + " --out " + Q(r) + " --size 32x24 --spp 1 --min-spp 1").code,
        0);
    EXPECT_EQ(Cli("reconstruct " + Q(*session_) + " --out " + Q(sc) + " --roi 0,0,40,30").code, 0);
  }
  // No temporaries or backups are left next to them.
  for (const auto& f : fs::directory_iterator(Work()))
    EXPECT_EQ(f.path().filename().string().find(".mesoscan-"), std::string::npos) << f.path();
  fs::remove_all(e);
  fs::remove_all(r);
  fs::remove_all(sc);
}

// ---- 2. Aborts ----------------------------------------------------------------------------

TEST_F(Hostile, Item2_RenderRefusesNumbersEmbreeWouldAbortOn) {
  const std::string base =
      "render " + Q(*scan_) + " --out " + Q(Work() / "R") + " --size 64x48 --spp 4 --min-spp 1";
  ExpectRefused(Cli(base + " --relief 1e30"), 2, "--relief");
  ExpectRefused(Cli(base + " --azimuth nan"), 2, "--azimuth");
  ExpectRefused(Cli(base + " --elevation inf"), 2, "--elevation");
  EXPECT_FALSE(fs::exists(Work() / "R")) << "a failed render leaves no --out";
}

TEST_F(Hostile, Item2_RenderRefusesHostileHeightFields) {
  const fs::path bad = CopyScan("SC_bad");
  HeightField hf = ReadHeightExr(*scan_ / "height.exr");
  const std::string base =
      "render " + Q(bad) + " --out " + Q(Work() / "R") + " --size 32x24 --spp 1 --min-spp 1";
  HeightField h = hf;
  h.z(3, 3) = 1e30f;
  WriteHeightExr(bad / "height.exr", h);
  ExpectRefused(Cli(base), 3, "height.exr");
  h = hf;
  h.x0 = std::numeric_limits<double>::quiet_NaN();
  WriteHeightExr(bad / "height.exr", h);
  ExpectRefused(Cli(base), 3, "mesoscan:x0");
  HeightField one;
  one.z = ImageF(1, 1, 1, 0.001f);
  one.confidence = ImageF(1, 1, 1, 1.0f);
  WriteHeightExr(bad / "height.exr", one);
  ExpectRefused(Cli(base), 3, "1x1");
  EXPECT_FALSE(fs::exists(Work() / "R"));
  fs::remove_all(bad);
}

// ---- 3. Hangs -----------------------------------------------------------------------------

TEST_F(Hostile, Item3_FifoDeviceAndHugeFramesDoNotHang) {
  const fs::path s = CopySession("S_hang");
  const std::string frame = FirstFrame(s);
  fs::remove(s / frame);
  ASSERT_EQ(mkfifo((s / frame).c_str(), 0600), 0);
  ExpectRefused(Cli("check " + Q(s)), 3, "FIFO");
  ExpectRefused(Cli("reconstruct " + Q(s) + " --out " + Q(Work() / "SC_hang")), 3, "FIFO");
  fs::remove(s / frame);
  fs::create_symlink("/dev/zero", s / frame);
  // (refused as leaving the session folder; core_test checks the device refusal itself)
  ExpectRefused(Cli("check " + Q(s)), 3, "/dev/zero");
  ExpectRefused(Cli("reconstruct " + Q(s) + " --out " + Q(Work() / "SC_hang")), 3, "/dev/zero");
  fs::remove(s / frame);
  // A 2 GB zero-filled frame (sparse): refused by the PNG reader at once, no DICOM fallback.
  { std::ofstream(s / frame); }
  fs::resize_file(s / frame, uintmax_t{2} << 30);
  const Result r = Cli("reconstruct " + Q(s) + " --out " + Q(Work() / "SC_hang"));
  ExpectRefused(r, 3, frame);
  EXPECT_LT(r.seconds, 10.0);
  EXPECT_FALSE(fs::exists(Work() / "SC_hang"));
  fs::remove_all(s);
}

// ---- 4. Budgets before allocation ---------------------------------------------------------

TEST_F(Hostile, Item4_SizesAreCheckedAgainstTheBudgetBeforeAllocation) {
  Result r = Cli("export " + Q(*scan_) + " --out " + Q(Work() / "E4") + " --pixel-size 1e-7");
  ExpectRefused(r, 2, "memory budget");
  r = Cli("reconstruct " + Q(*session_) + " --out " + Q(Work() / "SC4") + " --pixel-size-um 0.001");
  ExpectRefused(r, 3, "memory budget");
  r = Cli("render " + Q(*scan_) + " --out " + Q(Work() / "R4") + " --size 100000x100000");
  ExpectRefused(r, 2, "memory budget");
  const fs::path tab = Work() / "t4.binary";
  ASSERT_EQ(Cli("brdf tabulate --alpha 0.3 --out " + Q(tab)).code, 0);
  ExpectRefused(Cli("brdf plot " + Q(tab) + " --out " + Q(Work() / "p.png") + " --panel 100000"), 3,
                "panel_px");
  for (const char* d : {"E4", "SC4", "R4", "p.png"}) EXPECT_FALSE(fs::exists(Work() / d)) << d;
  fs::remove(tab);
}

TEST_F(Hostile, Item4_AllNanAndOversizedHeightFields) {
  const fs::path bad = CopyScan("SC_nan");
  HeightField h = ReadHeightExr(*scan_ / "height.exr");
  for (float& z : h.z.data()) z = std::numeric_limits<float>::quiet_NaN();
  WriteHeightExr(bad / "height.exr", h);
  ExpectRefused(Cli("export " + Q(bad) + " --out " + Q(Work() / "E_nan")), 3, "no valid");
  EXPECT_FALSE(fs::exists(Work() / "E_nan"));
  // A 1200x1200 all-NaN height.exr against an 8 MB budget (12000x12000 against the
  // default budget, scaled down): refused from the header before it is decoded.
  HeightField big;
  big.z = ImageF(1200, 1200, 1, std::numeric_limits<float>::quiet_NaN());
  big.confidence = ImageF(1200, 1200, 1, 0.0f);
  WriteHeightExr(bad / "height.exr", big);
  const Result r =
      Cli("export " + Q(bad) + " --out " + Q(Work() / "E_nan"), "MESOSCAN_MEMORY_BUDGET_MB=8");
  ExpectRefused(r, 3, "memory budget");
  EXPECT_FALSE(fs::exists(Work() / "E_nan"));
  fs::remove_all(bad);
}

// ---- 5. Partial outputs -------------------------------------------------------------------

// Starts `mesoscan args` and SIGKILLs (or SIGINTs) it after `ms` milliseconds.
void RunAndKill(const std::string& args, int ms, int sig) {
  const pid_t pid = fork();
  if (pid == 0) {
    const std::string cmd = "exec " + Exe() + " -q " + args + " >/dev/null 2>&1";
    execl("/bin/sh", "sh", "-c", cmd.c_str(), static_cast<char*>(nullptr));
    _exit(127);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(ms));
  kill(pid, sig);
  int status = 0;
  waitpid(pid, &status, 0);
}

// Hidden files below `dir` other than the output marker: temporaries of interrupted writes.
std::vector<std::string> HiddenLeftovers(const fs::path& dir) {
  std::vector<std::string> found;
  if (!fs::exists(dir)) return found;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (name[0] == '.' && name != kOutputMarker) found.push_back(e.path().string());
  }
  return found;
}

TEST_F(Hostile, Item5_KilledExportLeavesNothingOrAWholeExport) {
  // A 3x finer grid than the scan's makes the export take long enough to be killed mid-way.
  const double px = ReadHeightExr(*scan_ / "height.exr").pixel_size / 3;
  std::ostringstream args;
  args.precision(9);
  args << "export " << Q(*scan_) << " --out " << Q(Work() / "E5") << " --pixel-size " << px;
  const Result full = Cli(args.str());
  ASSERT_EQ(full.code, 0) << full.err;
  const auto complete = Snapshot(Work() / "E5").size();
  fs::remove_all(Work() / "E5");
  int killed_mid_way = 0;
  for (int trial = 0; trial < 10; ++trial) {
    const int ms = static_cast<int>(full.seconds * 1000 * (trial + 0.5) / 10);
    RunAndKill(args.str(), ms, trial % 2 ? SIGINT : SIGKILL);
    if (!fs::exists(Work() / "E5")) {
      ++killed_mid_way;
      continue;
    }
    EXPECT_TRUE(fs::exists(Work() / "E5" / "manifest.json")) << "trial " << trial;
    EXPECT_EQ(Snapshot(Work() / "E5").size(), complete) << "trial " << trial;
    EXPECT_TRUE(HiddenLeftovers(Work() / "E5").empty()) << "trial " << trial;
    fs::remove_all(Work() / "E5");
  }
  EXPECT_GT(killed_mid_way, 0) << "no trial was killed before the export finished";
  // A killed replacement of an existing export keeps the old one whole.
  ASSERT_EQ(Cli(args.str()).code, 0);
  RunAndKill(args.str(), static_cast<int>(full.seconds * 500), SIGKILL);
  EXPECT_TRUE(fs::exists(Work() / "E5" / "manifest.json"));
  EXPECT_EQ(Snapshot(Work() / "E5").size(), complete);
  // The next successful run removes what the killed runs left behind.
  ASSERT_EQ(Cli(args.str()).code, 0);
  for (const auto& f : fs::directory_iterator(Work()))
    EXPECT_EQ(f.path().filename().string().find(".E5"), std::string::npos) << f.path();
  EXPECT_TRUE(HiddenLeftovers(Work() / "E5").empty());
  fs::remove_all(Work() / "E5");
}

TEST_F(Hostile, Item5_FailedRunsLeaveNoOutputFolder) {
  ExpectRefused(Cli("render " + Q(*scan_) + " --out " + Q(Work() / "R5") +
                    " --size 32x24 --spp 1 --min-spp 1 --brdf /nonexistent.binary"),
                3, "nonexistent");
  EXPECT_FALSE(fs::exists(Work() / "R5"));
  const fs::path bad = CopyScan("SC_nan5");
  HeightField h = ReadHeightExr(*scan_ / "height.exr");
  for (float& z : h.z.data()) z = std::numeric_limits<float>::quiet_NaN();
  WriteHeightExr(bad / "height.exr", h);
  ExpectRefused(Cli("export " + Q(bad) + " --out " + Q(Work() / "E5b")), 3, "no valid");
  EXPECT_FALSE(fs::exists(Work() / "E5b"));
  fs::remove_all(bad);
}

// ---- 6. check is as strict as reconstruct (headers) ---------------------------------------

TEST_F(Hostile, Item6_UnsignedZeroProjectorSizeIsRefused) {
  const fs::path s = CopySession("S_zero");
  Json j = ReadJsonFile(s / "session.json");
  j["rig"]["projector"]["width"] = 0u;
  WriteJsonFile(s / "session.json", j);
  ExpectRefused(Cli("check " + Q(s)), 3, "rig.projector.width");
  fs::remove_all(s);
}

// A frame whose only damage is a chunk checksum (the first IDAT's stored CRC, its data intact):
// the frames' fast path checks every CRC and leaves the file to OpenImageIO, whose libpng
// refuses it; reconstruct exits 3 with one line naming the frame (a reader with its checks off
// would decode it).
TEST_F(Hostile, FrameWithAWrongChunkCrcIsRefused) {
  const fs::path s = CopySession("S_crc");
  const std::string frame = FirstFrame(s);
  std::string bytes;
  {
    std::ifstream in(s / frame, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  const size_t idat = bytes.find("IDAT");
  ASSERT_NE(idat, std::string::npos);
  ASSERT_GE(idat, 4u);
  const uint32_t len = (uint32_t{static_cast<uint8_t>(bytes[idat - 4])} << 24) |
                       (uint32_t{static_cast<uint8_t>(bytes[idat - 3])} << 16) |
                       (uint32_t{static_cast<uint8_t>(bytes[idat - 2])} << 8) |
                       static_cast<uint8_t>(bytes[idat - 1]);
  ASSERT_LE(idat + 4 + len + 4, bytes.size());
  bytes[idat + 4 + len + 3] ^= 0x01;  // the last byte of the IDAT's CRC
  std::ofstream(s / frame, std::ios::binary | std::ios::trunc) << bytes;
  ExpectRefused(Cli("reconstruct " + Q(s) + " --out " + Q(Work() / "SC_crc")), 3, frame);
  EXPECT_FALSE(fs::exists(Work() / "SC_crc"));
  fs::remove_all(s);
}

TEST_F(Hostile, Item6_CheckRefusesWhatReconstructWould) {
  const fs::path s = CopySession("S_check");
  const std::string frame = FirstFrame(s);
  // A truncated PNG: its header is fine (--quick passes), its body is not.
  fs::resize_file(s / frame, fs::file_size(s / frame) / 2);
  EXPECT_EQ(Cli("check --quick " + Q(s)).code, 0);
  ExpectRefused(Cli("check " + Q(s)), 3, frame);
  fs::remove_all(s);
  // Periods the unwrapping cannot resolve: refused by check as by reconstruct, naming the file.
  const fs::path p = CopySession("S_period");
  Json j = ReadJsonFile(p / "session.json");
  for (Json& f : j["frames"])
    if (f["pattern"].value("type", "") == "sine" && f["pattern"]["period_px"].get<double>() > 12)
      f["pattern"]["period_px"] = 1e9;
  WriteJsonFile(p / "session.json", j);
  const Result rc = Cli("check " + Q(p));
  EXPECT_EQ(rc.code, 3) << rc.err << rc.out;
  EXPECT_NE(rc.err.find("session.json"), std::string::npos) << rc.err;
  const Result rr = Cli("reconstruct " + Q(p) + " --out " + Q(Work() / "SC6"));
  EXPECT_EQ(rr.code, 3) << rr.err;
  EXPECT_NE(rr.err.find("session.json"), std::string::npos) << rr.err;
  fs::remove_all(p);
  // All frames identical: reconstruct refuses instead of writing an empty scan.
  const fs::path same = CopySession("S_same");
  const Json js = ReadJsonFile(same / "session.json");
  const std::string first = FirstFrame(same);
  for (const Json& f : js["frames"]) {
    const std::string file = f["file"];
    if (file != first)
      fs::copy_file(same / first, same / file, fs::copy_options::overwrite_existing);
  }
  ExpectRefused(Cli("reconstruct " + Q(same) + " --out " + Q(Work() / "SC6")), 3, "session.json");
  EXPECT_FALSE(fs::exists(Work() / "SC6"));
  fs::remove_all(same);
}

TEST_F(Hostile, Item6_CheckRefusesUnusableScans) {
  const fs::path bad = CopyScan("SC_check");
  HeightField one;
  one.z = ImageF(1, 1, 1, 0.001f);
  one.confidence = ImageF(1, 1, 1, 1.0f);
  WriteHeightExr(bad / "height.exr", one);
  ExpectRefused(Cli("check " + Q(bad)), 3, "1x1");
  HeightField h = ReadHeightExr(*scan_ / "height.exr");
  for (float& z : h.z.data()) z = std::numeric_limits<float>::quiet_NaN();
  WriteHeightExr(bad / "height.exr", h);
  ExpectRefused(Cli("check " + Q(bad)), 3, "no valid");
  fs::remove_all(bad);
}

// ---- 7. Containment -----------------------------------------------------------------------

TEST_F(Hostile, Item7_FrameSymlinkedOutsideTheSessionIsRefused) {
  const fs::path s = CopySession("S_link");
  const std::string frame = FirstFrame(s);
  fs::copy_file(s / frame, Work() / "outside.png");
  fs::remove(s / frame);
  fs::create_symlink(Work() / "outside.png", s / frame);
  ExpectRefused(Cli("check " + Q(s)), 3, "outside the session folder");
  ExpectRefused(Cli("reconstruct " + Q(s) + " --out " + Q(Work() / "SC7")), 3,
                "outside the session folder");
  // A link that stays inside is fine.
  fs::remove(s / frame);
  fs::rename(Work() / "outside.png", s / "frames" / "real.png");
  fs::create_symlink("real.png", s / frame);
  EXPECT_EQ(Cli("check " + Q(s)).code, 0);
  fs::remove_all(s);
}

// ---- 8. Exit codes and messages -----------------------------------------------------------

TEST_F(Hostile, Item8_ExitCodesMatchTheReadme) {
  const fs::path s = CopySession("S_loop");
  const std::string frame = FirstFrame(s);
  fs::remove(s / frame);
  fs::create_symlink(s / frame, s / frame);  // a link to itself
  ExpectRefused(Cli("check " + Q(s)), 3, frame);
  fs::remove_all(s);
  ExpectRefused(
      Cli("export " + Q(*scan_) + " --out " + Q(Work() / "E8") + " --crop 2147483647,0,1,1"), 2,
      "--crop");
  std::ofstream(Work() / "a_file") << "x";
  ExpectRefused(Cli("render " + Q(*scan_) + " --out " + Q(Work() / "a_file") + " --size 8x8"), 2,
                "not a folder");
  ExpectRefused(Cli("reconstruct " + Q(*session_) + " --out ''"), 2, "--out");
  ExpectRefused(
      Cli("reconstruct " + Q(*session_) + " --out " + Q(Work() / "SC8") + " --fitter bogus"), 2,
      "--fitter");
  EXPECT_FALSE(fs::exists(Work() / "E8"));
  EXPECT_FALSE(fs::exists(Work() / "SC8"));
  fs::remove(Work() / "a_file");
  // K = 1e999: a number beyond double range is bad input, not an internal error.
  const fs::path k = CopySession("S_k");
  std::string text = ReadTextFile(k / "session.json");
  const size_t at = text.find("\"K\"");
  ASSERT_NE(at, std::string::npos);
  const size_t num = text.find_first_of("-0123456789", at);
  text.insert(num, "1e999, ");
  text.erase(text.find(',', num + 7), 0);
  { std::ofstream(k / "session.json") << text; }
  // (the inserted number makes row 0 of K four long or overflows first: either way exit 3)
  ExpectRefused(Cli("check --quick " + Q(k)), 3, "session.json");
  fs::remove_all(k);
  // brdf: a folder, and a .bsdf shorter than its header.
  ExpectRefused(Cli("brdf info " + Q(Work())), 3, "a folder");
  std::ofstream(Work() / "tiny.bsdf") << "abc";
  ExpectRefused(Cli("brdf info " + Q(Work() / "tiny.bsdf")), 3, "RGL");
  fs::remove(Work() / "tiny.bsdf");
}

}  // namespace
}  // namespace mesoscan
