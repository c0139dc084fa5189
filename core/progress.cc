#include "core/progress.h"

#include <unistd.h>

#include <atomic>
#include <cstdio>

namespace mesoscan {
namespace {
std::atomic<bool> g_enabled{true};
}

void Progress::SetEnabled(bool enabled) { g_enabled = enabled; }

Progress::Progress(std::string label, int64_t total)
    : label_(std::move(label)),
      total_(total > 0 ? total : 1),
      start_(std::chrono::steady_clock::now()),
      tty_(isatty(STDERR_FILENO) != 0) {}

Progress::~Progress() { Finish(); }

void Progress::Advance(int64_t n) {
  const int64_t done = done_.fetch_add(n) + n;
  if (!tty_ || !g_enabled) return;
  const int64_t permille = done * 1000 / total_;
  int64_t last = last_drawn_permille_.load();
  // Redraw at most every 0.5%: cheap enough to call per row from many threads.
  if (permille >= last + 5 && last_drawn_permille_.compare_exchange_strong(last, permille)) {
    std::lock_guard<std::mutex> lock(mutex_);
    Draw(done, false);
  }
}

void Progress::Draw(int64_t done, bool final_line) {
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  const double frac = done >= total_ ? 1.0 : static_cast<double>(done) / total_;
  if (tty_) {
    constexpr int kWidth = 30;
    char bar[kWidth + 1];
    const int filled = static_cast<int>(frac * kWidth);
    for (int i = 0; i < kWidth; ++i) bar[i] = i < filled ? '#' : '.';
    bar[kWidth] = '\0';
    std::fprintf(stderr, "\r%-24s [%s] %5.1f%%  %.1f s%s", label_.c_str(), bar, 100.0 * frac, s,
                 final_line ? "\n" : "");
  } else if (final_line) {
    std::fprintf(stderr, "%s: done in %.2f s\n", label_.c_str(), s);
  }
  std::fflush(stderr);
}

void Progress::Finish() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (finished_) return;
  finished_ = true;
  if (g_enabled) Draw(done_.load(), true);
}

}  // namespace mesoscan
