// Wall-clock milliseconds for the per-stage timings in summaries and benches.
#pragma once
#include <chrono>

namespace vkunroll {

using Clock = std::chrono::steady_clock;
inline double ms_since(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

}  // namespace vkunroll
