#pragma once
// Wall time per pipeline stage (steady clock): Stage(name) records the time since the previous
// call (or construction) under `name`, in call order. One home for the stage timings that
// reconstruct, simulate and export report (report.json "timings_s").

#include <chrono>
#include <string>
#include <utility>
#include <vector>

namespace mesoscan {

using StageTimings = std::vector<std::pair<std::string, double>>;

class StageTimer {
 public:
  // `out` receives (stage, seconds) pairs; it must outlive the timer.
  explicit StageTimer(StageTimings* out) : out_(out), start_(Clock::now()), last_(start_) {}
  // Records the time since the previous stage ended; returns it in seconds.
  double Stage(const std::string& name) {
    const auto now = Clock::now();
    const double s = std::chrono::duration<double>(now - last_).count();
    out_->emplace_back(name, s);
    last_ = now;
    return s;
  }
  // Seconds since construction.
  double Total() const { return std::chrono::duration<double>(Clock::now() - start_).count(); }

 private:
  using Clock = std::chrono::steady_clock;
  StageTimings* out_;
  Clock::time_point start_, last_;
};

}  // namespace mesoscan
