#pragma once
// Wall time (steady clock), one home for every timing the tools report: a Stopwatch for one
// interval, and a StageTimer for a pipeline of stages: Stage(name) records the time since the
// previous call (or construction) under `name`, in call order (reconstruct's report.json
// "timings_s", the map set's stages, simulate's and export's summaries).

#include <sys/resource.h>

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

// CPU time (user + system) of the whole process so far, every thread, s.
inline double ProcessCpuSeconds() {
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  return static_cast<double>(ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) +
         1e-6 * static_cast<double>(ru.ru_utime.tv_usec + ru.ru_stime.tv_usec);
}

// Peak resident set size of the process so far, MB.
inline double PeakRssMegabytes() {
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  return static_cast<double>(ru.ru_maxrss) / 1024.0;
}

// Seconds recorded under `name` (summed if it occurs more than once); 0 if none.
inline double StageSeconds(const StageTimings& timings, const std::string& name) {
  double s = 0.0;
  for (const auto& [n, t] : timings)
    if (n == name) s += t;
  return s;
}

class StageTimer {
 public:
  // `out` receives (stage, seconds) pairs; it must outlive the timer. `cpu_out` (optional) the
  // process CPU time of each stage (every thread: several times the wall time when parallel).
  explicit StageTimer(StageTimings* out, StageTimings* cpu_out = nullptr)
      : out_(out), cpu_out_(cpu_out), last_cpu_(cpu_out ? ProcessCpuSeconds() : 0.0) {}
  // Records the time since the previous stage ended (or Skip()); returns it in seconds.
  double Stage(const std::string& name) {
    const double s = last_.Restart();
    out_->emplace_back(name, s);
    if (cpu_out_) {
      const double c = ProcessCpuSeconds();
      cpu_out_->emplace_back(name, c - last_cpu_);
      last_cpu_ = c;
    }
    return s;
  }
  // Starts the next stage now, without recording the time since the previous one.
  void Skip() {
    last_.Restart();
    if (cpu_out_) last_cpu_ = ProcessCpuSeconds();
  }
  // Seconds since construction.
  double Total() const { return total_.Seconds(); }

 private:
  StageTimings* out_;
  StageTimings* cpu_out_;
  double last_cpu_;
  Stopwatch total_, last_;
};

}  // namespace mesoscan
