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

namespace vkunroll {

namespace fs = std::filesystem;

namespace {

struct UnrollTarget {
  Rational t_us;
  double tau = 0;
  std::string name;  // output file name override (ground-truth instants)
  int gt = -1;       // index into seq.ground_truth, -1: none
};

cv::Mat read_image(const std::string& path, int width, int height) {
  cv::Mat m = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (m.empty()) throw Error(path + ": cannot read the image");
  if (m.cols != width || m.rows != height)
    throw Error(path + ": image is " + std::to_string(m.cols) + "x" + std::to_string(m.rows) + ", the sensor is " +
                std::to_string(width) + "x" + std::to_string(height));
  if (m.channels() == 4) cv::cvtColor(m, m, cv::COLOR_BGRA2BGR);
  if (m.channels() == 1) cv::cvtColor(m, m, cv::COLOR_GRAY2BGR);
  if (!cv::checkRange(m, true, nullptr)) throw Error(path + ": image holds NaN or Inf values");
  return to_unit_float(m);  // [0,1] float, BGR
}

double frame_mid(const SequenceFrame& f) {
  return 0.5 * (f.timing.first_start().to_double() + f.timing.last_end().to_double());
}

// The chosen frame whose span holds t (else the one with the nearest middle).
int frame_for_time(const Sequence& seq, const std::vector<int>& frames, double t) {
  int best = frames.front();
  double best_d = 1e300;
  for (int k : frames) {
    const auto& f = seq.frames[k];
    const double s = f.timing.first_start().to_double(), e = f.timing.last_end().to_double();
    const double d = (t >= s && t <= e) ? std::abs(t - frame_mid(f)) - 1e12 : std::abs(t - frame_mid(f));
    if (d < best_d) best_d = d, best = k;
  }
  return best;
}

double read_meta_gamma(const Sequence& seq) {
  const fs::path meta = fs::path(seq.root) / "meta.json";
  if (seq.layout != SequenceLayout::generic || !fs::exists(meta)) return 1.0;
  try {
    std::ifstream in(meta);
    const auto j = nlohmann::json::parse(in);
    // The simulator records its output encoding under source.settings.gamma.
    if (j.contains("source") && j["source"].contains("settings") && j["source"]["settings"].contains("gamma"))
      return j["source"]["settings"]["gamma"].get<double>();
    if (j.contains("source") && j["source"].contains("gamma")) return j["source"]["gamma"].get<double>();
  } catch (const std::exception&) {
  }
  return 1.0;
}

// The events of [lo, hi] microseconds, read once per frame.
EventStream read_window(const Sequence& seq, double lo, double hi) {
  return seq.read_events(static_cast<int64_t>(std::floor(lo)), static_cast<int64_t>(std::ceil(hi)) + 1);
}

std::vector<int> chosen_frames(const Sequence& seq, const std::vector<int>& requested) {
  std::vector<int> frames = requested;
  if (frames.empty())
    for (int k = 0; k < static_cast<int>(seq.frames.size()); ++k) frames.push_back(k);
  for (int k : frames) seq.frame(k);  // throws naming the index and the count
  return frames;
}

// The targets of every chosen frame, refused where no events can exist (beyond a frame period
// outside the recording).
std::map<int, std::vector<UnrollTarget>> plan_targets(const Sequence& seq, const std::vector<int>& frames,
                                                      const TargetTimes& times, const std::string& where) {
  std::map<int, std::vector<UnrollTarget>> targets;
  auto gt_at = [&](const Rational& t) {
    for (size_t g = 0; g < seq.ground_truth.size(); ++g)
      if (std::abs((seq.ground_truth[g].t_us - t).to_double()) < 0.5) return static_cast<int>(g);
    return -1;
  };
  switch (times.kind) {
    case TargetTimes::Kind::ground_truth:
      if (seq.ground_truth.empty()) throw Error(where + ": --times gt, but the sequence has no ground-truth frames");
      for (size_t g = 0; g < seq.ground_truth.size(); ++g) {
        const auto& gt = seq.ground_truth[g];
        const int k = frame_for_time(seq, frames, gt.t_us.to_double());
        targets[k].push_back({gt.t_us, seq.frames[k].timing.tau_of(gt.t_us).to_double(),
                              fs::path(gt.image).filename().string(), static_cast<int>(g)});
      }
      break;
    case TargetTimes::Kind::absolute_us:
      for (const Rational& t : times.values) {
        const int k = frame_for_time(seq, frames, t.to_double());
        targets[k].push_back({t, seq.frames[k].timing.tau_of(t).to_double(), "", gt_at(t)});
      }
      break;
    case TargetTimes::Kind::normalized:
      for (int k : frames)
        for (const Rational& tau : times.values) {
          const Rational t = seq.frames[k].timing.target_time(tau);
          targets[k].push_back({t, tau.to_double(), "", gt_at(t)});
        }
      break;
  }
  const double rec_lo = seq.frames.front().timing.first_start().to_double(),
               rec_hi = seq.frames.back().timing.last_end().to_double();
  const double margin = seq.frames.size() > 1 ? frame_mid(seq.frames[1]) - frame_mid(seq.frames[0])
                                              : seq.frames[0].timing.last_end().to_double() - rec_lo;
  for (const auto& [k, ts] : targets)
    for (const auto& t : ts)
      if (t.t_us.to_double() < rec_lo - margin || t.t_us.to_double() > rec_hi + margin)
        throw Error("target t* = " + std::to_string(t.t_us.to_double()) + " us is outside the recording [" +
                    std::to_string(rec_lo) + ", " + std::to_string(rec_hi) + "] us by more than a frame period");
  return targets;
}

// How one target is unrolled under `mode`; `notes` collects what the user should know.
FrameTarget::Method target_method(UnrollMode mode, bool moa, bool has_next, bool inside, int frame,
                                  std::map<std::string, int>& notes) {
  using M = FrameTarget::Method;
  switch (mode) {
    case UnrollMode::physics: return M::physics;
    case UnrollMode::s: return M::s;
    case UnrollMode::automatic: return moa && has_next ? M::m : M::s;
    case UnrollMode::m:
      if (!has_next) notes["frame " + std::to_string(frame) + " is the last: SelfUnroll-S used (M needs the next frame)"]++;
      return has_next ? M::m : M::s;
    case UnrollMode::choose:
      if (inside) return M::s;
      if (moa && has_next) return M::m;
      notes[std::string("target outside its frame's exposure span: SelfUnroll-S used (") +
            (moa ? "M needs the next frame" : "the model has no MOA weights") + ")"]++;
      return M::s;
  }
  return M::s;
}

// The events window every target of the frame needs (physics: [min(t*, S_y), max(t*, E_y)];
// the model: its pairs' windows up to t* + exposure for ev3).
std::pair<double, double> frame_window(const SequenceFrame& f1, const SequenceFrame* f2, const std::vector<UnrollTarget>& ts,
                                       const std::vector<FrameTarget>& methods) {
  double lo = f1.timing.first_start().to_double(), hi = f1.timing.last_end().to_double();
  for (size_t j = 0; j < ts.size(); ++j) {
    const double t = ts[j].t_us.to_double();
    lo = std::min(lo, t);
    hi = std::max(hi, t + (methods[j].method == FrameTarget::Method::physics ? 0.0 : f1.timing.exposure.to_double()));
    if (methods[j].method == FrameTarget::Method::m && f2) {
      lo = std::min(lo, f2->timing.first_start().to_double());
      hi = std::max({hi, f2->timing.last_end().to_double(), t + f2->timing.exposure.to_double()});
    }
  }
  for (int y = 0; y < f1.timing.rows; ++y) lo = std::min(lo, f1.timing.start(y).to_double()), hi = std::max(hi, f1.timing.end(y).to_double());
  return {lo, hi};
}

// v^exponent (negative values to 0 first): a frame in another gamma encoding; exponent 1: as it is.
cv::Mat encode_for_model(const cv::Mat& image, double exponent) {
  if (std::abs(exponent - 1.0) < 1e-12) return image;
  cv::Mat v = cv::max(image, 0.0), out;
  cv::pow(v, exponent, out);
  return out;
}

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
  std::vector<std::pair<int, int>> pairs;
  for (int k : frames)
    if (k + 1 < static_cast<int>(seq.frames.size()) && pairs.size() < 3) pairs.push_back({k, k + 1});
  if (pairs.empty()) return 0.2;
  struct Pair {
    std::vector<float> rs1, rs2;
    PixelEventLists l1, l2;
  };
  std::vector<Pair> data;
  for (auto [a, b] : pairs) {
    const auto& fa = seq.frames[a];
    const auto& fb = seq.frames[b];
    const double t = 0.5 * (frame_mid(fa) + frame_mid(fb));
    Pair p;
    p.rs1 = image_planes(read_image(fa.image, seq.width, seq.height), false);
    p.rs2 = image_planes(read_image(fb.image, seq.width, seq.height), false);
    const EventStream ev = read_window(seq, std::min(fa.timing.first_start().to_double(), t),
                                       std::max(fb.timing.last_end().to_double(), t));
    p.l1 = gather_pixel_events(ev, t, fa.timing.start_times_us(), fa.timing.end_times_us(), 0, 0, seq.width, seq.height);
    p.l2 = gather_pixel_events(ev, t, fb.timing.start_times_us(), fb.timing.end_times_us(), 0, 0, seq.width, seq.height);
    data.push_back(std::move(p));
  }
  double best_c = 0.2, best_err = 1e300;
  for (double c = 0.05; c <= 0.6001; c += 0.025) {
    PhysicsUnrollParams prm;
    prm.contrast = static_cast<float>(c);
    prm.gamma = static_cast<float>(gamma);
    double err = 0;
    size_t n = 0;
    for (const auto& p : data) {
      const auto g1 = physics_unroll_ref(p.rs1, 3, p.l1, prm), g2 = physics_unroll_ref(p.rs2, 3, p.l2, prm);
      for (size_t i = 0; i < g1.size(); ++i) {
        err += std::abs(std::log(g1[i] + 0.01) - std::log(g2[i] + 0.01));
        n++;
      }
    }
    err /= std::max<size_t>(n, 1);
    if (err < best_err) best_err = err, best_c = c;
  }
  return best_c;
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

