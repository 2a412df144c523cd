// Profiler: GPU time of every dispatch (timestamp queries), aggregated per op name.
#pragma once
#include <cstdint>
#include <map>
#include <ostream>
#include <string>

namespace vkunroll {

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

}  // namespace vkunroll
