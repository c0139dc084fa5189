#pragma once
// Minimal leveled logging to stderr. MESOSCAN_LOG(kInfo) << "..."; one line per message.

#include <sstream>
#include <string>

namespace mesoscan {

enum class LogLevel { kDebug = 0, kInfo = 1, kWarning = 2, kError = 3, kQuiet = 4 };

// Messages below this level are dropped. Default kInfo; the CLI sets it from --verbose/--quiet.
void SetLogLevel(LogLevel level);
LogLevel GetLogLevel();

class LogMessage {
 public:
  explicit LogMessage(LogLevel level) : level_(level) {}
  ~LogMessage();
  template <typename T>
  LogMessage& operator<<(const T& v) {
    if (level_ >= GetLogLevel()) oss_ << v;
    return *this;
  }

 private:
  LogLevel level_;
  std::ostringstream oss_;
};

#define MESOSCAN_LOG(level) ::mesoscan::LogMessage(::mesoscan::LogLevel::level)

}  // namespace mesoscan
