// Measured conv algorithm choice. Per conv shape (the conv's kernel, stride, padding, channels and
// precision, and its input extent) the candidate algorithms are timed once per device and the
// fastest is kept in a table persisted in the cache directory beside the pipeline cache, one file
// per device UUID and driver version; `vkunroll tune` times them again. Every algorithm gives the
// same result within rounding (the kernels' parity tests), so the choice changes speed only.
#pragma once
#include <map>
#include <string>
#include <vector>

#include "vkunroll/base/precision.hpp"
#include "vkunroll/base/shape.hpp"

namespace vkunroll {

class Context;
class Conv2d;
class ConvTranspose2d;

// automatic: the table's entries; a shape the table lacks is timed on first use on a GPU and left
//   to the kernels' heuristic on a CPU device (lavapipe: timing a model there takes minutes).
// heuristic: the kernels' own choice (choose_algorithm), no table.
// cached: the table's entries, the heuristic for the rest; never times.
// measured: the table's entries, a missing shape timed on first use on any device.
// retune: every shape met is timed again once (what `vkunroll tune` runs).
enum class ConvChoice { automatic, heuristic, cached, measured, retune };
ConvChoice parse_conv_choice(const std::string& s, const std::string& what);  // UsageError naming `what`
const char* conv_choice_name(ConvChoice c);

struct ConvChoiceEntry {
  std::string algo;     // conv_algo_name / conv_transpose_algo_name
  double ms = 0;        // its time (least of the timed runs)
  std::string timings;  // every candidate: "winograd=1.234 gemm=2.345 ..."
  std::string heuristic;  // what the kernels' heuristic picks for the shape (choose_algorithm)
};

class ConvChoiceTable {
 public:
  const ConvChoiceEntry* find(const std::string& key) const;
  void set(const std::string& key, ConvChoiceEntry entry);
  const std::map<std::string, ConvChoiceEntry>& entries() const { return entries_; }
  bool changed() const { return changed_; }

  // The table in `path` (missing file: empty). A line it cannot read is skipped with a warning
  // naming the file and line: a stale or damaged cache never stops a run.
  static ConvChoiceTable load(const std::string& path, std::vector<std::string>* warnings);
  // Writes this table merged over what `path` holds now (another process may have timed other
  // shapes), through a temporary file renamed into place. `header`: the device it was measured on.
  // Throws Error naming the path when it cannot be written.
  void save(const std::string& path, const std::string& header) const;

 private:
  std::map<std::string, ConvChoiceEntry> entries_;
  bool changed_ = false;
};

// <cache directory>/conv-choices-<device uuid>-<driver version>.tsv; empty without a cache directory.
std::string conv_choice_path(const Context& ctx);
// "device name, driver version, uuid": the file's first line.
std::string conv_choice_header(const Context& ctx);

// The table's key of a conv and its input. The batch is rounded up to a power of two (tiled runs
// batch a varying number of tiles); height and width are exact.
std::string conv_choice_key(const Conv2d& conv, const Shape& in, bool residual);
std::string conv_choice_key(const ConvTranspose2d& conv, const Shape& in);

// Empty when `result` agrees with `reference` within the precision's tolerance (fp32: 1e-3, fp16:
// 2e-2 of max(1, max |reference|)), else "rejected(max diff ...)". NaN never agrees.
std::string conv_choice_disagreement(const std::vector<float>& reference, const std::vector<float>& result,
                                     Precision precision);

// Times every candidate on device tensors of the conv's precision holding uniform values in [-1, 1]
// (the best of `reps` submits after a warm-up, device timestamps) and names the fastest. A candidate
// whose result disagrees with the first candidate's is not timed but listed as rejected: on a device
// where a path computes something else (a driver bug, the never-run cooperative-matrix path) the
// fastest wrong answer is never chosen.
ConvChoiceEntry time_conv_algorithms(Context& ctx, const Conv2d& conv, const Shape& in, bool residual, int reps);
ConvChoiceEntry time_conv_algorithms(Context& ctx, const ConvTranspose2d& conv, const Shape& in, int reps);

}  // namespace vkunroll
