// Profiler: GPU time of every dispatch (timestamp queries), aggregated per op name.
#pragma once
#include <cstdint>
#include <functional>
#include <map>
#include <ostream>
#include <string>

namespace vkunroll {

class CommandStream;
class Context;

struct OpStats {
  uint64_t calls = 0;
  double total_ms = 0;
  double flop = 0;   // as reported by the op (direct-algorithm count for convs)
  double bytes = 0;  // bytes read + written, as reported by the op
  double mean_ms() const { return calls ? total_ms / calls : 0; }
  double gflops() const { return total_ms > 0 ? flop / (total_ms * 1e6) : 0; }
  double gbps() const { return total_ms > 0 ? bytes / (total_ms * 1e6) : 0; }
};

class Profiler {
 public:
  void record(const std::string& op, double ms, double flop, double bytes);
  const std::map<std::string, OpStats>& ops() const { return ops_; }
  double total_ms() const;
  void clear() { ops_.clear(); }
  // A table: op, calls, total ms, mean ms, GFLOP/s, GB/s, sorted by total time.
  void print(std::ostream& os) const;

 private:
  std::map<std::string, OpStats> ops_;
};

// GPU time of what `record` records: the least of `reps` timed submits after untimed warm-up submits
// (at least one, and at least 25 ms of them: the first compiles pipelines, and a GPU that idled gets its
// clocks back up; on a shared machine the least is the least disturbed run). Where
// the queue writes no timestamps, the wall time of each submit. `total` (optional) gets every timed
// dispatch. The benches and the conv algorithm tuner share it.
double best_gpu_ms(Context& ctx, int reps, const std::function<void(CommandStream&)>& record, Profiler* total = nullptr);

}  // namespace vkunroll
