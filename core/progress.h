#pragma once
// A progress bar on stderr for long work. On a terminal it redraws one line in place; when
// stderr is not a terminal (CI, pipes) it is quiet except for one summary line at Finish().
// Thread-safe: Advance() may be called from TBB workers.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <mutex>
#include <string>

namespace mesoscan {

class Progress {
 public:
  // `label` names the stage ("decode frames"); `total` is the number of work units.
  Progress(std::string label, int64_t total);
  ~Progress();
  void Advance(int64_t n = 1);
  // Prints the final line (label, count, seconds). Called by the destructor if not before.
  void Finish();

  // Globally silence all progress output (tests, --quiet).
  static void SetEnabled(bool enabled);

 private:
  void Draw(int64_t done, bool final_line);
  std::string label_;
  int64_t total_;
  std::atomic<int64_t> done_{0};
  std::atomic<int64_t> last_drawn_permille_{-1};
  std::chrono::steady_clock::time_point start_;
  bool tty_;
  bool finished_ = false;
  std::mutex mutex_;
};

}  // namespace mesoscan
