#pragma once
// A bound on JSON nesting, checked on the text before it is parsed: copying or printing a JSON
// value recurses once per level, so a file nested 150,000 deep (300 KB) would overflow the
// stack. ReadJsonFile (core/json.h) and the session reader apply it.

#include <string>

#include "core/json.h"

namespace mesoscan {

inline constexpr int kMaxJsonDepth = 128;

// Throws Error naming `label` if the text nests deeper than kMaxJsonDepth (outside strings).
void CheckJsonDepth(const std::string& text, const std::string& label);

// Json::parse with the depth bound; throws Error naming `label` and the position on failure.
Json ParseJsonText(const std::string& text, const std::string& label);

}  // namespace mesoscan
