#include "vkunroll/runtime/profiler.hpp"

#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/base/stopwatch.hpp"

#include <algorithm>
#include <cstdio>
#include <vector>

namespace vkunroll {

void Profiler::record(const std::string& op, double ms, double flop, double bytes) {
  OpStats& s = ops_[op];
  s.calls++;
  s.total_ms += ms;
  s.flop += flop;
  s.bytes += bytes;
}

double Profiler::total_ms() const {
  double t = 0;
  for (const auto& [name, s] : ops_) t += s.total_ms;
  return t;
}

void Profiler::print(std::ostream& os) const {
  std::vector<std::pair<std::string, OpStats>> rows(ops_.begin(), ops_.end());
  std::sort(rows.begin(), rows.end(), [](const auto& a, const auto& b) { return a.second.total_ms > b.second.total_ms; });
  char line[256];
  std::snprintf(line, sizeof line, "%-28s %7s %11s %10s %9s %9s %6s\n", "op", "calls", "total ms", "mean ms",
                "GFLOP/s", "GB/s", "%time");
  os << line;
  const double total = total_ms();
  for (const auto& [name, s] : rows) {
    char gf[16] = "-", gb[16] = "-";
    if (s.flop > 0) std::snprintf(gf, sizeof gf, "%.2f", s.gflops());
    if (s.bytes > 0) std::snprintf(gb, sizeof gb, "%.2f", s.gbps());
    std::snprintf(line, sizeof line, "%-28s %7llu %11.3f %10.3f %9s %9s %5.1f%%\n", name.c_str(),
                  static_cast<unsigned long long>(s.calls), s.total_ms, s.mean_ms(), gf, gb,
                  total > 0 ? 100.0 * s.total_ms / total : 0.0);
    os << line;
  }
  std::snprintf(line, sizeof line, "%-28s %7s %11.3f\n", "total", "", total);
  os << line;
}

double best_gpu_ms(Context& ctx, int reps, const std::function<void(CommandStream&)>& record, Profiler* total) {
  // Warm-up: submissions for at least 25 ms (at most 64 of them), so that a GPU that clocked down
  // while the host worked is back at speed for the timed runs (an H200's FMA ceiling read 53 and 9.6
  // TFLOP/s within one bench run, 2026-12-04). On lavapipe one run usually takes that long alone.
  const Stopwatch warm_clock;
  for (int w = 0; w < 64; ++w) {
    CommandStream warm(ctx);
    record(warm);
    warm.submit_and_wait();
    if (warm_clock.ms() >= 25) break;
  }
  const bool stamps = ctx.info().timestamps;
  double best = 1e300;
  for (int r = 0; r < std::max(1, reps); ++r) {
    Profiler prof;
    CommandStream cs(ctx, stamps ? &prof : nullptr);
    record(cs);
    const Stopwatch clock;
    cs.submit_and_wait();
    const double wall = clock.ms();
    best = std::min(best, stamps ? prof.total_ms() : wall);
    if (total)
      for (const auto& [op, st] : prof.ops()) total->record(op, st.total_ms, st.flop, st.bytes);
  }
  return best;
}

}  // namespace vkunroll