  // The sequence's encoding, and the model's: frames go into a model with a known gamma in its
  // encoding (v^(g_f/g_m)) and its results come back (docs/model.md, "unroll").
  const double seq_gamma = o.gamma ? *o.gamma : read_meta_gamma(seq);
  const std::optional<double> model_gamma = session.has_model() ? session.model_config().gamma : std::nullopt;
  const double to_model = model_gamma ? seq_gamma / *model_gamma : 1.0;
  const bool variant = session.has_model() && session.model_config().physics_input;
  PhysicsUnrollParams prm;
  std::string contrast_source = "given";
  if (mode == UnrollMode::physics || variant) {
    // --mode physics decodes the frames with the sequence's gamma; the variant's physics input is
    // computed on the model-encoded frame (docs/model.md).
    prm.gamma = static_cast<float>(mode == UnrollMode::physics ? seq_gamma : model_gamma.value_or(1.0));
    const std::string& from_model = variant ? session.model_config().physics_contrast : std::string("estimate");
    if (o.contrast) {
      prm.contrast = static_cast<float>(*o.contrast);
    } else if (from_model != "estimate") {
      prm.contrast = std::stof(from_model);  // validated when the weights were loaded
      contrast_source = "the model's metadata";
    } else {
      const auto t = Clock::now();
      prm.contrast = static_cast<float>(estimate_contrast(seq, frames, seq_gamma));
      stage_ms["contrast_estimate"] = ms_since(t);
      contrast_source = "estimated (temporal consistency of consecutive frames)";
    }
    if (!o.quiet)
      std::cerr << "unroll: " << (variant ? "physics input of the model" : "physics unroller") << ", contrast c = "
                << prm.contrast << " (" << contrast_source << "), gamma " << prm.gamma << "\n";
  }
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
    const cv::Mat rs_input = read_image(f1.image, seq.width, seq.height);
    in.rs1 = encode_for_model(rs_input, to_model);
    in.timing1 = f1.timing;
    if (f2) {
      in.rs2 = encode_for_model(read_image(f2->image, seq.width, seq.height), to_model);
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
        gt = read_image(gt_file, seq.width, seq.height);
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
