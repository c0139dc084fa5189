#include "core/json.h"

#include <gtest/gtest.h>

#include "core/error.h"
#include "core/fs.h"
#include "core/test_temp_dir.h"

namespace mesoscan {
namespace {

TEST(Json, WrittenFilesReadBackAndMatricesAreRowMajor) {
  const auto dir = TestTempDir("json", "rt");
  Eigen::MatrixXd m(2, 3);
  m << 1, 2, 3, 4, 5, 6;
  const Json j = {{"K", MatrixToJson(m)}, {"name", "coin"}};
  WriteJsonFile(dir / "a.json", j);
  const Json back = ReadJsonFile(dir / "a.json");
  EXPECT_EQ(back, j);
  EXPECT_EQ(back["K"][1][0].get<double>(), 4.0);
  EXPECT_EQ(back["K"][0].size(), 3u);
}

TEST(Json, ASyntaxErrorNamesTheFile) {
  const auto dir = TestTempDir("json", "bad");
  WriteTextFile(dir / "bad.json", "{\"format\": \n");
  try {
    ReadJsonFile(dir / "bad.json");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kBadInput);
    EXPECT_EQ(e.file(), (dir / "bad.json").string());
    EXPECT_NE(std::string(e.what()).find("not valid JSON"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace mesoscan
