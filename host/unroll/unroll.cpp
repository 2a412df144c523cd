#include "vkunroll/host/unroll/unroll.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <optional>

#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/unroll/provenance.hpp"
#include "vkunroll/host/unroll/sha256.hpp"
#include "vkunroll/host/unroll/image_planes.hpp"
#include "vkunroll/host/unroll/metrics.hpp"
#include "vkunroll/host/unroll/progress.hpp"
#include "vkunroll/host/model/backend.hpp"
#include "vkunroll/host/unroll/session.hpp"
#include "vkunroll/host/unroll/unroll_output.hpp"
#include "vkunroll/host/unroll/unroll_plan.hpp"

namespace vkunroll {

namespace fs = std::filesystem;

namespace {

nlohmann::json traffic_json(const DeviceTraffic& t, size_t targets) {
  const double n = static_cast<double>(std::max<size_t>(targets, 1));
  return {{"upload_bytes", double(t.upload_bytes) / n}, {"download_bytes", double(t.download_bytes) / n},
          {"submits", double(t.submits) / n}};
}

// The frame loop's state: where results go, what was counted.
struct FrameLoop {
  UnrollSession& session;
  UnrollOutput& output;
  Progress& progress;
  UnrollMode mode;
  bool resume = false;
  std::map<std::string, double> stage_ms{{"read", 0}, {"write", 0}};
  std::map<std::string, int> notes;
  size_t done = 0;
  // Events read per frame window (frames whose targets were all reused read none).
  nlohmann::json events_per_frame = nlohmann::json::array();
  uint64_t events_in_windows = 0;
  std::vector<int> frames_without_events;
  size_t frames_read = 0;
  // The frames' encoding into the model's (v^to_model, docs/model.md "unroll"); 1: as they are.
  double to_model = 1.0;
};

// Unrolls frame k's targets (those a resume cannot reuse) and files every result.
void unroll_frame(const Sequence& seq, int k, const std::vector<UnrollTarget>& ts, FrameLoop& L) {
  const SequenceFrame& f1 = seq.frames[k];
  const bool has_next = k + 1 < static_cast<int>(seq.frames.size());
  const bool moa = L.session.has_model() && L.session.model_config().moa;
  std::vector<std::optional<cv::Mat>> reused(ts.size());
  std::vector<GsFrameRecord> reused_record(ts.size());
  std::vector<UnrollTarget> todo;
  std::vector<FrameTarget> methods;
  for (size_t j = 0; j < ts.size(); ++j) {
    if (L.resume) reused[j] = L.output.find_reusable(k, ts[j].t_us.str(), ts[j].name, &reused_record[j]);
    if (reused[j]) continue;
    const double tv = ts[j].t_us.to_double();
    const bool inside = tv >= f1.timing.first_start().to_double() && tv <= f1.timing.last_end().to_double();
    todo.push_back(ts[j]);
    methods.push_back({ts[j].t_us, target_method(L.mode, moa, has_next, inside, k, L.notes)});
  }
  auto t_read = Clock::now();
  FrameInput in;
  const cv::Mat rs_input = read_frame_image(f1.image, seq.width, seq.height);
  in.rs1 = encode_for_model(rs_input, L.to_model);
  in.timing1 = f1.timing;
  std::vector<cv::Mat> results;
  if (!todo.empty()) {
    const bool any_m = std::any_of(methods.begin(), methods.end(), [](const FrameTarget& t) { return t.method == FrameTarget::Method::m; });
    const SequenceFrame* f2 = any_m ? &seq.frames[k + 1] : nullptr;
    if (f2) {
      in.rs2 = encode_for_model(read_frame_image(f2->image, seq.width, seq.height), L.to_model);
      in.timing2 = f2->timing;
    }
    const auto [lo, hi] = frame_window(f1, f2, todo, methods);
    const EventStream ev = read_window(seq, lo, hi);
    in.events = &ev;
    L.stage_ms["read"] += ms_since(t_read);
    L.events_per_frame.push_back({{"frame", k}, {"events", ev.size()}});
    L.events_in_windows += ev.size();
    L.frames_read++;
    if (ev.empty()) L.frames_without_events.push_back(k);
    results = L.session.unroll(in, methods);
    for (size_t j = 0; j < results.size(); ++j)
      if (methods[j].method != FrameTarget::Method::physics) results[j] = encode_for_model(results[j], 1.0 / L.to_model);
  } else {
    L.stage_ms["read"] += ms_since(t_read);
  }
  const auto t_write = Clock::now();
  size_t next = 0;
  for (size_t j = 0; j < ts.size(); ++j) {
    cv::Mat gt;
    std::string gt_file;
    if (ts[j].gt >= 0) {
      gt_file = seq.ground_truth[ts[j].gt].image;
      gt = read_frame_image(gt_file, seq.width, seq.height);
    }
    if (reused[j]) {
      L.output.add_reused(reused_record[j], *reused[j], rs_input, gt);
    } else {
      L.output.add(k, ts[j].t_us.to_double(), ts[j].t_us.str(), ts[j].tau, results[next++], rs_input, gt, gt_file, ts[j].name);
    }
    L.progress.update(++L.done, "frame " + std::to_string(k) + (reused[j] ? " (reused)" : ""));
  }
  L.stage_ms["write"] += ms_since(t_write);
}

// What decides the pixels of a GS frame: frames written under another key are not reused.
std::string resume_key(const UnrollOptions& o, UnrollMode mode, const UnrollSession& session,
                       const PhysicsUnrollParams& prm, const std::string& model_sha256) {
  const BuildInfo b = build_info();
  nlohmann::json opts = unroll_options_json(o);
  for (const char* k : {"out", "frames", "times", "video", "fps", "existing_output", "device", "cpu_threads", "model"}) opts.erase(k);
  nlohmann::json key = {{"vkunroll", b.version}, {"git", b.git_revision}, {"options", opts},
                        {"sequence", fs::absolute(o.sequence).lexically_normal().string()},
                        {"mode", unroll_mode_name(mode)}, {"model_sha256", model_sha256}};
  if (mode == UnrollMode::physics) key["physics"] = {{"contrast", prm.contrast}, {"gamma", prm.gamma}};
  if (session.has_model()) key["rgb"] = session.model_rgb();
  return sha256_hex(key.dump());
}

// Threads this process runs with: OpenCV's pool and lavapipe's rasterizer workers ("llvmpipe-N").
nlohmann::json thread_report(const UnrollOptions& o) {
  int lavapipe = 0;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator("/proc/self/task", ec)) {
    std::ifstream comm(e.path() / "comm");
    std::string name;
    std::getline(comm, name);
    lavapipe += name.rfind("llvmpipe-", 0) == 0;
  }
  const char* lp = std::getenv("LP_NUM_THREADS");
  return {{"requested", o.session.cpu_threads}, {"opencv", cv::getNumThreads()},
          {"lavapipe_workers", lavapipe}, {"LP_NUM_THREADS", lp ? nlohmann::json(lp) : nlohmann::json()}};
}

// The events every frame window held (Sequence::event_totals(): each record counted once over
// the windows), and the warnings they call for.
nlohmann::json events_report(const FrameLoop& L, const Sequence& seq, std::vector<std::string>& warnings) {
  const EventTotals totals = seq.event_totals();
  nlohmann::json j = {{"in_frame_windows", L.events_in_windows}, {"frames_read", L.frames_read},
                      {"per_frame", L.events_per_frame}, {"frames_without_events", L.frames_without_events},
                      {"files", seq.event_files},
                      {"file_totals", {{"records", totals.records}, {"valid", totals.valid}, {"dropped", totals.dropped()},
                                       {"dropped_out_of_sensor", totals.dropped_out_of_sensor},
                                       {"dropped_time_order", totals.dropped_time_order}, {"dropped_nan", totals.dropped_nan},
                                       {"dropped_unknown_word", totals.dropped_unknown_word},
                                       {"dropped_bad_polarity", totals.dropped_bad_polarity},
                                       {"reordered", totals.reordered}, {"empty_files", totals.empty_files},
                                       {"summary", totals.summary()}}}};
  std::string files;
  for (const auto& f : seq.event_files) files += (files.empty() ? "" : ", ") + f;
  if (totals.dropped()) {
    std::string kinds;
    for (const auto& [n, what] : {std::pair<uint64_t, const char*>{totals.dropped_out_of_sensor, "out of sensor"},
                                  {totals.dropped_time_order, "out of time order"}, {totals.dropped_nan, "NaN time"},
                                  {totals.dropped_unknown_word, "unknown word"}, {totals.dropped_bad_polarity, "bad polarity"}})
      if (n) kinds += (kinds.empty() ? "" : ", ") + std::to_string(n) + " " + what;
    warnings.push_back("--on-bad drop: " + std::to_string(totals.dropped()) + " of " + std::to_string(totals.records) +
                       " event record(s) broke a rule and were dropped (" + kinds + ") in " + files);
  }
  if (totals.reordered)
    warnings.push_back("--on-bad sort: " + std::to_string(totals.reordered) + " event record(s) were out of time order and were sorted");
  if (totals.empty_files)
    warnings.push_back(std::to_string(totals.empty_files) + " event file(s) are empty (0 bytes): " + files);
  if (L.frames_read && L.events_in_windows == 0) {
    warnings.push_back("no events: the frame windows of " + std::to_string(L.frames_read) + " frame(s) hold no event (" +
                       files + "); the GS frames are the RS input, unchanged");
  } else if (!L.frames_without_events.empty()) {
    std::string list;
    for (size_t i = 0; i < L.frames_without_events.size() && i < 20; ++i) list += (i ? ", " : "") + std::to_string(L.frames_without_events[i]);
    if (L.frames_without_events.size() > 20) list += ", ...";
    warnings.push_back(std::to_string(L.frames_without_events.size()) + " of " + std::to_string(L.frames_read) +
                       " frame(s) have no event in their window (frames " + list + "): their GS frames are the RS input");
  }
  return j;
}

}  // namespace

