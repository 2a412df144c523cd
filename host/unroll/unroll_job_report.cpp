// UnrollJob::report(): what the job did, in summary.json's words (the CLI adds the files, the
// model file and the provenance; Python returns it as the result's stats).
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <map>
#include <string>

#include "vkunroll/host/model/backend.hpp"
#include "vkunroll/host/unroll/unroll_job.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll {

namespace {

nlohmann::json traffic_per_target(const DeviceTraffic& t, size_t targets) {
  const double n = static_cast<double>(std::max<size_t>(targets, 1));
  return {{"upload_bytes", double(t.upload_bytes) / n}, {"download_bytes", double(t.download_bytes) / n},
          {"submits", double(t.submits) / n}, {"waits", double(t.waits) / n}, {"dispatches", double(t.dispatches) / n},
          {"transfers", double(t.transfers) / n}};
}

nlohmann::json tiling_json(const UnrollOptions& o, const TileOptions& tiling, const SessionStats& st) {
  nlohmann::json j{{"tile", tiling.tile}, {"tile_used", st.tile_used}, {"halo", tiling.halo},
                   {"sparse", sparse_policy_name(o.sparse)}, {"sparse_threshold", o.sparse_threshold},
                   {"sparse_split", o.sparse_split},
                   {"tiles_per_target", st.tiles_per_target}, {"tiles", st.tiles}, {"tiles_run", st.tiles_run},
                   {"active_tile_fraction", st.tiles ? double(st.tiles_run) / double(st.tiles) : 0.0},
                   {"work_ratio", st.target_active_fraction.empty() ? 0.0 : st.work_pixels / double(st.target_active_fraction.size())}};
  if (!st.target_active_fraction.empty()) {
    double lo = 1, hi = 0, sum = 0;
    for (double a : st.target_active_fraction) lo = std::min(lo, a), hi = std::max(hi, a), sum += a;
    j["target_active_fraction"] = {{"min", lo}, {"mean", sum / double(st.target_active_fraction.size())}, {"max", hi}};
  }
  return j;
}

// The session's counters since the job began: a Python session serves many jobs. The tile
// shape of the last run (tile_used, tiles_per_target) is the session's as it is.
SessionStats since(const SessionStats& now, const SessionStats& before) {
  SessionStats d = now;
  d.runs_s -= before.runs_s, d.runs_m -= before.runs_m, d.runs_physics -= before.runs_physics;
  d.physics_on_cpu -= before.physics_on_cpu, d.host_path_targets -= before.host_path_targets;
  d.frames_unrolled -= before.frames_unrolled, d.image_uploads -= before.image_uploads;
  d.tiles -= before.tiles, d.tiles_run -= before.tiles_run, d.work_pixels -= before.work_pixels;
  d.target_active_fraction.erase(d.target_active_fraction.begin(),
                                 d.target_active_fraction.begin() + long(before.target_active_fraction.size()));
  for (auto& [name, ms] : d.ms) {
    const auto b = before.ms.find(name);
    if (b != before.ms.end()) ms -= b->second;
  }
  return d;
}

// When no frame window holds an event: where the file's events are, if it has any (regular files
// up to 256 MiB are read whole for this; a pipe or a larger file is not), against the frames' span.
std::string events_elsewhere(const Sequence& layout) {
  uint64_t bytes = 0;
  for (const auto& f : layout.event_files) {
    std::error_code ec;
    if (!std::filesystem::is_regular_file(f, ec)) return "";
    bytes += std::filesystem::file_size(f, ec);
  }
  if (layout.event_files.empty() || bytes > (uint64_t(256) << 20) || layout.frames.empty()) return "";
  const EventStream all = layout.read_events(-(int64_t(1) << 53), int64_t(1) << 53);
  if (all.empty()) return "";
  char text[320];
  std::snprintf(text, sizeof text,
                ", yet the file holds %zu event(s) at [%lld, %lld] us, outside the frames' span [%.0f, %.0f] us: check that "
                "the events are in microseconds on the frames' time base (ns, ms or an offset clock?)",
                all.size(), static_cast<long long>(all.t.front()), static_cast<long long>(all.t.back()),
                layout.frames.front().timing.first_start().to_double(), layout.frames.back().timing.last_end().to_double());
  return text;
}

std::string joined(const std::vector<std::string>& items) {
  std::string s;
  for (const auto& i : items) s += (s.empty() ? "" : ", ") + i;
  return s;
}

}  // namespace

