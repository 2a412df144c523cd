// The unroll job, once for every front end: a frame source in (a sequence folder or arrays), a
// result sink out (the CLI's output folder, Python's arrays), and between them the whole loop —
// the plan, each frame's image decoded once (and kept for the next frame), each frame's targets in
// one UnrollSession call, the gamma encoding into the model and back, and the report of what was done.
//
//   SequenceFrameSource source(seq);
//   UnrollJob job(options, session, source);   // plans (plan_job); errors name the option
//   job.run(sink);                              // sink.add() per GS frame
//   nlohmann::json what = job.report();
#pragma once
#include <functional>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/unroll/frame_source.hpp"
#include "vkunroll/host/unroll/session.hpp"
#include "vkunroll/host/unroll/unroll_options.hpp"
#include "vkunroll/host/unroll/unroll_plan.hpp"

namespace vkunroll {

// One GS frame, as the job hands it to a sink.
struct GsResult {
  int frame = 0;                   // the RS frame it was unrolled from
  const UnrollTarget* target = nullptr;
  FrameTarget::Method method = FrameTarget::Method::s;
  cv::Mat image;                   // BGR float32 in the source's encoding (not clamped)
  cv::Mat rs_input;                // the RS frame, decoded
  cv::Mat ground_truth;            // empty: none at this instant
  bool reused = false;             // the sink's own earlier image (ResultSink::reusable)
  std::string events_window;       // "partial": the source's window was cut short (--follow); empty: whole
  // The frame's unroll (all its computed targets): wall, GPU (timestamps) and device-wait ms.
  double frame_ms = 0, frame_gpu_ms = 0, frame_wait_ms = 0;
};

class ResultSink {
 public:
  virtual ~ResultSink() = default;
  // An image the sink already holds for this target (an earlier run's, under --resume): the job
  // then computes none and hands it back through add() with `reused` set.
  virtual std::optional<cv::Mat> reusable(int /*frame*/, const UnrollTarget& /*target*/) { return std::nullopt; }
  virtual void add(const GsResult& result) = 0;
  // After each frame's results: `done` of `total` GS frames filed.
  virtual void frame_finished(int /*frame*/, size_t /*done*/, size_t /*total*/) {}
};

// Everything a job decides before its first frame: what to unroll and how the session runs it.
struct JobPlan {
  UnrollMode mode = UnrollMode::automatic;  // auto without a model is physics
  std::vector<int> frames;
  std::map<int, std::vector<UnrollTarget>> targets;  // by frame
  size_t total_targets = 0;
  PhysicsPlan physics;       // encodings, physics parameters (the contrast estimated when asked)
  GateChoice gate;           // the variant's event gate radius (-1: none) and why
  TileOptions tiling;
  std::optional<bool> model_rgb;  // the model's channel order asked for (unset: the weights' metadata)
  double contrast_estimate_ms = 0;
  std::vector<std::string> notes;  // what planning left out and why (the report's notes)
};

// The plan from the options, the session's model (read only) and the source: errors name the
// option. It reads frames (through `image`, the job's decode cache) and events only for a contrast
// estimate; it changes nothing else.
JobPlan plan_job(const UnrollOptions& options, const UnrollSession& session, FrameSource& source,
                 const std::function<cv::Mat(int)>& image);
// Sets the session up for `plan`, in one place: channel order, physics parameters, gate, tiling.
void configure_session(UnrollSession& session, const JobPlan& plan);

// What the loop counted: reads, decodes, events.
struct UnrollJobCounters {
  size_t frame_decodes = 0;          // frame images decoded from the source (each frame once)
  size_t distinct_frames_decoded = 0;
  size_t ground_truth_decodes = 0;
  size_t frames_read = 0;            // frames whose event window was read
  uint64_t events_in_windows = 0;
  std::vector<std::pair<int, size_t>> events_per_frame;  // (frame, events in its window)
  std::vector<int> frames_without_events;
};

class UnrollJob {
 public:
  // Plans the job (plan_job), logs what it chose and configures `session` for it.
  UnrollJob(const UnrollOptions& options, UnrollSession& session, FrameSource& source);

  const JobPlan& plan() const { return plan_; }
  UnrollMode mode() const { return plan_.mode; }
  const std::vector<int>& frames() const { return plan_.frames; }
  const std::map<int, std::vector<UnrollTarget>>& targets() const { return plan_.targets; }
  size_t total_targets() const { return plan_.total_targets; }
  const PhysicsPlan& physics() const { return plan_.physics; }
  const TileOptions& tiling() const { return plan_.tiling; }
  const UnrollJobCounters& counters() const { return counters_; }

  // Every frame, in order, into `sink`.
  void run(ResultSink& sink);

  // Host time the caller spent for the job outside it (setup, the sequence's read): it joins the
  // report's per-stage breakdown.
  void add_stage_ms(Stage stage, double ms) { stage_ms_[stage] += ms; }

  // What the job did, as summary.json says it: mode, runs, physics, encoding, tiling, events,
  // reads, notes, warnings, ms per GS frame by stage and device traffic (per GS frame). `total_ms`:
  // the wall time the frames are charged (< 0: since the job was planned); what no stage timed is "other".
  nlohmann::json report(double total_ms = -1) const;

 private:
  struct DecodedFrame {
    cv::Mat image;      // the source's encoding
    cv::Mat for_model;  // v^to_model: the model's encoding
  };
  DecodedFrame& decoded(int k);
  const cv::Mat& model_encoded(DecodedFrame& f) const;
  void run_frame(int k, const std::vector<UnrollTarget>& ts, ResultSink& sink);
  std::vector<FrameTarget> methods_for(int k, const std::vector<UnrollTarget>& todo);
  nlohmann::json events_report(std::vector<std::string>& warnings) const;
  void add_time_breakdown(nlohmann::json& r, const SessionStats& st, double total_ms) const;

  const UnrollOptions& options_;
  UnrollSession& session_;
  FrameSource& source_;
  Stopwatch since_start_;  // the job's wall time, planning included
  std::map<int, DecodedFrame> decoded_;  // frames decoded and still needed (the next frame's f1)
  std::set<int> ever_decoded_;
  JobPlan plan_;
  std::map<std::string, int> notes_;
  std::map<Stage, double> stage_ms_{{Stage::read, 0}, {Stage::write, 0}};
  UnrollJobCounters counters_;
  DeviceTraffic traffic_before_, traffic_;
  SessionStats stats_before_;
  std::map<std::string, OpStats> ops_before_;  // the session's per-op profile when the run started (profile_ops)
  size_t done_ = 0;
};

}  // namespace vkunroll
