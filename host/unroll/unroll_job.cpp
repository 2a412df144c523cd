#include "vkunroll/host/unroll/unroll_job.hpp"

#include <algorithm>
#include <sstream>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/log.hpp"
#include "vkunroll/host/unroll/device_stage.hpp"

namespace vkunroll {

namespace {

// Targets planned from the options; a time the rationals cannot hold names the option.
std::map<int, std::vector<UnrollTarget>> planned_targets(const Sequence& layout, const std::vector<int>& frames,
                                                         const TargetTimes& times, const std::string& where,
                                                         std::vector<std::string>* notes) {
  try {
    return plan_targets(layout, frames, times, where, notes);
  } catch (const TimeRangeError& e) {
    const std::string field = times.kind == TargetTimes::Kind::absolute_us ? "times_us" : "times";
    const std::string rule = "targets must lie within +-2^53 us of the recording";
    throw OptionError(field, "", rule,
                      opt(field) + (times.kind == TargetTimes::Kind::ground_truth ? " gt" : "") +
                          ": a target instant is out of the range of exact time arithmetic (" + e.text() + "); " + rule);
  }
}

// The tiling the options ask for; unset values take the defaults of docs/tiling.md.
TileOptions tile_options(const UnrollOptions& o) {
  TileOptions t;
  t.sparse = o.sparse;
  const bool sparse_on = o.sparse != SparsePolicy::off;
  t.tile = o.tile > 0 ? o.tile : (sparse_on ? kTileAlign : 0);
  t.halo = o.halo >= 0 ? o.halo : (sparse_on ? kTileAlign : 2 * kTileAlign);
  t.threshold = o.sparse_threshold;
  t.split_groups = o.sparse_split;
  return t;
}

bool is_m(const FrameTarget& t) { return t.method == FrameTarget::Method::m; }

}  // namespace

JobPlan plan_job(const UnrollOptions& o, const UnrollSession& session, FrameSource& source,
                 const std::function<cv::Mat(int)>& image) {
  JobPlan p;
  p.mode = o.mode == UnrollMode::automatic && !session.has_model() ? UnrollMode::physics : o.mode;
  if (p.mode != UnrollMode::physics && !session.has_model())
    throw OptionError("mode", unroll_mode_name(p.mode), "needs a model",
                      opt("mode") + " " + unroll_mode_name(p.mode) + " needs a model (" + opt("model") + " FILE.safetensors)");
  if (p.mode == UnrollMode::m && !session.model_config().moa)
    throw OptionError("mode", "m", "a model with MOA weights",
                      o.session.model_path + ": the model has no MOA weights (attfusion_net), so it runs SelfUnroll-S only; use " +
                          opt("mode") + " s");
  if (o.channel_order != ChannelOrder::model) p.model_rgb = o.channel_order == ChannelOrder::rgb;
  const Sequence& layout = source.layout();
  if (layout.frames.empty()) throw DataError(o.sequence + ": the sequence has no frames");
  p.frames = chosen_frames(layout, o.frames);
  p.targets = planned_targets(layout, p.frames, o.times, o.sequence, &p.notes);
  for (const auto& [k, ts] : p.targets) p.total_targets += ts.size();
  // The frames' encoding and the model's: frames go into a model with a known gamma as
  // v^(g_f/g_m) and its results come back (docs/model.md, "unroll").
  const double seq_gamma = o.gamma ? *o.gamma : source.recorded_gamma();
  std::vector<RowTiming> timings;
  for (const SequenceFrame& f : layout.frames) timings.push_back(f.timing);
  p.physics = plan_physics(p.mode, session, seq_gamma, o.contrast, [&](double gamma) {
    const Stopwatch t;
    ContrastEstimate c = estimate_contrast(timings, p.frames, gamma, layout.width, layout.height, image,
                                           [&](double lo, double hi) { return source.events(lo, hi); });
    p.contrast_estimate_ms = t.ms();
    return c;
  });
  // Without a model (or a gate) the radius is -1, and a given one is refused by choose_gate_radius.
  p.gate = choose_gate_radius(o.gate_radius, session.metadata_gate_radius(), p.physics);
  p.tiling = tile_options(o);
  return p;
}

void configure_session(UnrollSession& session, const JobPlan& plan) {
  if (plan.model_rgb) session.set_model_rgb(*plan.model_rgb);
  session.set_physics(plan.physics.params);
  if (plan.gate.radius >= 0) session.set_gate_radius(plan.gate.radius);
  session.set_tiling(plan.tiling);
}

UnrollJob::UnrollJob(const UnrollOptions& o, UnrollSession& session, FrameSource& source)
    : options_(o), session_(session), source_(source) {
  plan_ = plan_job(o, session, source, [&](int k) { return decoded(k).image; });
  for (const std::string& n : plan_.notes) notes_[n]++;
  if (plan_.contrast_estimate_ms > 0) stage_ms_[Stage::contrast_estimate] = plan_.contrast_estimate_ms;
  const PhysicsPlan& physics = plan_.physics;
  if (physics.uses_physics && !o.quiet) {
    std::ostringstream line;
    line << "unroll: " << (physics.variant ? "physics input of the model" : "physics unroller") << ", contrast c = "
         << physics.params.contrast << " (" << physics.contrast_source << "), log offset " << physics.params.log_offset
         << ", gamma " << physics.params.gamma;
    log_info(line.str());
  }
  // A default or an implausible contrast is a warning, said even when quiet (summary.json has it too).
  if (!physics.contrast_warning.empty()) log_warning("unroll: warning: " + physics.contrast_warning);
  if (plan_.gate.radius >= 0 && !o.quiet)
    log_info("unroll: event gate radius " + std::to_string(plan_.gate.radius) + " (" + plan_.gate.source + ")");
  configure_session(session, plan_);
}

UnrollJob::DecodedFrame& UnrollJob::decoded(int k) {
  auto it = decoded_.find(k);
  if (it != decoded_.end()) return it->second;
  DecodedFrame f;
  f.image = source_.decode_frame(k);
  counters_.frame_decodes++;
  ever_decoded_.insert(k);
  counters_.distinct_frames_decoded = ever_decoded_.size();
  return decoded_.emplace(k, std::move(f)).first->second;
}

const cv::Mat& UnrollJob::model_encoded(DecodedFrame& f) const {
  // Encoded on first use in the loop: the contrast estimate decodes frames before to_model is known.
  if (f.for_model.empty()) f.for_model = encode_for_model(f.image, plan_.physics.to_model);
  return f.for_model;
}

std::vector<FrameTarget> UnrollJob::methods_for(int k, const std::vector<UnrollTarget>& todo) {
  const Sequence& layout = source_.layout();
  const RowTiming& timing = layout.frames[size_t(k)].timing;
  const bool has_next = k + 1 < static_cast<int>(layout.frames.size());
  const bool moa = session_.has_model() && session_.model_config().moa;
  std::vector<FrameTarget> methods;
  for (const UnrollTarget& t : todo) {
    const double tv = t.t_us.to_double();
    const bool inside = tv >= timing.first_start().to_double() && tv <= timing.last_end().to_double();
    methods.push_back({t.t_us, target_method(plan_.mode, moa, has_next, inside, k, notes_)});
  }
  return methods;
}

void UnrollJob::run(ResultSink& sink) {
  traffic_before_ = session_.traffic();
  stats_before_ = session_.stats();
  if (const Profiler* p = session_.profiler()) ops_before_ = p->ops();
  try {
    for (int k : plan_.frames) {
      auto it = plan_.targets.find(k);
      if (it != plan_.targets.end()) run_frame(k, it->second, sink);
    }
    source_.read_events_to_end();  // the whole stream's rules (time order), not only the windows'
  } catch (...) {
    traffic_ = session_.traffic() - traffic_before_;  // a stopped stream (--follow) still reports its frames
    throw;
  }
  traffic_ = session_.traffic() - traffic_before_;
}

void UnrollJob::run_frame(int k, const std::vector<UnrollTarget>& ts, ResultSink& sink) {
  const Sequence& layout = source_.layout();
  std::vector<std::optional<cv::Mat>> reused(ts.size());
  std::vector<UnrollTarget> todo;
  for (size_t j = 0; j < ts.size(); ++j) {
    reused[j] = sink.reusable(k, ts[j]);
    if (!reused[j]) todo.push_back(ts[j]);
  }
  const std::vector<FrameTarget> methods = methods_for(k, todo);
  const Stopwatch t_read;
  DecodedFrame& f1 = decoded(k);
  const cv::Mat rs_input = f1.image;  // the header outlives the cache entry erased below (the pixels are shared)
  std::vector<cv::Mat> results;
  struct {
    double ms = 0, gpu_ms = 0, wait_ms = 0;
  } frame_time;
  if (!todo.empty()) {
    FrameInput in;
    in.rs1 = model_encoded(f1);
    in.timing1 = layout.frames[size_t(k)].timing;
    const bool any_m = std::any_of(methods.begin(), methods.end(), is_m);
    const SequenceFrame* f2 = any_m ? &layout.frames[size_t(k) + 1] : nullptr;
    if (f2) in.rs2 = model_encoded(decoded(k + 1)), in.timing2 = f2->timing;
    const auto [lo, hi] = frame_window(layout.frames[size_t(k)], f2, todo, methods);
    const EventStream ev = source_.events(lo, hi);
    in.events = &ev;
    stage_ms_[Stage::read] += t_read.ms();
    counters_.events_per_frame.push_back({k, ev.size()});
    counters_.events_in_windows += ev.size();
    counters_.frames_read++;
    if (ev.empty()) counters_.frames_without_events.push_back(k);
    const DeviceTraffic before = session_.traffic();
    const Stopwatch t_unroll;
    results = in_device_stage("frame " + std::to_string(k) + ", unrolling " + std::to_string(methods.size()) + " target(s)",
                              [&] { return session_.unroll(in, methods); });
    const DeviceTraffic d = session_.traffic() - before;
    frame_time = {t_unroll.ms(), d.gpu_ms, d.wait_ms};
    decode_model_results(results, methods, plan_.physics.to_model);
  } else {
    stage_ms_[Stage::read] += t_read.ms();
  }
  // Frames at or before k are past: only the next frame (k + 1, as f1) is used again.
  decoded_.erase(decoded_.begin(), decoded_.upper_bound(k));
  const Stopwatch t_write;
  size_t next = 0;
  for (size_t j = 0; j < ts.size(); ++j) {
    GsResult r;
    r.frame = k;
    r.target = &ts[j];
    r.rs_input = rs_input;
    r.reused = reused[j].has_value();
    r.frame_ms = frame_time.ms, r.frame_gpu_ms = frame_time.gpu_ms, r.frame_wait_ms = frame_time.wait_ms;
    if (ts[j].gt >= 0) r.ground_truth = source_.decode_ground_truth(ts[j].gt), counters_.ground_truth_decodes++;
    if (r.reused) {
      r.image = *reused[j];
    } else {
      r.method = methods[next].method;
      r.image = results[next++];
    }
    sink.add(r);
  }
  done_ += ts.size();
  stage_ms_[Stage::write] += t_write.ms();
  sink.frame_finished(k, done_, plan_.total_targets);
}

}  // namespace vkunroll
