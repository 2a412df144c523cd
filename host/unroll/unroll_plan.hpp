// The unroll job's planning, shared by run_unroll (the CLI) and the Python bindings' unroll():
// which targets go to which frame, how each target is unrolled, which events a frame needs, the
// frames' images, and the physics contrast estimate. The per-frame work itself is UnrollSession's.
#pragma once
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "vkunroll/base/events.hpp"
#include "vkunroll/host/events/sequence.hpp"
#include "vkunroll/host/unroll/session.hpp"
#include "vkunroll/host/unroll/unroll_options.hpp"

namespace vkunroll {

struct UnrollTarget {
  Rational t_us;
  double tau = 0;
  std::string name;  // output file name override (ground-truth instants)
  int gt = -1;       // index into seq.ground_truth, -1: none
};

// An 8/16-bit or float image file as BGR float32 in [0, 1] of the sensor's size; throws Error
// naming the file (unreadable, wrong size, NaN or Inf).
cv::Mat read_frame_image(const std::string& path, int width, int height);

// The middle of the frame's exposure span, microseconds.
double frame_mid(const SequenceFrame& f);

// The frames' encoding gamma a generic sequence's meta.json records (source.settings.gamma, as the
// simulator writes it, or source.gamma); 1 otherwise.
double read_meta_gamma(const Sequence& seq);

// The events of [lo, hi] microseconds (both ends included), read through the file's index;
// `report` gets the reader's counts.
EventStream read_window(const Sequence& seq, double lo, double hi, EventReadReport* report = nullptr);

// `requested` checked against the sequence (empty: every frame).
std::vector<int> chosen_frames(const Sequence& seq, const std::vector<int>& requested);

// The targets of every chosen frame, refused where no events can exist (beyond a frame period
// outside the recording). An absolute instant (gt, times_us) goes to the frame whose span holds it
// among all frames (else the nearest middle); `frames` bounds them: a times_us instant of a frame
// not chosen is refused, a ground-truth instant of one is left out and counted in `notes`.
// `where` prefixes the errors.
std::map<int, std::vector<UnrollTarget>> plan_targets(const Sequence& seq, const std::vector<int>& frames,
                                                      const TargetTimes& times, const std::string& where,
                                                      std::vector<std::string>* notes = nullptr);

// A target instant lies within the recording's span, give or take a frame period (an OptionError naming
// `field`, times or times_us, otherwise): unroll's target times and voxelize's, one rule.
void check_target_in_recording(const Sequence& seq, double t_us, const std::string& field);

// How one target is unrolled under `mode`; `notes` collects what the user should know.
FrameTarget::Method target_method(UnrollMode mode, bool moa, bool has_next, bool inside, int frame,
                                  std::map<std::string, int>& notes);

// The events window [lo, hi] (microseconds) every target of the frame needs (physics:
// [min(t*, S_y), max(t*, E_y)]; the model: its pairs' windows up to t* + exposure for ev3).
std::pair<double, double> frame_window(const SequenceFrame& f1, const SequenceFrame* f2, const std::vector<UnrollTarget>& ts,
                                       const std::vector<FrameTarget>& methods);

// The contrast threshold c (and the log offset eps) of the physics unroller, estimated from
// the frames and the events between them. For up to four pairs of consecutive frames (k, k+1),
// every pixel compares its linear luminance change log((L_b + eps) / (L_a + eps)) with its net
// event count N between the two rows' mid-exposures: ideally c * N. Noise is left out: a pixel
// needs |N| >= 2, at least 3 of its 8 neighbours with the same net sign (background activity and
// hot pixels are isolated), both frames neither black nor saturated, and a change beyond 3x the
// frames' noise (robust spread where no event fired) with the events' sign. c is the L1 fit
// through 0 (the |N|-weighted median of change / N); eps is the candidate (0 .. 0.05) whose fit
// leaves the least residual. Fewer than 200 such pixels, or no pair of consecutive frames: no
// estimate, a fixed 0.2 said in `source`, `is_default` and `warning`. A c outside 0.05 .. 1 comes
// with a warning (noise or a slow sensor may dominate).
// `image(k)`: frame k as BGR float32 in [0, 1]; `events(lo, hi)`: the events of [lo, hi] microseconds
// (UnrollJob passes its frame source, through its decode cache).
ContrastEstimate estimate_contrast(const std::vector<RowTiming>& timings, const std::vector<int>& frames, double gamma, int width,
                         int height, const std::function<cv::Mat(int)>& image,
                         const std::function<EventStream(double, double)>& events);

// The job's encodings and physics parameters (docs/model.md, "unroll"): frames go into a model with
// a known gamma in its encoding (v^to_model) and its results come back (v^(1/to_model)); the physics
// unroller decodes frames with the sequence's gamma, the physics-informed variant's physics input is
// computed on the model-encoded frame.
struct PhysicsPlan {
  double seq_gamma = 1.0;
  double to_model = 1.0;
  bool variant = false;        // the model is the physics-informed variant
  bool uses_physics = false;   // mode physics or the variant: `params` matter
  PhysicsUnrollParams params;
  std::string contrast_source = "given";
  std::string contrast_warning;  // the estimate's (ContrastEstimate::warning); empty: none
  // How c was obtained, for summary.json: given | model_metadata | event_count_fit | default.
  std::string contrast_method = "given";
  std::vector<std::pair<int, int>> contrast_pairs;  // event_count_fit (and default, if any): the frame pairs compared
  size_t contrast_pixels = 0;                       // event_count_fit: the pixels the fit used
  double frame_noise = -1, isolated_event_fraction = -1;  // the estimate's (ContrastEstimate), -1: none
};
// `contrast`: the user's (unset: the model's metadata, else `estimate(seq_gamma)`, called only then).
PhysicsPlan plan_physics(UnrollMode mode, const UnrollSession& session, double seq_gamma, std::optional<double> contrast,
                         const std::function<ContrastEstimate(double)>& estimate);

// The event gate radius the variant runs with, and why (summary.json). `automatic`: where the
// contrast estimate measured the recording's noise, a noisy recording (frame noise from
// kCleanFrameNoise or isolated events from kCleanIsolatedEvents) gets kNoisyGateRadius, a clean one
// (or one not measured) the model's own: on validation (docs/journal/training.md, "The event gate's radius")
// r = 2 beat r = 1 inside and between frames in every noisy group, and lost in every clean one.
// `model_radius` -1 (no gate): stays -1, and a fixed radius is refused (UsageError).
constexpr double kCleanFrameNoise = 0.01, kCleanIsolatedEvents = 0.05;
constexpr int kNoisyGateRadius = 2;
struct GateChoice {
  int radius = -1;
  std::string source;
};
GateChoice choose_gate_radius(const GateRadiusOption& o, int model_radius, const PhysicsPlan& physics);

// v^exponent (negative values to 0 first): a frame in another gamma encoding; exponent 1: as it is.
cv::Mat encode_for_model(const cv::Mat& image, double exponent);

// The way back from the model's encoding (v^(1/to_model)) for the results of model targets;
// physics targets were computed in the frames' own encoding and stay as they are.
void decode_model_results(std::vector<cv::Mat>& results, const std::vector<FrameTarget>& methods, double to_model);

}  // namespace vkunroll
