#include "core/rect.h"

#include <regex>

#include "core/error.h"

namespace mesoscan {

PixelRect ParsePixelRect(const std::string& text, const std::string& option) {
  static const std::regex kCommas(R"(^\s*(\d+)\s*,\s*(\d+)\s*,\s*(\d+)\s*,\s*(\d+)\s*$)");
  static const std::regex kGeometry(R"(^(\d+)x(\d+)\+(\d+)\+(\d+)$)");
  std::smatch m;
  const bool commas = std::regex_match(text, m, kCommas);
  if (!commas && !std::regex_match(text, m, kGeometry))
    MESOSCAN_BAD_OPTION(option, "'" << text
                                    << "': expected X,Y,W,H (non-negative integers, W and H > 0; "
                                       "or WxH+X+Y), e.g. 960,620,256,192");
  long v[4];
  for (int k = 0; k < 4; ++k) {
    // At most 10 digits each (a 32-bit int); a larger value is refused, not wrapped.
    if (m[k + 1].length() > 10 || std::stoll(m[k + 1].str()) > 2147483647LL)
      MESOSCAN_BAD_OPTION(option, "'" << text << "': value too large");
    v[k] = std::stol(m[k + 1].str());
  }
  PixelRect r;
  if (commas)
    r = {int(v[0]), int(v[1]), int(v[2]), int(v[3])};
  else
    r = {int(v[2]), int(v[3]), int(v[0]), int(v[1])};
  if (r.w <= 0 || r.h <= 0) MESOSCAN_BAD_OPTION(option, "'" << text << "': expected W and H > 0");
  return r;
}

std::string ToString(const PixelRect& r) {
  return std::to_string(r.x) + "," + std::to_string(r.y) + "," + std::to_string(r.w) + "," +
         std::to_string(r.h);
}

}  // namespace mesoscan
