// Wall-clock time for the per-stage timings in summaries, benches and progress: the one clock of
// the project (nothing else calls std::chrono::steady_clock).
//
//   Stopwatch t;  ...;  report["ms"] = t.ms();
#pragma once
#include <chrono>

namespace vkunroll {

using Clock = std::chrono::steady_clock;
inline double ms_since(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

// Time since construction (or the last restart()).
class Stopwatch {
 public:
  Stopwatch() : start_(Clock::now()) {}
  void restart() { start_ = Clock::now(); }
  Clock::time_point started() const { return start_; }
  double ms() const { return ms_since(start_); }
  double seconds() const { return std::chrono::duration<double>(Clock::now() - start_).count(); }

 private:
  Clock::time_point start_;
};

}  // namespace vkunroll
