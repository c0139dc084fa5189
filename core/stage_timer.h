#pragma once
// Wall time (steady clock), one home for every timing the tools report: a Stopwatch for one
// interval, and a StageTimer for a pipeline of stages: Stage(name) records the time since the
// previous call (or construction) under `name`, in call order (reconstruct's report.json
// "timings_s", the map set's stages, simulate's and export's summaries).

#include <chrono>
#include <string>
#include <utility>
#include <vector>

namespace mesoscan {

class Stopwatch {
 public:
  Stopwatch() : start_(Clock::now()) {}
  // Seconds since construction or the last Restart().
  double Seconds() const { return std::chrono::duration<double>(Clock::now() - start_).count(); }
  // Returns Seconds() and starts again from now.
  double Restart() {
    const auto now = Clock::now();
    const double s = std::chrono::duration<double>(now - start_).count();
    start_ = now;
    return s;
  }

 private:
  using Clock = std::chrono::steady_clock;
  Clock::time_point start_;
};

using StageTimings = std::vector<std::pair<std::string, double>>;

// Seconds recorded under `name` (summed if it occurs more than once); 0 if none.
inline double StageSeconds(const StageTimings& timings, const std::string& name) {
  double s = 0.0;
  for (const auto& [n, t] : timings)
    if (n == name) s += t;
  return s;
}

class StageTimer {
 public:
  // `out` receives (stage, seconds) pairs; it must outlive the timer.
  explicit StageTimer(StageTimings* out) : out_(out) {}
  // Records the time since the previous stage ended (or Skip()); returns it in seconds.
  double Stage(const std::string& name) {
    const double s = last_.Restart();
    out_->emplace_back(name, s);
    return s;
  }
  // Starts the next stage now, without recording the time since the previous one.
  void Skip() { last_.Restart(); }
  // Seconds since construction.
  double Total() const { return total_.Seconds(); }

 private:
  StageTimings* out_;
  Stopwatch total_, last_;
};

}  // namespace mesoscan
