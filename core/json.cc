#include "core/json.h"

#include "core/error.h"
#include "core/fs.h"

namespace mesoscan {

Json ReadJsonFile(const std::filesystem::path& path) {
  const std::string text = ReadTextFile(path);
  try {
    return Json::parse(text);
  } catch (const Json::parse_error& e) {
    MESOSCAN_BAD_INPUT(path.string() << ": not valid JSON (byte " << e.byte << ")");
  } catch (const Json::exception& e) {  // e.g. a number beyond double range (1e999)
    std::string what = e.what();
    const size_t close = what.find("] ");
    if (close != std::string::npos) what = what.substr(close + 2);
    MESOSCAN_BAD_INPUT(path.string() << ": not valid JSON (" << what << ")");
  }
}

void WriteJsonFile(const std::filesystem::path& path, const Json& j) {
  WriteTextFile(path, j.dump(2) + "\n");
}

Json MatrixToJson(const Eigen::MatrixXd& m) {
  Json rows = Json::array();
  for (int r = 0; r < m.rows(); ++r) {
    Json row = Json::array();
    for (int c = 0; c < m.cols(); ++c) row.push_back(m(r, c));
    rows.push_back(row);
  }
  return rows;
}

}  // namespace mesoscan
