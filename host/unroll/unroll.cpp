#include "vkunroll/host/unroll/unroll.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "vkunroll/base/stopwatch.hpp"
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

// summary.json's job fields (everything but the per-frame records and metrics UnrollOutput adds).
nlohmann::json job_summary(const UnrollOptions& o, const Sequence& seq, UnrollMode mode, const UnrollSession& session,
                           const TileOptions& tile_options, const PhysicsUnrollParams& prm, const std::string& contrast_source,
                           double seq_gamma,
                           const std::map<std::string, double>& stage_ms, double total_ms, size_t frames, size_t total_targets,
                           const DeviceTraffic& traffic, std::map<std::string, int> notes) {
  const SessionStats& st = session.stats();
  nlohmann::json extra;
  extra["sequence"] = {{"path", o.sequence}, {"layout", sequence_layout_name(seq.layout)},
                       {"width", seq.width}, {"height", seq.height}, {"frames_in_sequence", seq.frames.size()},
                       {"notes", seq.notes}};
  extra["mode"] = unroll_mode_name(mode);
  extra["runs"] = {{"s", st.runs_s}, {"m", st.runs_m}, {"physics", st.runs_physics}, {"physics_on_cpu", st.physics_on_cpu},
                   {"host_path", st.host_path_targets}};
  if (session.has_model())
    extra["model"] = {{"path", o.session.model_path}, {"config", session.model_config().summary()},
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
  extra["frames"] = frames;
  extra["targets"] = total_targets;
  extra["backend"] = backend_kind_name(session.backend_kind());
  extra["precision"] = precision_name(o.session.precision);
  if (session.context()) extra["device"] = session.context()->info().name;
  nlohmann::json per_frame;
  for (const auto& [name, ms] : stage_ms) per_frame[name] = total_targets ? ms / total_targets : 0.0;
  extra["ms_per_gs_frame"] = per_frame;
  extra["ms_per_gs_frame_total"] = total_targets ? total_ms / total_targets : 0.0;
  extra["device_traffic_per_gs_frame"] = traffic_json(traffic, total_targets);
  // Device time against wall time: on a GPU most of a frame should be device work.
  extra["gpu_ms_per_gs_frame"] = total_targets ? traffic.gpu_ms / total_targets : 0.0;
  extra["memory_forced_submits"] = session.memory_forced_submits();
  extra["peak_device_bytes"] = session.peak_device_bytes();
  extra["notes"] = nlohmann::json::array();
  if (st.host_path_targets)
    notes[std::to_string(st.host_path_targets) + " target(s) too large for device-resident event tensors (one binding " +
          "holds at most " + std::to_string(session.backend().max_buffer_bytes() >> 20) +
          " MiB): built, downloaded and tiled on the host"]++;
  if (session.memory_forced_submits())
    notes["the device's memory forced " + std::to_string(session.memory_forced_submits()) +
          " extra submission(s) inside frames (released buffers held more than the pool limit)"]++;
  for (const auto& [n, c] : notes) extra["notes"].push_back(n + (c > 1 ? " (x" + std::to_string(c) + ")" : ""));
  return extra;
}

}  // namespace

double estimate_contrast(const Sequence& seq, const std::vector<int>& frames, double gamma) {
  std::vector<RowTiming> timings;
  for (const SequenceFrame& f : seq.frames) timings.push_back(f.timing);
  return estimate_contrast(
      timings, frames, gamma, seq.width, seq.height,
      [&](int k) { return read_frame_image(seq.frames[k].image, seq.width, seq.height); },
      [&](double lo, double hi) { return read_window(seq, lo, hi); });
}

