// What `vkunroll unroll` (and the library's UnrollSession) is asked to do, as typed values. The CLI
// and the Python bindings only parse their inputs into these; validate_unroll_options() checks the
// combinations before any work starts. Errors are OptionErrors (base/error.hpp) naming the
// option by its field here (times_us, precision, ...), which the CLI spells as its flag and Python
// as its keyword; `what` / `field` arguments below are such field names.
#pragma once
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/precision.hpp"
#include "vkunroll/base/row_timing.hpp"
#include "vkunroll/host/events/sequence.hpp"
#include "vkunroll/host/model/conv_choice.hpp"
#include "vkunroll/host/model/make_backend.hpp"
#include "vkunroll/host/model/tiling.hpp"
#include "vkunroll/host/unroll/unroll_output.hpp"

namespace vkunroll {

// s | m: SelfUnroll-S / -M for every target. physics: the weight-free event double integral.
// automatic: M where the next frame exists, else S; physics without a model. choose: per target,
// S when t* lies in the frame's exposure span, M between frames (when the next frame exists).
enum class UnrollMode { automatic, s, m, physics, choose };
UnrollMode parse_unroll_mode(const std::string& s, const std::string& what);  // "auto" | "s" | ...
const char* unroll_mode_name(UnrollMode m);                                   // "auto", "s", ...

// The image channel order of the model's input; `model`: the weights' metadata says.
enum class ChannelOrder { model, rgb, bgr };
ChannelOrder parse_channel_order(const std::string& s, const std::string& what);

// The physics-informed variant's event gate radius (metadata physics_gate): `automatic` chooses it
// from the recording's noise (choose_gate_radius, unroll_plan.hpp), `model` keeps the weights' value,
// `fixed` takes `radius`.
struct GateRadiusOption {
  enum class Kind { automatic, model, fixed };
  Kind kind = Kind::automatic;
  int radius = 0;
};
constexpr int kMaxGateRadius = 15;  // as the metadata (docs/model.md)
// "auto" | "model" | an integer 0..kMaxGateRadius; the OptionError names field `what`.
GateRadiusOption parse_gate_radius(const std::string& s, const std::string& what);
std::string gate_radius_text(const GateRadiusOption& g);  // "auto", "model" or the number

// Which instants to render.
struct TargetTimes {
  enum class Kind {
    normalized,    // per frame: 0 = first row's exposure start, 1 = last row's exposure end
    absolute_us,   // absolute microseconds; each goes to the frame whose span holds it
    ground_truth,  // exactly the sequence's ground-truth instants
  };
  Kind kind = Kind::normalized;
  std::vector<Rational> values{Rational(1, 2)};
};

// From the front end's texts: `times_us` a value list (absolute; empty: not given), else `times` a
// value list of normalized instants or "gt". Errors name the field (times_us or times).
TargetTimes parse_target_times(const std::string& times, const std::string& times_us = {});

// What the session holds: where it runs and which model.
struct SessionOptions {
  BackendKind backend = BackendKind::vulkan;
  std::string device;             // index, name substring; empty: VKUNROLL_DEVICE, then policy
  Precision precision = Precision::fp32;
  std::string model_path;         // safetensors; empty: physics only
  bool announce = true;           // log the chosen device (info)
  unsigned cpu_threads = 0;       // CPU backend threads (0: the machine's, at most 8)
  // Vulkan: the conv algorithm per shape (host/model/conv_choice.hpp): the device's measured table
  // in the cache directory; auto times a missing shape on first use on a GPU only.
  ConvChoice conv_choice = ConvChoice::automatic;
  // Vulkan: sum every dispatch's GPU time per op (kernel) too, for summary.json's per-op table.
  bool profile_ops = false;
  // Vulkan: keep a timeline of the host stages and every GPU dispatch (UnrollSession::trace(), the
  // CLI's --trace FILE.json). GPU timestamps are written only with this or profile_ops.
  bool trace = false;
};

// The largest time a target or a timing override may name: +-2^53 us (285 years), where a double
// still holds every microsecond (the readers keep frame times within the same range).
constexpr double kMaxTimeUs = 9007199254740992.0;
// The largest normalized target |tau| accepted (a million frame spans).
constexpr double kMaxTau = 1e6;

// `unroll --follow` (docs/follow.md): events from a pipe or a growing file, frames as they appear.
struct FollowOptions {
  bool enabled = false;
  std::string events = "-";       // EVT 3.0 raw (Prophesee '%' header first); "-": stdin
  double idle_s = 10;             // no new event bytes and no awaited frame file for this long: the stream ended
  size_t max_events = size_t(1) << 24;  // the ring of events still needed (a frame window larger than it is an error)
  std::function<bool()> stop_requested;  // polled while waiting (Python's stream closed); empty: SIGINT only
};

struct UnrollOptions {
  std::string sequence;           // folder
  SequenceOptions sequence_options;
  std::string out_dir;
  std::string trace_path;         // --trace: the run's timeline (Chrome trace-event JSON) is written here (empty: none)
  SessionOptions session;
  std::string model_source;       // how session.model_path was chosen (choose_model), for summary.json
  UnrollMode mode = UnrollMode::automatic;
  TargetTimes times;
  std::vector<int> frames;        // empty: all frames
  ChannelOrder channel_order = ChannelOrder::model;
  std::optional<double> contrast;  // physics: c; empty: estimated (see estimate_contrast)
  std::optional<double> gamma;     // physics: decode gamma of the frames; empty: meta.json's source gamma or 1
  GateRadiusOption gate_radius;    // the variant's event gate: chosen from the recording's noise unless given
  bool quiet = false;             // log nothing but warnings and errors, show no progress
  UnrollOutputOptions output;     // frame format, video, what to do with an existing folder (overwrite, resume)
  // Provenance: the command line that asked for this run (summary.json; empty for library calls).
  std::vector<std::string> command_line;
  // How the front end names options (base/error.hpp opt()) in the texts run_unroll writes into
  // summary.json (the CLI: its flags); empty: by their fields.
  FieldSpelling option_spelling;
  // Tiled / sparse model execution (host/model/tiling.hpp, docs/tiling.md). Defaults from the
  // speed-against-error report: sparse exact on 32-pixel tiles with a 32-pixel halo never lost PSNR
  // there and ran 1.8-2x faster on a static scene.
  int64_t tile = 0;               // interior side, multiple of 32; 0: sparse: 32; dense: untiled if it fits, else the largest that fits
  int64_t halo = -1;              // multiple of 32; -1: sparse 32, dense tiles 64
  SparsePolicy sparse = SparsePolicy::exact;
  double sparse_threshold = 0.05; // fast: ev1 + ev2 events per pixel of a tile's input rect
  bool sparse_split = false;      // groups of active tiles run as rectangles of tiles where that is fewer pixels than their box
  FollowOptions follow;
};

// Throws OptionError naming the option when a value or a combination is refused (and, of kind
// input_missing, the events file that does not exist), before any work.
void validate_unroll_options(const UnrollOptions& o);
// The sequence folder and the model file exist (OptionError of kind input_missing naming them);
// run_unroll calls it after validate_unroll_options, the Python bindings (arrays in memory) do not.
void check_unroll_inputs(const UnrollOptions& o);

// Refuses (OptionError of `out_field`) an output that is one of the inputs, holds one, or lies
// inside an input folder: a run never writes over, or replaces, what it reads. `inputs`: (what, path)
// pairs, e.g. ("{sequence}", dir), what naming options as {field}; paths are compared after
// resolving links and '..'.
void check_output_apart(const std::string& out, const std::string& out_field,
                        const std::vector<std::pair<std::string, std::string>>& inputs);

// The timing overrides of a sequence (shared by unroll and voxelize): finite, within kMaxTimeUs,
// line delay >= 0, exposure and frame period > 0. The OptionError names the field (line_delay_us, ...).
void validate_sequence_options(const SequenceOptions& o);

// Every option as resolved, for summary.json's provenance.
nlohmann::json unroll_options_json(const UnrollOptions& o);
// Every string in `j` (at any depth) with its options (opt()) spelled by `spell` (empty: by their fields).
void spell_options(nlohmann::json& j, const FieldSpelling& spell);

// A physics contrast estimate (estimate_contrast in unroll_plan.hpp) and what to say of it.
struct ContrastEstimate {
  double contrast = 0.2;
  double log_offset = 0.0;  // eps fitted with c: the events measure log(luminance + eps)
  std::string source;   // how it was found, for the log and summary.json
  std::string warning;  // empty: none
  bool is_default = false;                  // not estimated: a fixed value (no pair of frames, too few pixels)
  std::vector<std::pair<int, int>> pairs;   // the frame pairs the estimate compared
  size_t pixels = 0;                        // the pixels (over all pairs) the fit used
  // What the recording's noise looks like (-1: not measured): the frames' robust spread of log
  // luminance change where no event fired, and the share of event pixels with no event among
  // their 8 neighbours (background activity and hot pixels are isolated; motion is not).
  double frame_noise = -1;
  double isolated_event_fraction = -1;
};

}  // namespace vkunroll
