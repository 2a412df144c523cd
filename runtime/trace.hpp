// Trace: a timeline of a run in the Chrome trace-event format (JSON) that Perfetto
// (ui.perfetto.dev) and chrome://tracing open: host spans on named tracks (the unroll session's
// stages, the stream's waits) and the GPU's dispatches from their timestamps, each named with its
// op, what the op said about its shape and algorithm, and its GFLOP/s.
//
// GPU times come from the device's timestamp clock, mapped onto the host's steady clock by one
// offset: set by the first submission (its first timestamp lands at its submit time) and raised
// whenever a later submission would otherwise start before it was submitted, so the GPU track keeps
// the device's own spacing and never runs ahead of the host. Dispatches that overlap on the device
// (no barrier between them) go to extra lanes of the GPU track: every lane is a sequence of
// non-overlapping spans.
#pragma once
#include <cstdint>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "vkunroll/base/stopwatch.hpp"

namespace vkunroll {

// One timed command of a submission, as the stream read it back.
struct GpuSpan {
  std::string name;    // the op (DispatchInfo::name)
  std::string detail;  // shape and algorithm where the op gave them (DispatchInfo::detail)
  std::string stage;   // the stage it was recorded in
  double flop = 0, bytes = 0;
  uint32_t groups[3] = {0, 0, 0};  // workgroups (0: a copy or fill)
  double begin_ns = 0, end_ns = 0;  // on the device's timestamp clock (ticks x period)
};

class Trace {
 public:
  using Clock = vkunroll::Clock;
  Trace();

  // A host span on `track` (a named lane: "host stages", "host waits").
  void host_span(const std::string& track, const std::string& name, Clock::time_point begin, Clock::time_point end);
  // The timed commands of one submission, submitted at `submitted` (host time).
  void gpu_submission(Clock::time_point submitted, const std::vector<GpuSpan>& spans);

  // The events as a JSON document: {"traceEvents": [...], "displayTimeUnit": "ms"}, spans ("ph": "X",
  // ts and dur in microseconds) sorted by start time, and one thread_name record per track.
  std::string json() const;
  // Writes json() to `path` through a temporary file in its folder; an Error naming the file otherwise.
  void write(const std::string& path) const;

  // The GPU spans' summed duration per op name, in ms (what the profiler's per-op totals must equal).
  std::map<std::string, double> gpu_ms_by_op() const;
  size_t spans() const;

 private:
  struct Event {
    int tid;
    std::string name, args;  // args: a JSON object's text
    double ts_us, dur_us;
  };
  int track_id(const std::string& track);  // with mutex_ held
  int gpu_lane(double ts_us, double end_us);  // with mutex_ held

  mutable std::mutex mutex_;
  Clock::time_point t0_;
  std::map<std::string, int> tracks_;  // name -> tid
  std::vector<double> lane_end_us_;    // GPU lanes: end of each lane's last span
  std::vector<int> lane_tid_;
  bool offset_set_ = false;
  double offset_us_ = 0;  // host us (from t0_) = device ns / 1000 + offset_us_
  std::vector<Event> events_;
  std::map<std::string, double> gpu_ms_by_op_;
};

// Escapes `s` for a JSON string (quotes, backslashes, control characters).
std::string json_escape(const std::string& s);

}  // namespace vkunroll
