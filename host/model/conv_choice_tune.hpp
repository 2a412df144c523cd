// vkunroll tune's engine (the CLI's `tune` and the device bundle's vkunroll-bench-tune): times every
// candidate algorithm of every conv shape a model meets at the given sizes on this device, keeps the
// fastest in the device's table (conv_choice.hpp: the cache directory, keyed by device UUID and driver
// version) that `unroll` then uses, and reports the model's device time with the kernels' heuristic and
// with the measured choice, side by side. Built for a short GPU window: the clocks are warmed first,
// each candidate is timed for at most candidate_ms, no shape is timed after budget_s, and the FMA
// ceiling is read again beside every shape's timing, so that a clock that dropped shows in the table.
#pragma once
#include <functional>
#include <string>
#include <vector>

#include "vkunroll/base/precision.hpp"
#include "vkunroll/host/model/weights.hpp"

namespace vkunroll {


struct TuneSize {
  int w = 0, h = 0;
  int batch_s = 1;  // S batch items (tiles run several at once)
};

struct TuneOptions {
  std::vector<TuneSize> sizes;  // tune_sizes()
  bool s = true, m = true;      // the modes run (M where the model has it, batch 2, frame sizes only)
  std::vector<Precision> precisions{Precision::fp32};
  int reps = 10;                                    // timed submits per candidate at most
  // candidate_ms: wall ms of timed submits per candidate at most (at least one); 8 keeps the published
  // configuration's table (about 2300 candidates on a GPU with the igemm family, docs/tuning.md)
  // inside budget_s. warm_ms: FMA work at the start. budget_s 0: no limit.
  double candidate_ms = 8, warm_ms = 300, budget_s = 55;
  bool plan = false;    // count shapes and candidates, time nothing, write no table
  bool compare = true;  // then time the model with the heuristic against the measured choice
  std::string device;   // ContextOptions::device
  // Each line of the report as it goes; empty: the log sink at info level.
  std::function<void(const std::string&)> report;
  // Called with this device's table path before anything is timed: throws where the table could not
  // be written (the front end's output rule; empty: none).
  std::function<void(const std::string&)> check_table;
};

// The frames (w, h) at batch 1, and where tile > 0 the sparse tiles' side (tile + 2 halo) at batch 1
// and 4. OptionError naming tile and halo where they are not multiples of 32.
std::vector<TuneSize> tune_sizes(const std::vector<std::pair<int, int>>& frames, int tile, int halo);

// The model option's weights: a file (an input_missing OptionError naming it where missing), or "published": the published
// configuration with random weights, the shapes the benches race (timings do not depend on the values).
Weights tune_model_weights(const std::string& model);

// Reports as it goes (TuneOptions::report). UsageError where there is no cache directory to keep the table in.
void tune_conv_choices(const Weights& weights, const TuneOptions& options);

}  // namespace vkunroll