ContrastEstimate estimate_contrast(const Sequence& seq, const std::vector<int>& frames, double gamma) {
  std::vector<RowTiming> timings;
  for (const SequenceFrame& f : seq.frames) timings.push_back(f.timing);
  return estimate_contrast(
      timings, frames, gamma, seq.width, seq.height,
      [&](int k) { return read_frame_image(seq.frames[k].image, seq.width, seq.height); },
      [&](double lo, double hi) { return read_window(seq, lo, hi); });
}

namespace {

// Everything summary.json says beyond the frames and outputs (UnrollOutput::finish adds those).
nlohmann::json summary_extra(const UnrollOptions& o, UnrollMode mode, const UnrollSession& session, const Sequence& seq,
                             const std::vector<int>& frames, size_t total_targets, const PhysicsUnrollParams& prm,
                             const std::string& contrast_source, double seq_gamma, const TileOptions& tile_options,
                             const std::string& model_sha256) {
  const SessionStats& st = session.stats();
  nlohmann::json extra;
  extra["sequence"] = {{"path", o.sequence}, {"layout", sequence_layout_name(seq.layout)},
                       {"width", seq.width}, {"height", seq.height}, {"frames_in_sequence", seq.frames.size()},
                       {"notes", seq.notes}};
  extra["mode"] = unroll_mode_name(mode);
  extra["runs"] = {{"s", st.runs_s}, {"m", st.runs_m}, {"physics", st.runs_physics}, {"physics_on_cpu", st.physics_on_cpu},
                   {"host_path", st.host_path_targets}};
  if (session.has_model())
    extra["model"] = {{"path", o.session.model_path}, {"sha256", model_sha256},
                      {"bytes", fs::file_size(o.session.model_path)}, {"config", session.model_config().summary()},
                      {"channel_order", session.model_rgb() ? "rgb" : "bgr"}};
  const bool variant = session.has_model() && session.model_config().physics_input;
  if (mode == UnrollMode::physics || variant)
    extra["physics"] = {{"contrast", prm.contrast}, {"contrast_source", contrast_source}, {"gamma", prm.gamma},
                        {"role", variant ? "the model's physics input" : "the unroller"}};
  if (session.has_model())
    extra["encoding"] = {{"sequence_gamma", seq_gamma},
                         {"model_gamma", session.model_config().gamma ? nlohmann::json(*session.model_config().gamma) : nlohmann::json()}};
  if (session.has_model()) {
    nlohmann::json tj{{"tile", tile_options.tile}, {"tile_used", st.tile_used}, {"halo", tile_options.halo},
                      {"sparse", sparse_policy_name(o.sparse)}, {"sparse_threshold", o.sparse_threshold},
                      {"tiles_per_target", st.tiles_per_target}, {"tiles", st.tiles}, {"tiles_run", st.tiles_run},
                      {"active_tile_fraction", st.tiles ? double(st.tiles_run) / double(st.tiles) : 0.0},
                      {"work_ratio", st.target_active_fraction.empty() ? 0.0 : st.work_pixels / double(st.target_active_fraction.size())}};
    if (!st.target_active_fraction.empty()) {
      double lo = 1, hi = 0, sum = 0;
      for (double a : st.target_active_fraction) lo = std::min(lo, a), hi = std::max(hi, a), sum += a;
      tj["target_active_fraction"] = {{"min", lo}, {"mean", sum / st.target_active_fraction.size()}, {"max", hi}};
    }
    extra["tiling"] = tj;
  }
  extra["frames"] = frames.size();
  extra["targets"] = total_targets;
  extra["backend"] = backend_kind_name(session.backend_kind());
  extra["precision"] = precision_name(o.session.precision);
  if (session.context()) extra["device"] = session.context()->info().name;
  const BuildInfo b = build_info();
  extra["provenance"] = {{"vkunroll_version", b.version},
                         {"git_revision", b.git_revision},
                         {"git_dirty", b.git_dirty < 0 ? nlohmann::json() : nlohmann::json(b.git_dirty == 1)},
                         {"command_line", o.command_line},
                         {"working_directory", fs::current_path().string()},
                         {"host", host_name()},
                         {"options", unroll_options_json(o)},
                         {"backend", backend_kind_name(session.backend_kind())},
                         {"device", session.context() ? device_json(session.context()->info()) : nlohmann::json()},
                         {"precision", precision_name(o.session.precision)},
                         {"threads", thread_report(o)}};
  if (session.has_model())
    extra["provenance"]["model"] = {{"path", fs::absolute(o.session.model_path).string()}, {"sha256", model_sha256},
                                    {"config", session.model_config().summary()}};
  return extra;
}

void report(const UnrollOptions& o, UnrollMode mode, const nlohmann::json& summary, const FrameLoop& L,
            const UnrollSession& session, const DeviceTraffic& traffic, double total_ms, size_t frames, size_t total_targets) {
  const double n = static_cast<double>(std::max<size_t>(total_targets, 1));
  std::cerr << "unroll: " << frames << " frame(s), " << total_targets << " GS frame(s), mode " << unroll_mode_name(mode)
            << ", " << total_ms / n << " ms per GS frame (";
  bool first = true;
  for (const auto& [name, ms] : L.stage_ms) std::cerr << (first ? "" : ", ") << name << " " << ms / n, first = false;
  std::cerr << "; GPU " << traffic.gpu_ms / n << "), per GS frame " << traffic.upload_bytes / n / 1e6 << " MB up, "
            << traffic.download_bytes / n / 1e6 << " MB down, " << traffic.submits / n << " submits; peak device memory "
            << (session.peak_device_bytes() >> 20) << " MiB\n";
  if (summary.contains("resume"))
    std::cerr << "unroll: resume: " << summary["resume"]["reused"] << " GS frame(s) reused, " << summary["resume"]["computed"]
              << " computed\n";
  if (summary.contains("metrics"))
    std::cerr << "unroll: vs ground truth (" << summary["metrics"]["count"] << " frames): PSNR "
              << summary["metrics"]["mean_psnr"] << " dB, SSIM " << summary["metrics"]["mean_ssim"]
              << "; RS input: PSNR " << summary["metrics"]["rs_mean_psnr"] << " dB, SSIM "
              << summary["metrics"]["rs_mean_ssim"] << "\n";
  std::cerr << "unroll: wrote " << o.out_dir << "\n";
}

// Targets planned from the options; a time the rationals cannot hold names the option.
std::map<int, std::vector<UnrollTarget>> planned_targets(const Sequence& seq, const std::vector<int>& frames,
                                                         const UnrollOptions& o) {
  try {
    return plan_targets(seq, frames, o.times, o.sequence);
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::unspecified || std::string(e.what()).rfind("Rational", 0) != 0) throw;
    const char* opt = o.times.kind == TargetTimes::Kind::absolute_us ? "--times-us"
                      : o.times.kind == TargetTimes::Kind::normalized ? "--times" : "--times gt";
    throw UsageError(std::string(opt) + ": a target instant is out of the range of exact time arithmetic (" + e.what() +
                     "); targets must lie within +-2^53 us of the recording");
  }
}

}  // namespace

