#include "core/log.h"

#include <atomic>
#include <cstdio>
#include <mutex>

namespace mesoscan {
namespace {
std::atomic<LogLevel> g_level{LogLevel::kInfo};
std::mutex g_mutex;
}  // namespace

void SetLogLevel(LogLevel level) { g_level = level; }
LogLevel GetLogLevel() { return g_level; }

LogMessage::~LogMessage() {
  if (level_ < GetLogLevel()) return;
  static const char* kPrefix[] = {"debug: ", "", "warning: ", "error: ", ""};
  std::lock_guard<std::mutex> lock(g_mutex);
  std::fprintf(stderr, "%s%s\n", kPrefix[static_cast<int>(level_)], oss_.str().c_str());
}

}  // namespace mesoscan