// Host stages (device waits excluded), the wait, and "other" (what no stage timed: setup, the
// job's bookkeeping) add up to the frame time; GPU time, from timestamps, is split by the stage
// its commands were recorded in and lies inside the wait.
void UnrollJob::add_time_breakdown(nlohmann::json& r, const SessionStats& st, double total_ms) const {
  const double n = static_cast<double>(std::max<size_t>(plan_.total_targets, 1));
  std::map<std::string, double> host;
  for (const auto& [stage, v] : stage_ms_) host[stage_name(stage)] += v;
  for (const auto& [stage, v] : st.ms) host[stage_name(stage)] += v;
  double tracked = 0;
  for (const auto& [name, v] : host) tracked += v;
  host["other"] += std::max(0.0, total_ms - tracked);
  nlohmann::json ms = nlohmann::json::object();
  for (const auto& [name, v] : host) ms[name] = v / n;
  r["ms_per_gs_frame"] = ms;
  r["ms_per_gs_frame_total"] = std::max(total_ms, tracked) / n;
  r["device_traffic_per_gs_frame"] = traffic_per_target(traffic_, plan_.total_targets);
  // GPU times exist only where the device wrote timestamps: --profile or --trace (they cost time).
  const bool timed = session_.context() && session_.context()->timestamps();
  r["gpu_timestamps"] = timed;
  nlohmann::json gpu = nlohmann::json::object();
  for (const auto& [stage, v] : traffic_.gpu_ms_by_stage)
    if (v > 0) gpu[stage.empty() ? "other" : stage] = gpu.value(stage.empty() ? "other" : stage, 0.0) + v / n;
  r["gpu_ms_per_gs_frame_by_stage"] = timed ? gpu : nlohmann::json();
  r["gpu_ms_per_gs_frame"] = timed ? nlohmann::json(traffic_.gpu_ms / n) : nlohmann::json();
  if (const Profiler* p = session_.profiler()) {  // --profile: each kernel's GPU time and calls, this run's
    nlohmann::json ops = nlohmann::json::object();
    for (const auto& [op, s] : p->ops()) {
      const auto b = ops_before_.find(op);
      const double op_ms = s.total_ms - (b != ops_before_.end() ? b->second.total_ms : 0.0);
      const double calls = static_cast<double>(s.calls - (b != ops_before_.end() ? b->second.calls : 0));
      if (calls > 0) ops[op] = {{"ms", op_ms / n}, {"calls", calls / n}};
    }
    r["gpu_ms_per_gs_frame_by_op"] = ops;
  }
  const double wait = host.count("wait") ? host["wait"] : 0.0;
  // Inside the wait but not GPU work: submission, gaps between commands, the fence's latency.
  r["wait_not_gpu_ms_per_gs_frame"] = timed ? nlohmann::json(std::max(0.0, wait - traffic_.gpu_ms) / n) : nlohmann::json();
  r["host_ms_per_gs_frame"] = std::max(0.0, std::max(total_ms, tracked) - wait) / n;
  // Device time against wall time: on a GPU most of a frame should be device work (target >= 0.8).
  r["gpu_share_of_frame_time"] = !timed ? nlohmann::json() : nlohmann::json(total_ms > 0 ? traffic_.gpu_ms / std::max(total_ms, tracked) : 0.0);
}

nlohmann::json UnrollJob::events_report(std::vector<std::string>& warnings) const {
  const UnrollJobCounters& c = counters_;
  nlohmann::json per_frame = nlohmann::json::array();
  for (const auto& [k, n] : c.events_per_frame) per_frame.push_back({{"frame", k}, {"events", n}});
  nlohmann::json j = {{"in_frame_windows", c.events_in_windows}, {"frames_read", c.frames_read},
                      {"per_frame", per_frame}, {"frames_without_events", c.frames_without_events}};
  const Sequence& layout = source_.layout();
  if (layout.event_files.empty()) return j;  // arrays: no files to total
  const EventTotals totals = source_.event_totals();
  j["files"] = layout.event_files;
  j["file_totals"] = {{"records", totals.records}, {"valid", totals.valid}, {"dropped", totals.dropped()},
                      {"dropped_out_of_sensor", totals.dropped_out_of_sensor}, {"dropped_time_order", totals.dropped_time_order},
                      {"dropped_nan", totals.dropped_nan}, {"dropped_unknown_word", totals.dropped_unknown_word},
                      {"dropped_bad_polarity", totals.dropped_bad_polarity}, {"reordered", totals.reordered},
                      {"empty_files", totals.empty_files}, {"summary", totals.summary()}};
  const std::string files = joined(layout.event_files);
  if (totals.dropped()) {
    std::vector<std::string> kinds;
    for (const auto& [n, what] : {std::pair<uint64_t, const char*>{totals.dropped_out_of_sensor, "out of sensor"},
                                  {totals.dropped_time_order, "out of time order"}, {totals.dropped_nan, "NaN time"},
                                  {totals.dropped_unknown_word, "unknown word"}, {totals.dropped_bad_polarity, "bad polarity"}})
      if (n) kinds.push_back(std::to_string(n) + " " + what);
    warnings.push_back(opt("on_bad") + " drop: " + std::to_string(totals.dropped()) + " of " + std::to_string(totals.records) +
                       " event record(s) broke a rule and were dropped (" + joined(kinds) + ") in " + files);
  }
  if (totals.reordered)
    warnings.push_back(opt("on_bad") + " sort: " + std::to_string(totals.reordered) + " event record(s) were out of time order and were sorted");
  if (totals.empty_files) warnings.push_back(std::to_string(totals.empty_files) + " event file(s) are empty (0 bytes): " + files);
  if (!totals.size_disagreement.empty()) warnings.push_back(totals.size_disagreement);
  return j;
}

