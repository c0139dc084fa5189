#include "core/json.h"

#include "core/error.h"
#include "core/fs.h"
#include "core/json_depth.h"

namespace mesoscan {

// The text's bracket nesting, outside strings, checked against kMaxJsonDepth before parsing
// (the parser itself does not recurse; copies and dumps of the value would).
void CheckJsonDepth(const std::string& text, const std::string& label) {
  int depth = 0;
  bool in_string = false, escaped = false;
  for (size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (in_string) {
      if (escaped)
        escaped = false;
      else if (c == '\\')
        escaped = true;
      else if (c == '"')
        in_string = false;
      continue;
    }
    if (c == '"') {
      in_string = true;
    } else if (c == '{' || c == '[') {
      if (++depth > kMaxJsonDepth)
        MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label), "JSON nested deeper than " << kMaxJsonDepth
                                                                                 << " levels (byte "
                                                                                 << i + 1 << ")");
    } else if (c == '}' || c == ']') {
      --depth;
    }
  }
}

Json ParseJsonText(const std::string& text, const std::string& label) {
  CheckJsonDepth(text, label);
  try {
    return Json::parse(text);
  } catch (const Json::parse_error& e) {
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label), "not valid JSON (byte " << e.byte << ")");
  } catch (const Json::exception& e) {  // e.g. a number beyond double range (1e999)
    std::string what = e.what();
    const size_t close = what.find("] ");
    if (close != std::string::npos) what = what.substr(close + 2);
    MESOSCAN_BAD_INPUT_AT(ErrorSite::File(label), "not valid JSON (" << what << ")");
  }
}

Json ReadJsonFile(const std::filesystem::path& path) {
  return ParseJsonText(ReadTextFile(path), path.string());
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
