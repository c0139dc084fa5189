#include "core/fs.h"

#include <gtest/gtest.h>

#include <stdexcept>

#include "core/error.h"
#include "core/test_temp_dir.h"

namespace mesoscan {
namespace fs = std::filesystem;
namespace {

TEST(Fs, AFailedWriteLeavesTheOldFileAndNoTemporary) {
  const fs::path dir = TestTempDir("fs", "atomic");
  WriteTextFile(dir / "a.txt", "old");
  EXPECT_THROW(WriteFileChecked(dir / "a.txt",
                                [](CheckedFile& f) {
                                  f.Write("half");
                                  throw std::runtime_error("killed");
                                }),
               std::runtime_error);
  EXPECT_EQ(ReadTextFile(dir / "a.txt"), "old");
  int entries = 0;
  for (const auto& e : fs::directory_iterator(dir)) entries += e.path().filename() != "a.txt";
  EXPECT_EQ(entries, 0) << "a temporary was left behind";
  WriteTextFile(dir / "a.txt", "new");
  EXPECT_EQ(ReadTextFile(dir / "a.txt"), "new");
}

TEST(Fs, AWriteThatFailsNamesTheFinalFileAsData) {
  const fs::path path = TestTempDir("fs", "unwritable") / "missing" / "a.txt";
  try {
    WriteTextFile(path, "x");
    ADD_FAILURE() << path << " written";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
    EXPECT_EQ(e.file(), path.string());
    EXPECT_EQ(e.Detail().rfind("cannot write (", 0), 0u) << e.what();
  }
  EXPECT_FALSE(fs::exists(path.parent_path()));
}

TEST(Fs, TemporarySiblingsAreUniqueAndKeepTheExtension) {
  const fs::path a = TempSiblingPath("/x/out.png"), b = TempSiblingPath("/x/out.png");
  EXPECT_NE(a, b);
  EXPECT_EQ(a.parent_path(), fs::path("/x"));
  EXPECT_EQ(a.extension(), ".png");
}

TEST(Fs, ReadingAFolderOrAMissingFileNamesIt) {
  const fs::path dir = TestTempDir("fs", "read");
  for (const fs::path& p : {dir, dir / "missing.txt"}) {
    try {
      ReadTextFile(p);
      ADD_FAILURE() << p << " read";
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
      EXPECT_EQ(e.file(), p.string());
    }
  }
}

TEST(Fs, AFolderIsReplacedOnlyWhenItsFillSucceeds) {
  const fs::path dir = TestTempDir("fs", "folder");
  WriteFolderAtomically(dir / "out", [](const fs::path& tmp) { WriteTextFile(tmp / "a", "1"); });
  EXPECT_THROW(WriteFolderAtomically(dir / "out",
                                     [](const fs::path& tmp) {
                                       WriteTextFile(tmp / "b", "2");
                                       throw std::runtime_error("killed");
                                     }),
               std::runtime_error);
  EXPECT_EQ(ReadTextFile(dir / "out" / "a"), "1");
  EXPECT_FALSE(fs::exists(dir / "out" / "b"));
}

}  // namespace
}  // namespace mesoscan