nlohmann::json run_unroll(const UnrollOptions& o) {
  const auto t_start = Clock::now();
  validate_unroll_options(o);  // a refused option does not wait for the sequence to load
  const UnrollMode mode = o.mode == UnrollMode::automatic && o.session.model_path.empty() ? UnrollMode::physics : o.mode;
  SessionOptions so = o.session;
  so.announce = so.announce && !o.quiet;
  if (mode == UnrollMode::physics) so.model_path.clear();
  UnrollSession session(so);  // the model and the device before the sequence: their errors come first
  if (mode == UnrollMode::m && !session.model_config().moa)
    throw Error(o.session.model_path + ": the model has no MOA weights (attfusion_net), so it runs SelfUnroll-S only; use --mode s");
  if (o.channel_order != ChannelOrder::model) session.set_model_rgb(o.channel_order == ChannelOrder::rgb);
  std::map<std::string, double> stage_ms{{"read", 0}, {"write", 0}};
  auto t_read = Clock::now();
  const Sequence seq = load_sequence(o.sequence, o.sequence_options);
  stage_ms["read"] += ms_since(t_read);
  if (seq.frames.empty()) throw Error(o.sequence + ": the sequence has no frames");
  const std::vector<int> frames = chosen_frames(seq, o.frames);

  const std::map<int, std::vector<UnrollTarget>> targets = plan_targets(seq, frames, o.times, o.sequence);
  size_t total_targets = 0;
  for (const auto& [k, ts] : targets) total_targets += ts.size();

  const double seq_gamma = o.gamma ? *o.gamma : read_meta_gamma(seq);
  const PhysicsPlan physics = plan_physics(mode, session, seq_gamma, o.contrast, [&](double gamma) {
    const auto t = Clock::now();
    const double c = estimate_contrast(seq, frames, gamma);
    stage_ms["contrast_estimate"] = ms_since(t);
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

  UnrollOutputOptions uo = o.output;
  if (seq.frames.size() > 1) {
    const double period = frame_mid(seq.frames[1]) - frame_mid(seq.frames[0]);
    const double per_frame = static_cast<double>(total_targets) / frames.size();
    if (period > 0) uo.video_fps = std::clamp(per_frame * 1e6 / period / 10.0, 1.0, 60.0);  // 10x slow motion
  }
  UnrollOutput output(o.out_dir, uo);
  Progress progress("unroll", total_targets, Progress::automatic(o.quiet));
  std::map<std::string, int> notes;
  const DeviceTraffic traffic_before = session.traffic();
  size_t done = 0;
  for (int k : frames) {
    auto it = targets.find(k);
    if (it == targets.end()) continue;
    const auto& ts = it->second;
    const SequenceFrame& f1 = seq.frames[k];
    const bool has_next = k + 1 < static_cast<int>(seq.frames.size());
    const bool moa = session.has_model() && session.model_config().moa;
    std::vector<FrameTarget> methods;
    for (const auto& t : ts) {
      const double tv = t.t_us.to_double();
      const bool inside = tv >= f1.timing.first_start().to_double() && tv <= f1.timing.last_end().to_double();
      methods.push_back({t.t_us, target_method(mode, moa, has_next, inside, k, notes)});
    }
    const bool any_m = std::any_of(methods.begin(), methods.end(), [](const FrameTarget& t) { return t.method == FrameTarget::Method::m; });
    const SequenceFrame* f2 = any_m ? &seq.frames[k + 1] : nullptr;
    t_read = Clock::now();
    FrameInput in;
    const cv::Mat rs_input = read_frame_image(f1.image, seq.width, seq.height);
    in.rs1 = encode_for_model(rs_input, to_model);
    in.timing1 = f1.timing;
    if (f2) {
      in.rs2 = encode_for_model(read_frame_image(f2->image, seq.width, seq.height), to_model);
      in.timing2 = f2->timing;
    }
    const auto [lo, hi] = frame_window(f1, f2, ts, methods);
    const EventStream ev = read_window(seq, lo, hi);
    in.events = &ev;
    stage_ms["read"] += ms_since(t_read);
    std::vector<cv::Mat> results = session.unroll(in, methods);
    for (size_t j = 0; j < results.size(); ++j)
      if (methods[j].method != FrameTarget::Method::physics) results[j] = encode_for_model(results[j], 1.0 / to_model);
    const auto t_write = Clock::now();
    for (size_t j = 0; j < ts.size(); ++j) {
      cv::Mat gt;
      std::string gt_file;
      if (ts[j].gt >= 0) {
        gt_file = seq.ground_truth[ts[j].gt].image;
        gt = read_frame_image(gt_file, seq.width, seq.height);
      }
      output.add(k, ts[j].t_us.to_double(), ts[j].tau, results[j], rs_input, gt, gt_file, ts[j].name);
      progress.update(++done, "frame " + std::to_string(k));
    }
    stage_ms["write"] += ms_since(t_write);
  }
  progress.finish();
  const DeviceTraffic traffic = session.traffic() - traffic_before;
  const SessionStats& st = session.stats();
  for (const auto& [name, ms] : st.ms) stage_ms[name] += ms;

  const nlohmann::json extra = job_summary(o, seq, mode, session, tile_options, prm, contrast_source, seq_gamma, stage_ms,
                                           ms_since(t_start), frames.size(), total_targets, traffic, notes);
  const double total_ms = extra["ms_per_gs_frame_total"].get<double>() * double(total_targets);
  nlohmann::json summary = output.finish(extra);

  if (!o.quiet) {
    const double n = static_cast<double>(std::max<size_t>(total_targets, 1));
    std::cerr << "unroll: " << frames.size() << " frame(s), " << total_targets << " GS frame(s), mode " << unroll_mode_name(mode)
              << ", " << total_ms / n << " ms per GS frame (";
    bool first = true;
    for (const auto& [name, ms] : stage_ms) std::cerr << (first ? "" : ", ") << name << " " << ms / n, first = false;
    std::cerr << "; GPU " << traffic.gpu_ms / n << "), per GS frame " << traffic.upload_bytes / n / 1e6 << " MB up, "
              << traffic.download_bytes / n / 1e6 << " MB down, " << traffic.submits / n << " submits; peak device memory "
              << (session.peak_device_bytes() >> 20) << " MiB\n";
    if (summary.contains("metrics"))
      std::cerr << "unroll: vs ground truth (" << summary["metrics"]["count"] << " frames): PSNR "
                << summary["metrics"]["mean_psnr"] << " dB, SSIM " << summary["metrics"]["mean_ssim"]
                << "; RS input: PSNR " << summary["metrics"]["rs_mean_psnr"] << " dB, SSIM "
                << summary["metrics"]["rs_mean_ssim"] << "\n";
    std::cerr << "unroll: wrote " << o.out_dir << "\n";
  }
  return summary;
}

}  // namespace vkunroll
