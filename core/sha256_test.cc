#include "core/sha256.h"

#include <gtest/gtest.h>

#include <fstream>

#include "core/error.h"
#include "core/test_temp_dir.h"

namespace mesoscan {
namespace {

// FIPS 180-2's example digests: "abc" and the empty message.
TEST(Sha256OfFile, KnownDigests) {
  const std::filesystem::path abc = TestTempPath("sha256", "abc.txt");
  std::ofstream(abc, std::ios::binary) << "abc";
  EXPECT_EQ(Sha256OfFile(abc), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  const std::filesystem::path empty = TestTempPath("sha256", "empty.txt");
  std::ofstream(empty, std::ios::binary).flush();
  EXPECT_EQ(Sha256OfFile(empty),
            "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
}

TEST(Sha256OfFile, MissingFileIsBadInputNamingIt) {
  try {
    Sha256OfFile("/nonexistent/rig.json");
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
    EXPECT_NE(std::string(e.what()).find("/nonexistent/rig.json"), std::string::npos);
  }
}

}  // namespace
}  // namespace mesoscan
