#include "core/output_dir.h"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmath>
#include <fstream>

#include "core/budget.h"
#include "core/error.h"
#include "core/fs.h"
#include "core/image_input.h"

namespace mesoscan {
namespace {
namespace fs = std::filesystem;

class OutputDirTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("mesoscan_output_dir_test_" + std::to_string(getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "in");
    std::ofstream(dir_ / "in" / "data.txt") << "input";
  }
  void TearDown() override { fs::remove_all(dir_); }
  static ErrorKind KindOf(const std::function<void()>& fn) {
    try {
      fn();
    } catch (const Error& e) {
      return e.kind();
    }
    return ErrorKind::kInternal;  // "no error" reads as a failure below
  }
  fs::path dir_;
};

TEST_F(OutputDirTest, PathIsWithinComparesWholeComponents) {
  EXPECT_TRUE(PathIsWithin("/a/b/c", "/a/b"));
  EXPECT_TRUE(PathIsWithin("/a/b", "/a/b"));
  EXPECT_TRUE(PathIsWithin("/a/b", "/a/b/"));
  EXPECT_FALSE(PathIsWithin("/a/bc", "/a/b"));
  EXPECT_FALSE(PathIsWithin("/a", "/a/b"));
}

TEST_F(OutputDirTest, RefusesInputsAndForeignFolders) {
  const fs::path in = dir_ / "in";
  auto check = [&](const fs::path& out, bool force = false) {
    return KindOf([&] { CheckOutputFolder({"test", "out", out, {in}, force, {}}); });
  };
  EXPECT_EQ(check(in), ErrorKind::kUsage);
  EXPECT_EQ(check(dir_), ErrorKind::kUsage);
  EXPECT_EQ(check(in / "sub"), ErrorKind::kUsage);
  EXPECT_EQ(check(in / "sub" / ".."), ErrorKind::kUsage);
  EXPECT_EQ(check(""), ErrorKind::kUsage);
  EXPECT_EQ(check(in, /*force=*/true), ErrorKind::kUsage) << "force never overrides an input";
  EXPECT_EQ(check(dir_ / "in" / "data.txt" / ".." / ".." / "new"), ErrorKind::kInternal);  // ok
  fs::create_directories(dir_ / "foreign");
  std::ofstream(dir_ / "foreign" / "x") << "x";
  EXPECT_EQ(check(dir_ / "foreign"), ErrorKind::kUsage);
  EXPECT_EQ(check(dir_ / "foreign", true), ErrorKind::kInternal);  // ok with force
  fs::create_directories(dir_ / "empty");
  EXPECT_EQ(check(dir_ / "empty"), ErrorKind::kInternal);  // ok: empty
  EXPECT_EQ(check(dir_ / "in" / "data.txt"), ErrorKind::kUsage);
}

TEST_F(OutputDirTest, ReplacesItsOwnOutputAndKeepsItOnFailure) {
  const OutputSpec spec{"test", "out", dir_ / "out", {dir_ / "in"}, false, {}};
  WriteOutputFolder(spec, [](const fs::path& tmp) { std::ofstream(tmp / "a") << "1"; });
  WriteOutputFolder(spec, [](const fs::path& tmp) { std::ofstream(tmp / "a") << "2"; });
  EXPECT_EQ(ReadTextFile(dir_ / "out" / "a"), "2");
  EXPECT_THROW(WriteOutputFolder(spec,
                                 [](const fs::path& tmp) {
                                   std::ofstream(tmp / "a") << "3";
                                   MESOSCAN_BAD_INPUT("fails half way");
                                 }),
               Error);
  EXPECT_EQ(ReadTextFile(dir_ / "out" / "a"), "2");
  int entries = 0;
  for (const auto& e : fs::directory_iterator(dir_)) entries += e.path().filename() != "in";
  EXPECT_EQ(entries, 1) << "no temporary left behind";
}

TEST_F(OutputDirTest, StaleTemporariesAreRemovedAndABackupIsRecovered) {
  // A process that no longer exists (pid_max is below 2^22) left a temporary and a backup of
  // "out" after renaming the old output aside and before renaming the new one in.
  const fs::path tmp = dir_ / ".out.mesoscan-tmp.4999999.0",
                 old = dir_ / ".out.mesoscan-old.4999999.1";
  fs::create_directories(tmp);
  fs::create_directories(old);
  std::ofstream(old / "a") << "old";
  CleanStaleOutputs(dir_ / "out");
  EXPECT_FALSE(fs::exists(tmp));
  EXPECT_FALSE(fs::exists(old));
  EXPECT_EQ(ReadTextFile(dir_ / "out" / "a"), "old");
  // With the final name present, a stale backup is only removed.
  fs::create_directories(old);
  CleanStaleOutputs(dir_ / "out");
  EXPECT_FALSE(fs::exists(old));
  EXPECT_EQ(ReadTextFile(dir_ / "out" / "a"), "old");
  // A live process's temporaries are left alone (this process).
  const fs::path live = dir_ / (".out.mesoscan-tmp." + std::to_string(getpid()) + ".7");
  fs::create_directories(live);
  CleanStaleOutputs(dir_ / "out");
  EXPECT_TRUE(fs::exists(live));
}

TEST_F(OutputDirTest, ImagesAreOpenedOnlyAsRegularFiles) {
  auto message = [](const fs::path& p) {
    try {
      CheckRegularFile(p);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("(no error)");
  };
  EXPECT_NE(message("/dev/zero").find("a device"), std::string::npos);
  ASSERT_EQ(mkfifo((dir_ / "fifo.png").c_str(), 0600), 0);
  EXPECT_NE(message(dir_ / "fifo.png").find("a FIFO"), std::string::npos);
  EXPECT_NE(message(dir_ / "in").find("a folder"), std::string::npos);
  fs::create_symlink(dir_ / "loop.png", dir_ / "loop.png");
  EXPECT_NE(message(dir_ / "loop.png").find("cannot open"), std::string::npos);
  EXPECT_EQ(message(dir_ / "in" / "data.txt"), "(no error)");
}

}  // namespace
}  // namespace mesoscan