nlohmann::json run_unroll(const UnrollOptions& o) {
  const auto t_start = Clock::now();
  validate_unroll_options(o);  // a refused option does not wait for the sequence to load
  check_unroll_inputs(o);
  const UnrollMode mode = o.mode == UnrollMode::automatic && o.session.model_path.empty() ? UnrollMode::physics : o.mode;
  SessionOptions so = o.session;
  so.announce = so.announce && !o.quiet;
  if (mode == UnrollMode::physics) so.model_path.clear();
  UnrollSession session(so);  // the model and the device before the sequence: their errors come first
  if (mode == UnrollMode::m && !session.model_config().moa)
    throw UsageError(o.session.model_path + ": the model has no MOA weights (attfusion_net), so it runs SelfUnroll-S only; use --mode s");
  if (o.channel_order != ChannelOrder::model) session.set_model_rgb(o.channel_order == ChannelOrder::rgb);
  auto t_read = Clock::now();
  const Sequence seq = load_sequence(o.sequence, o.sequence_options);
  const double load_ms = ms_since(t_read);
  if (seq.frames.empty()) throw DataError(o.sequence + ": the sequence has no frames");
  std::vector<std::pair<std::string, std::string>> event_files;  // meta.json may name files outside the folder
  for (const auto& f : seq.event_files) event_files.emplace_back("event file", f);
  check_output_apart(o.out_dir, "--out", event_files);
  const std::vector<int> frames = chosen_frames(seq, o.frames);
  const std::map<int, std::vector<UnrollTarget>> targets = planned_targets(seq, frames, o);
  size_t total_targets = 0;
  for (const auto& [k, ts] : targets) total_targets += ts.size();

  // The sequence's encoding, and the model's: frames go into a model with a known gamma in its
  // encoding (v^(g_f/g_m)) and its results come back (docs/model.md, "unroll").
  const double seq_gamma = o.gamma ? *o.gamma : read_meta_gamma(seq);
  double contrast_ms = -1;
  const PhysicsPlan physics = plan_physics(mode, session, seq_gamma, o.contrast, [&](double gamma) {
    const auto t = Clock::now();
    ContrastEstimate c = estimate_contrast(seq, frames, gamma);
    contrast_ms = ms_since(t);
    return c;
  });
  const double to_model = physics.to_model;
  const PhysicsUnrollParams& prm = physics.params;
  const std::string& contrast_source = physics.contrast_source;
  if (physics.uses_physics && !o.quiet)
    std::cerr << "unroll: " << (physics.variant ? "physics input of the model" : "physics unroller") << ", contrast c = "
              << prm.contrast << " (" << contrast_source << "), gamma " << prm.gamma << "\n";
  session.set_physics(prm);
  TileOptions tile_options;
  tile_options.sparse = o.sparse;
  const bool sparse_on = o.sparse != SparsePolicy::off;
  tile_options.tile = o.tile > 0 ? o.tile : (sparse_on ? kTileAlign : 0);
  tile_options.halo = o.halo >= 0 ? o.halo : (sparse_on ? kTileAlign : 2 * kTileAlign);
  tile_options.threshold = o.sparse_threshold;
  session.set_tiling(tile_options);

  const std::string model_sha = session.has_model() ? sha256_file(o.session.model_path) : std::string();
  UnrollOutputOptions uo = o.output;
  if (!uo.video_fps && seq.frames.size() > 1) {
    const double period = frame_mid(seq.frames[1]) - frame_mid(seq.frames[0]);
    const double per_frame = static_cast<double>(total_targets) / frames.size();
    if (period > 0) uo.video_fps = std::clamp(per_frame * 1e6 / period / 10.0, 1.0, 60.0);  // 10x slow motion
  }
  uo.resume_key = resume_key(o, mode, session, prm, model_sha);
  UnrollOutput output(o.out_dir, uo);
  Progress progress("unroll", total_targets, Progress::automatic(o.quiet));
  FrameLoop loop{session, output, progress, mode, o.output.existing == ExistingOutput::resume};
  loop.to_model = to_model;
  loop.stage_ms["read"] += load_ms;
  if (contrast_ms >= 0) loop.stage_ms["contrast_estimate"] = contrast_ms;
  const DeviceTraffic traffic_before = session.traffic();
  for (int k : frames) {
    auto it = targets.find(k);
    if (it != targets.end()) unroll_frame(seq, k, it->second, loop);
  }
  progress.finish();
  const DeviceTraffic traffic = session.traffic() - traffic_before;
  for (const auto& [name, ms] : session.stats().ms) loop.stage_ms[name] += ms;

  const double total_ms = ms_since(t_start);
  nlohmann::json extra = summary_extra(o, mode, session, seq, frames, total_targets, prm, contrast_source, seq_gamma,
                                     tile_options, model_sha);
  if (extra.contains("model") && !o.model_source.empty()) extra["model"]["source"] = o.model_source;
  nlohmann::json per_frame;
  for (const auto& [name, ms] : loop.stage_ms) per_frame[name] = total_targets ? ms / total_targets : 0.0;
  extra["ms_per_gs_frame"] = per_frame;
  extra["ms_per_gs_frame_total"] = total_targets ? total_ms / total_targets : 0.0;
  extra["device_traffic_per_gs_frame"] = traffic_json(traffic, total_targets);
  // Device time against wall time: on a GPU most of a frame should be device work.
  extra["gpu_ms_per_gs_frame"] = total_targets ? traffic.gpu_ms / total_targets : 0.0;
  // The rest of the frame is host work and waits; the target on a GPU is a device share >= 0.8.
  extra["host_ms_per_gs_frame"] = total_targets ? std::max(0.0, total_ms - traffic.gpu_ms) / total_targets : 0.0;
  extra["gpu_share_of_frame_time"] = total_ms > 0 ? traffic.gpu_ms / total_ms : 0.0;
  extra["conv_algorithms"] = session.conv_choice_report();
  extra["memory_forced_submits"] = session.memory_forced_submits();
  extra["peak_device_bytes"] = session.peak_device_bytes();
  const SessionStats& st = session.stats();
  if (st.host_path_targets)
    loop.notes[std::to_string(st.host_path_targets) + " target(s) too large for device-resident event tensors (one binding " +
               "holds at most " + std::to_string(session.backend().max_buffer_bytes() >> 20) +
               " MiB): built, downloaded and tiled on the host"]++;
  if (session.memory_forced_submits())
    loop.notes["the device's memory forced " + std::to_string(session.memory_forced_submits()) +
               " extra submission(s) inside frames (released buffers held more than the pool limit)"]++;
  extra["notes"] = nlohmann::json::array();
  for (const auto& [n, c] : loop.notes) extra["notes"].push_back(n + (c > 1 ? " (x" + std::to_string(c) + ")" : ""));
  std::vector<std::string> warnings;
  extra["events"] = events_report(loop, seq, warnings);
  if (output.replaces_existing())
    extra["notes"].push_back("replaced the earlier output in " + output.dir().string() + " (" +
                             existing_output_name(o.output.existing) + ")");
  if (!physics.contrast_warning.empty()) warnings.push_back(physics.contrast_warning);
  extra["warnings"] = warnings;
  extra["provenance"]["finished_utc"] = utc_now();
  for (const auto& w : warnings) std::cerr << "unroll: warning: " << w << "\n";  // even under --quiet
  nlohmann::json summary = output.finish(extra);
  if (!o.quiet) report(o, mode, summary, loop, session, traffic, total_ms, frames.size(), total_targets);
  return summary;
}

}  // namespace vkunroll
