// Measured conv algorithm choice. Per conv shape (the conv's kernel, stride, padding, channels and
// precision, and its input extent) the candidate algorithms are timed once per device and the
// fastest is kept in a table persisted in the cache directory beside the pipeline cache, one file
// per device UUID and driver version; `vkunroll tune` times them again. Every algorithm gives the
// same result within rounding (the kernels' parity tests), so the choice changes speed only.
#pragma once
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "vkunroll/base/precision.hpp"
#include "vkunroll/base/shape.hpp"

namespace vkunroll {

class Context;
class Conv2d;
class ConvTranspose2d;
enum class ConvAlgo : uint32_t;
enum class ConvTransposeAlgo : uint32_t;

// automatic: the table's entries; a shape the table lacks is timed on first use on a GPU and left
//   to the kernels' heuristic on a CPU device (lavapipe: timing a model there takes minutes).
// heuristic: the kernels' own choice (choose_algorithm), no table.
// cached: the table's entries, the heuristic for the rest; never times.
// measured: the table's entries, a missing shape timed on first use on any device.
// retune: every shape met is timed again once (what `vkunroll tune` runs).
// gpu: the GPU family's rule (gpu_family_algorithm) on any device, lavapipe included, no table: the
//   GPU paths' frames and dispatch counts, checked and counted where no GPU is at hand.
enum class ConvChoice { automatic, heuristic, cached, measured, retune, gpu };
ConvChoice parse_conv_choice(const std::string& s, const std::string& what);  // UsageError naming `what`
const char* conv_choice_name(ConvChoice c);

struct ConvChoiceEntry {
  std::string algo;     // conv_algo_name / conv_transpose_algo_name
  double ms = 0;        // its time (least of the timed runs)
  std::string timings;  // every candidate: "winograd=1.234 gemm=2.345 ..."
  std::string heuristic;  // what the kernels' heuristic picks for the shape (choose_algorithm)
  // Not in the file: the conv's direct-convolution FLOP (GFLOP/s beside the timings), candidates
  // timed, and whether the entry came from a committed table (save() leaves those out of the cache).
  double flop = 0;
  int timed = 0;
  bool committed = false;
};

// How long the measured choice times each candidate. A candidate first runs once untimed (its
// pipelines built, its result checked), then `warm_ms` of untimed submits bring a GPU that idled
// during the host work back to speed, then timed submits until `reps` or `candidate_ms` of wall
// time (at least one); the least device time counts. census: no candidate runs; the entry lists
// them (timings "NAME=untimed") and names the heuristic's algorithm (vkunroll tune --plan).
struct ConvTimingBudget {
  int reps = 3;
  double candidate_ms = 0;  // 0: `reps` timed submits whatever they take
  double warm_ms = 25;
  bool census = false;
};

// Who measured a table: written in its second line, compared with the running device when a
// committed table is looked for (find_committed_conv_table).
struct ConvDeviceIdentity {
  std::string name, driver, uuid;  // driver: DeviceInfo::driver_version_string
  uint32_t vendor_id = 0, device_id = 0;
  bool known() const { return vendor_id != 0 || device_id != 0 || !uuid.empty(); }
};

class ConvChoiceTable {
 public:
  // The device the file says it was measured on (empty for a file without the line).
  const ConvDeviceIdentity& identity() const { return identity_; }
  const ConvChoiceEntry* find(const std::string& key) const;
  void set(const std::string& key, ConvChoiceEntry entry);
  const std::map<std::string, ConvChoiceEntry>& entries() const { return entries_; }
  bool changed() const { return changed_; }

  // The table in `path` (missing file: empty). A line it cannot read is skipped with a warning
  // naming the file and line: a stale or damaged cache never stops a run.
  static ConvChoiceTable load(const std::string& path, std::vector<std::string>* warnings);
  // Writes this table merged over what `path` holds now (another process may have timed other
  // shapes), through a temporary file renamed into place; entries of a committed table stay out.
  // `header`: the device it was measured on. Throws Error naming the path when it cannot be written,
  // and refuses (IoError) to replace a file at `path` that is not a conv choice table (issue 58).
  void save(const std::string& path, const std::string& header, const ConvDeviceIdentity& identity = {}) const;
  // Adds `committed`'s entries where this table has none (this device's own timings win), marked committed.
  void merge_committed(const ConvChoiceTable& committed);

 private:
  std::map<std::string, ConvChoiceEntry> entries_;
  ConvDeviceIdentity identity_;
  bool changed_ = false;
};

ConvDeviceIdentity conv_device_identity(const Context& ctx);

// A regular file whose first line is a conv choice table's (of any version): vkunroll wrote it.
bool is_conv_choice_table(const std::string& path);

// This device's table: its cache file (conv_choice_path), with the best committed table of
// `committed_dirs` merged under it (find_committed_conv_table; the cache's own timings win).
struct DeviceConvTable {
  std::shared_ptr<ConvChoiceTable> table;
  std::string path;                       // the cache file (empty: no cache directory)
  std::string committed, committed_how;   // the committed table merged in (empty: none)
};
DeviceConvTable load_device_conv_table(const Context& ctx, const std::vector<std::string>& committed_dirs,
                                       std::vector<std::string>* warnings);

// A table measured on another machine and committed with the project (for a GPU it has run on), found
// by the running device: `how` says which match it is, the best of "device uuid and driver", "device
// model and driver" (vendor and device id) and "device model, driver <X> measured" (another driver:
// used, and said, since a table of the same chip still beats the heuristic).
struct CommittedConvTable {
  std::string path, how;
  ConvChoiceTable table;
};
// The best match among the `*.tsv` tables in `dirs` (missing folders skipped); nullopt when none
// matches. Unreadable lines and files are skipped with a warning naming them.
std::optional<CommittedConvTable> find_committed_conv_table(const std::vector<std::string>& dirs, const ConvDeviceIdentity& device,
                                                            std::vector<std::string>* warnings);

// <cache directory>/conv-choices-<device uuid>-<driver version>.tsv; empty without a cache directory.
std::string conv_choice_path(const Context& ctx);
// "device name, driver version, uuid": the file's first line.
std::string conv_choice_header(const Context& ctx);

// What the kernels choose for this conv and input on a device that is not a CPU (the GPU family:
// Conv2d::gpu_choice, ConvTranspose2d::gpu_choice), whatever device runs it. An algorithm `candidates`
// lacks falls back there.
ConvAlgo gpu_family_algorithm(const Conv2d& conv, const Shape& in);
ConvTransposeAlgo gpu_family_algorithm(const ConvTranspose2d& conv);

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
ConvChoiceEntry time_conv_algorithms(Context& ctx, const Conv2d& conv, const Shape& in, bool residual,
                                     const ConvTimingBudget& budget);
ConvChoiceEntry time_conv_algorithms(Context& ctx, const ConvTranspose2d& conv, const Shape& in,
                                     const ConvTimingBudget& budget);

// The device's FMA rate in GFLOP/s (fma_ceiling.comp: fp32 vec4 chains; `half`: fma_ceiling_half.comp,
// f16vec4, 0 without shaderFloat16), the best of `reps` submits of about `gflop` each, after one.
// What the conv timings are judged against; read again during a run, it shows a GPU's clock drop.
double fma_ceiling_gflops(Context& ctx, bool half = false, int reps = 5, double gflop = 2.147483648);
// Keeps the device busy on the FMA ceiling kernel for at least `ms` of wall time, so that its clocks
// are up before timings (a GPU idles at a fraction of its clock: an H200's SM at 345 MHz).
void warm_device(Context& ctx, double ms);

}  // namespace vkunroll