nlohmann::json UnrollJob::report(double total_ms) const {
  const SessionStats st = since(session_.stats(), stats_before_);
  const size_t n = plan_.total_targets;
  nlohmann::json r;
  r["mode"] = unroll_mode_name(plan_.mode);
  r["frames"] = plan_.frames.size();
  r["targets"] = n;
  r["runs"] = {{"s", st.runs_s}, {"m", st.runs_m}, {"physics", st.runs_physics}, {"physics_on_cpu", st.physics_on_cpu},
               {"host_path", st.host_path_targets}};
  if (plan_.physics.uses_physics) {
    r["physics"] = {{"contrast", plan_.physics.params.contrast}, {"contrast_source", plan_.physics.contrast_source},
                    {"contrast_method", plan_.physics.contrast_method},
                    {"log_offset", plan_.physics.params.log_offset},
                    {"gamma", plan_.physics.params.gamma}, {"role", plan_.physics.variant ? "the model's physics input" : "the unroller"}};
    if (!plan_.physics.contrast_pairs.empty()) r["physics"]["contrast_pairs"] = plan_.physics.contrast_pairs;
    if (plan_.physics.contrast_method == "event_count_fit") r["physics"]["contrast_pixels"] = plan_.physics.contrast_pixels;
    if (plan_.physics.frame_noise >= 0) r["physics"]["frame_noise"] = plan_.physics.frame_noise;
    if (plan_.physics.isolated_event_fraction >= 0) r["physics"]["isolated_event_fraction"] = plan_.physics.isolated_event_fraction;
    if (plan_.gate.radius >= 0) r["physics"]["gate_radius"] = {{"radius", plan_.gate.radius}, {"source", plan_.gate.source}};
  }
  if (session_.has_model()) {
    const auto& g = session_.model_config().gamma;
    r["encoding"] = {{"sequence_gamma", plan_.physics.seq_gamma}, {"model_gamma", g ? nlohmann::json(*g) : nlohmann::json()},
                     {"to_model", plan_.physics.to_model}};
    r["tiling"] = tiling_json(options_, plan_.tiling, st);
  }
  const UnrollJobCounters& c = counters_;
  r["reads"] = {{"frame_decodes", c.frame_decodes}, {"distinct_frames_decoded", c.distinct_frames_decoded},
                {"ground_truth_decodes", c.ground_truth_decodes},
                {"image_uploads", st.image_uploads}, {"frames_unrolled", st.frames_unrolled}};
  if (total_ms < 0) total_ms = since_start_.ms();
  add_time_breakdown(r, st, total_ms);

  std::map<std::string, int> notes = notes_;
  if (st.host_path_targets)
    notes[std::to_string(st.host_path_targets) + " target(s) too large for device-resident event tensors (one binding holds at most " +
          std::to_string(session_.binding_limit() >> 20) + " MiB): built, downloaded and tiled on the host"]++;
  if (session_.memory_forced_submits())
    notes["the device's memory forced " + std::to_string(session_.memory_forced_submits()) +
          " extra submission(s) inside frames (released buffers held more than the pool limit)"]++;
  r["notes"] = nlohmann::json::array();
  for (const auto& [text, count] : notes) r["notes"].push_back(text + (count > 1 ? " (x" + std::to_string(count) + ")" : ""));
  std::vector<std::string> warnings = source_.layout().warnings;  // meta.json: implausible values, unknown fields
  r["events"] = events_report(warnings);
  if (c.frames_read && c.events_in_windows == 0) {
    warnings.push_back("no events: the frame windows of " + std::to_string(c.frames_read) + " frame(s) hold no event (" +
                       joined(source_.layout().event_files) + ")" + events_elsewhere(source_.layout()) +
                       "; the GS frames are the RS input, unchanged");
  } else if (!c.frames_without_events.empty()) {
    std::string list;
    for (size_t i = 0; i < c.frames_without_events.size() && i < 20; ++i) list += (i ? ", " : "") + std::to_string(c.frames_without_events[i]);
    if (c.frames_without_events.size() > 20) list += ", ...";
    warnings.push_back(std::to_string(c.frames_without_events.size()) + " of " + std::to_string(c.frames_read) +
                       " frame(s) have no event in their window (frames " + list + "): their GS frames are the RS input");
  }
  if (!plan_.physics.contrast_warning.empty()) warnings.push_back(plan_.physics.contrast_warning);
  r["warnings"] = warnings;
  return r;
}

}  // namespace vkunroll
