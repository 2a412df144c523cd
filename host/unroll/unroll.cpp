#include "vkunroll/host/unroll/unroll.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "vkunroll/base/int_math.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/model/backend_cpu.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/unroll/metrics.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/unroll/progress.hpp"
#include "vkunroll/host/model/tiling.hpp"
#include "vkunroll/host/unroll/unroll_output.hpp"
#include "vkunroll/host/unroll/value_list.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/kernels/event_tensor.hpp"
#include "vkunroll/kernels/physics_unroll.hpp"
#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/context.hpp"

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

// [3, H, W] planes in the model's channel order from a BGR float image.
void append_planes(const cv::Mat& bgr, bool rgb, std::vector<float>& dst) {
  std::vector<cv::Mat> ch;
  cv::split(bgr, ch);
  if (rgb) std::swap(ch[0], ch[2]);
  for (const auto& c : ch) {
    cv::Mat cont = c.isContinuous() ? c : c.clone();
    dst.insert(dst.end(), cont.ptr<float>(), cont.ptr<float>() + cont.total());
  }
}

cv::Mat planes_to_bgr(const float* p, int h, int w, bool rgb) {
  std::vector<cv::Mat> ch;
  for (int c = 0; c < 3; ++c) ch.push_back(cv::Mat(h, w, CV_32F, const_cast<float*>(p + static_cast<size_t>(c) * h * w)).clone());
  if (rgb) std::swap(ch[0], ch[2]);
  cv::Mat out;
  cv::merge(ch, out);
  return out;
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

std::vector<double> row_starts(const RowTiming& t) {
  std::vector<double> v(t.rows);
  for (int y = 0; y < t.rows; ++y) v[y] = t.start(y).to_double();
  return v;
}
std::vector<double> row_ends(const RowTiming& t) {
  std::vector<double> v(t.rows);
  for (int y = 0; y < t.rows; ++y) v[y] = t.end(y).to_double();
  return v;
}

std::vector<float> bgr_planes(const cv::Mat& bgr) {
  std::vector<float> v;
  append_planes(bgr, false, v);
  return v;
}

// Physics result for one frame and one target (CPU reference or GPU). `ev` holds at least the
// events of [min(t*, first row start), max(t*, last row end)].
std::vector<float> physics_planes(const Sequence& seq, const EventStream& ev, const std::vector<double>& starts,
                                  const std::vector<double>& ends, const std::vector<float>& rs_planes,
                                  double t_star, const PhysicsUnrollParams& prm, Context* ctx) {
  const PixelEventLists lists = gather_pixel_events(ev, t_star, starts, ends, 0, 0, seq.width, seq.height);
  // The CPU reference also takes what the GPU kernel cannot (a pixel with tens of thousands of events).
  if (!ctx || !PhysicsUnroll::fits(lists)) return physics_unroll_ref(rs_planes, 3, lists, prm);
  check_physics_image(rs_planes, 3, lists);  // the CPU path checks inside; the GPU one cannot cheaply
  Tensor rs_t(*ctx, {1, 3, seq.height, seq.width}), out_t(*ctx, {1, 3, seq.height, seq.width});
  rs_t.upload(rs_planes);
  PhysicsUnroll op(*ctx, lists);
  CommandStream cs(*ctx);
  op.record(cs, rs_t, out_t, prm);
  cs.submit_and_wait();
  return out_t.download<float>();
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
    p.rs1 = bgr_planes(read_image(fa.image, seq.width, seq.height));
    p.rs2 = bgr_planes(read_image(fb.image, seq.width, seq.height));
    const double lo = std::min(fa.timing.first_start().to_double(), t), hi = std::max(fb.timing.last_end().to_double(), t);
    const EventStream ev = seq.read_events(static_cast<int64_t>(std::floor(lo)), static_cast<int64_t>(std::ceil(hi)) + 1);
    p.l1 = gather_pixel_events(ev, t, row_starts(fa.timing), row_ends(fa.timing), 0, 0, seq.width, seq.height);
    p.l2 = gather_pixel_events(ev, t, row_starts(fb.timing), row_ends(fb.timing), 0, 0, seq.width, seq.height);
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
  std::map<std::string, double> stage_ms{{"read", 0}, {"event_tensors", 0}, {"eic", 0}, {"moa", 0}, {"physics", 0}, {"write", 0}};

  // Options first: a refused option should not wait for the sequence to load.
  if (o.precision != "fp32")
    throw Error("--precision '" + o.precision + "': fp32 is the only precision (the kernels compute in fp32)");

  auto t_read = Clock::now();
  const Sequence seq = load_sequence(o.sequence, o.sequence_options);
  stage_ms["read"] += ms_since(t_read);
  if (seq.frames.empty()) throw Error(o.sequence + ": the sequence has no frames");
  std::vector<int> frames;
  if (o.frames.empty()) {
    for (int k = 0; k < static_cast<int>(seq.frames.size()); ++k) frames.push_back(k);
  } else {
    frames = parse_frame_list(o.frames, "--frames");
    for (int k : frames) seq.frame(k);  // throws naming the index and the count
  }

  // Model or physics.
  std::string mode = o.mode;
  if (mode != "auto" && mode != "s" && mode != "m" && mode != "physics" && mode != "choose")
    throw Error("--mode '" + mode + "' (expected s, m, choose, physics or auto)");
  const SparsePolicy sparse_policy = parse_sparse_policy(o.sparse, "--sparse");  // fail before any work
  if (o.tile < 0 || o.tile % kTileAlign)
    throw Error("--tile " + std::to_string(o.tile) + ": expected 0 (automatic) or a positive multiple of " + std::to_string(kTileAlign));
  if (o.halo < -1 || (o.halo >= 0 && o.halo % kTileAlign))
    throw Error("--halo " + std::to_string(o.halo) + ": expected -1 (automatic) or a non-negative multiple of " + std::to_string(kTileAlign));
  if (!(o.sparse_threshold >= 0))
    throw Error("--sparse-threshold " + std::to_string(o.sparse_threshold) + ": expected >= 0 events per pixel");
  if (o.backend != "vulkan" && o.backend != "cpu") throw Error("--backend '" + o.backend + "' (expected vulkan or cpu)");
  if (mode == "auto" && o.model_path.empty()) mode = "physics";
  if (mode == "choose" && o.model_path.empty()) throw Error("--mode choose needs --model FILE.safetensors");
  if (mode != "physics" && o.model_path.empty()) throw Error("--mode " + mode + " needs --model FILE.safetensors");
  std::optional<Weights> weights;
  if (mode != "physics") {
    weights = load_weights(o.model_path);
    if (mode == "m" && !weights->config.moa)
      throw Error(o.model_path + ": the model has no MOA weights (attfusion_net), so it runs SelfUnroll-S only; use --mode s");
  }
  const bool rgb = o.channel_order.empty() ? (!weights || weights->config.channel_order != "bgr") : o.channel_order == "rgb";
  if (!o.channel_order.empty() && o.channel_order != "rgb" && o.channel_order != "bgr")
    throw Error("--channel-order '" + o.channel_order + "' (expected rgb or bgr)");

  std::unique_ptr<Context> ctx;
  std::unique_ptr<Backend> backend;
  std::unique_ptr<Model> model;
  if (o.backend == "vulkan") {
    ContextOptions co;
    co.device = o.device;
    co.announce = !o.quiet;
    ctx = std::make_unique<Context>(co);
  }
  if (weights) {
    if (ctx)
      backend = std::make_unique<VulkanBackend>(*ctx);
    else
      backend = std::make_unique<CpuBackend>();
    model = std::make_unique<Model>(*backend, *weights);
  }

  // Targets per frame.
  std::map<int, std::vector<UnrollTarget>> targets;
  auto gt_at = [&](const Rational& t) {
    for (size_t g = 0; g < seq.ground_truth.size(); ++g)
      if (std::abs((seq.ground_truth[g].t_us - t).to_double()) < 0.5) return static_cast<int>(g);
    return -1;
  };
  if (o.times == "gt" && o.times_us.empty()) {
    if (seq.ground_truth.empty()) throw Error(o.sequence + ": --times gt, but the sequence has no ground-truth frames");
    for (size_t g = 0; g < seq.ground_truth.size(); ++g) {
      const auto& gt = seq.ground_truth[g];
      const int k = frame_for_time(seq, frames, gt.t_us.to_double());
      targets[k].push_back({gt.t_us, seq.frames[k].timing.tau_of(gt.t_us).to_double(),
                            fs::path(gt.image).filename().string(), static_cast<int>(g)});
    }
  } else if (!o.times_us.empty()) {
    for (const Rational& t : parse_value_list(o.times_us, "--times-us")) {
      const int k = frame_for_time(seq, frames, t.to_double());
      targets[k].push_back({t, seq.frames[k].timing.tau_of(t).to_double(), "", gt_at(t)});
    }
  } else {
    const auto taus = parse_value_list(o.times, "--times");
    for (int k : frames)
      for (const Rational& tau : taus) {
        const Rational t = seq.frames[k].timing.target_time(tau);
        targets[k].push_back({t, tau.to_double(), "", gt_at(t)});
      }
  }
  // Targets must lie where events exist: beyond one frame period outside the recording is refused.
  const double rec_lo = seq.frames.front().timing.first_start().to_double(),
               rec_hi = seq.frames.back().timing.last_end().to_double();
  const double margin = seq.frames.size() > 1 ? frame_mid(seq.frames[1]) - frame_mid(seq.frames[0])
                                              : seq.frames[0].timing.last_end().to_double() - rec_lo;
  for (const auto& [k, ts] : targets)
    for (const auto& t : ts)
      if (t.t_us.to_double() < rec_lo - margin || t.t_us.to_double() > rec_hi + margin)
        throw Error("target t* = " + std::to_string(t.t_us.to_double()) + " us is outside the recording [" +
                    std::to_string(rec_lo) + ", " + std::to_string(rec_hi) + "] us by more than a frame period");

  size_t total_targets = 0;
  for (const auto& [k, ts] : targets) total_targets += ts.size();

  // Physics parameters.
  PhysicsUnrollParams prm;
  std::string contrast_source = "given";
  if (mode == "physics") {
    prm.gamma = static_cast<float>(o.gamma ? *o.gamma : read_meta_gamma(seq));
    if (o.contrast) {
      prm.contrast = static_cast<float>(*o.contrast);
    } else {
      const auto t = Clock::now();
      prm.contrast = static_cast<float>(estimate_contrast(seq, frames, prm.gamma));
      stage_ms["physics"] += ms_since(t);
      contrast_source = "estimated (temporal consistency of consecutive frames)";
    }
    if (!o.quiet)
      std::cerr << "unroll: physics unroller, contrast c = " << prm.contrast << " (" << contrast_source
                << "), gamma " << prm.gamma << "\n";
  }

  UnrollOutputOptions uo;
  uo.write_video = o.video;
  uo.bit_depth = o.bit_depth;
  if (seq.frames.size() > 1) {
    const double period = frame_mid(seq.frames[1]) - frame_mid(seq.frames[0]);
    const double per_frame = static_cast<double>(total_targets) / frames.size();
    if (period > 0) uo.video_fps = std::clamp(per_frame * 1e6 / period / 10.0, 1.0, 60.0);  // 10x slow motion
  }
  UnrollOutput output(o.out_dir, uo);
  Progress progress("unroll", total_targets, Progress::automatic(o.quiet));
  std::optional<EventTensorBuilder> builder_gpu;
  if (ctx) builder_gpu.emplace(*ctx);
  size_t done = 0, runs_s = 0, runs_m = 0, runs_physics = 0;
  // Tiling and sparse execution of the model (host/model/tiling.hpp).
  TileOptions tile_options;
  tile_options.sparse = sparse_policy;
  const bool sparse_on = tile_options.sparse != SparsePolicy::off;
  tile_options.tile = o.tile > 0 ? o.tile : (sparse_on ? kTileAlign : 0);
  tile_options.halo = o.halo >= 0 ? o.halo : (sparse_on ? kTileAlign : 2 * kTileAlign);
  tile_options.threshold = o.sparse_threshold;
  int64_t tiles_total = 0, tiles_run = 0, tile_used = 0, tiles_per_target = 0;
  double work_pixels = 0;  // sum over targets of run_tiled's work_ratio
  std::vector<double> target_active;
  std::map<std::string, int> notes;

  for (int k : frames) {
    auto it = targets.find(k);
    if (it == targets.end()) continue;
    const auto& ts = it->second;
    const SequenceFrame& f1 = seq.frames[k];
    t_read = Clock::now();
    const cv::Mat rs1 = read_image(f1.image, seq.width, seq.height);
    stage_ms["read"] += ms_since(t_read);
    std::vector<cv::Mat> results(ts.size());

    if (mode == "physics") {
      // The events of every target of this frame, read once.
      const auto starts = row_starts(f1.timing), ends = row_ends(f1.timing);
      double lo = f1.timing.first_start().to_double(), hi = f1.timing.last_end().to_double();
      for (const auto& t : ts) lo = std::min(lo, t.t_us.to_double()), hi = std::max(hi, t.t_us.to_double());
      for (size_t y = 0; y < starts.size(); ++y) lo = std::min(lo, starts[y]), hi = std::max(hi, ends[y]);
      t_read = Clock::now();
      const EventStream ev = seq.read_events(static_cast<int64_t>(std::floor(lo)), static_cast<int64_t>(std::ceil(hi)) + 1);
      stage_ms["read"] += ms_since(t_read);
      const auto t = Clock::now();
      const auto rs_planes = bgr_planes(rs1);
      for (size_t j = 0; j < ts.size(); ++j) {
        const auto gs = physics_planes(seq, ev, starts, ends, rs_planes, ts[j].t_us.to_double(), prm, ctx.get());
        results[j] = planes_to_bgr(gs.data(), seq.height, seq.width, /*rgb=*/false);
      }
      stage_ms["physics"] += ms_since(t);
      runs_physics += ts.size();
    } else {
      const bool has_next = k + 1 < static_cast<int>(seq.frames.size());
      const bool moa = weights->config.moa;
      const double span_lo = f1.timing.first_start().to_double(), span_hi = f1.timing.last_end().to_double();
      // Per target: SelfUnroll-M or -S. choose: S inside the frame's exposure span, M between frames.
      std::vector<size_t> s_targets, m_targets;
      for (size_t j = 0; j < ts.size(); ++j) {
        bool use_m = (mode == "m" || mode == "auto") && moa && has_next;
        if (mode == "choose") {
          const double t = ts[j].t_us.to_double();
          const bool inside = t >= span_lo && t <= span_hi;
          use_m = !inside && moa && has_next;
          if (!inside && !use_m)
            notes[std::string("target outside its frame's exposure span: SelfUnroll-S used (") +
                  (moa ? "M needs the next frame" : "the model has no MOA weights") + ")"]++;
        }
        (use_m ? m_targets : s_targets).push_back(j);
      }
      if (mode == "m" && !has_next) notes["frame " + std::to_string(k) + " is the last: SelfUnroll-S used (M needs the next frame)"]++;
      cv::Mat rs2;
      if (!m_targets.empty()) {
        t_read = Clock::now();
        rs2 = read_image(seq.frames[k + 1].image, seq.width, seq.height);
        stage_ms["read"] += ms_since(t_read);
      }
      // Pairs per group: S: (k, t_j); M: (k, t_j), (k+1, t_j) interleaved.
      std::vector<EventTensorPair> group_pairs[2];
      for (const bool use_m : {false, true})
        for (size_t j : use_m ? m_targets : s_targets) {
          group_pairs[use_m].push_back({f1.timing, ts[j].t_us, std::nullopt});
          if (use_m) group_pairs[use_m].push_back({seq.frames[k + 1].timing, ts[j].t_us, std::nullopt});
        }
      // The frame's events are read once, over the window every pair of both groups needs.
      double lo = 1e300, hi = -1e300;
      for (const auto& pairs : group_pairs)
        for (const auto& p : pairs) {
          lo = std::min({lo, p.target_us.to_double(), p.timing.first_start().to_double()});
          hi = std::max({hi, p.target_us.to_double() + p.timing.exposure.to_double(), p.timing.last_end().to_double()});
        }
      t_read = Clock::now();
      const EventStream ev = seq.read_events(static_cast<int64_t>(std::floor(lo)), static_cast<int64_t>(std::ceil(hi)) + 1);
      stage_ms["read"] += ms_since(t_read);
      for (const bool use_m : {false, true}) {
        const std::vector<size_t>& group = use_m ? m_targets : s_targets;
        if (group.empty()) continue;
        const std::vector<EventTensorPair>& pairs = group_pairs[use_m];
        ModelInputs in;
        for (size_t q = 0; q < group.size(); ++q) {
          append_planes(rs1, rgb, in.rs.data);
          if (use_m) append_planes(rs2, rgb, in.rs.data);
        }
        const int64_t B = static_cast<int64_t>(pairs.size());
        in.rs.shape = {B, 3, seq.height, seq.width};
        const auto t_ev = Clock::now();
        EventTensorSpec spec;
        spec.bins = weights->config.N;
        EventTensors et = builder_gpu ? builder_gpu->build(ev, pairs, spec) : build_event_tensors_ref(ev, pairs, spec);
        stage_ms["event_tensors"] += ms_since(t_ev);
        const Shape es{B, 2 * spec.bins, seq.height, seq.width};
        in.ev1 = {es, std::move(et.ev1)};
        in.ev2 = {es, std::move(et.ev2)};
        in.ev3 = {es, std::move(et.ev3)};
        RunOptions ro;
        ro.mode = use_m ? Mode::m : Mode::s;
        ro.outputs = {use_m ? "out" : "fused"};
        ro.stage_ms = &stage_ms;
        const TiledResult res = run_tiled(*model, in, ro, tile_options);
        for (const char* st : {"plan", "cut", "stitch"})
          if (res.stage_ms.count(st)) stage_ms["tiling"] += res.stage_ms.at(st);
        tiles_total += res.tiles;
        work_pixels += res.work_ratio * double(group.size());
        tiles_run += res.tiles_run;
        tile_used = res.plan.tile_h == seq.height && res.plan.tile_w == seq.width ? 0 : std::max(res.plan.tile_h, res.plan.tile_w);
        tiles_per_target = static_cast<int64_t>(res.plan.tiles.size());
        for (double a : res.target_active_fraction) target_active.push_back(a);
        const HostTensor& out = res.outputs.at(use_m ? "out" : "fused");
        for (size_t q = 0; q < group.size(); ++q)
          results[group[q]] = planes_to_bgr(out.data.data() + q * 3 * seq.height * seq.width, seq.height, seq.width, rgb);
        (use_m ? runs_m : runs_s) += group.size();
      }
    }

    const auto t_write = Clock::now();
    for (size_t j = 0; j < ts.size(); ++j) {
      cv::Mat gt;
      std::string gt_file;
      if (ts[j].gt >= 0) {
        gt_file = seq.ground_truth[ts[j].gt].image;
        gt = read_image(gt_file, seq.width, seq.height);
      }
      output.add(k, ts[j].t_us.to_double(), ts[j].tau, results[j], rs1, gt, gt_file, ts[j].name);
      progress.update(++done, "frame " + std::to_string(k));
    }
    stage_ms["write"] += ms_since(t_write);
  }
  progress.finish();

  const double total_ms = ms_since(t_start);
  nlohmann::json extra;
  extra["sequence"] = {{"path", o.sequence}, {"layout", sequence_layout_name(seq.layout)},
                       {"width", seq.width}, {"height", seq.height}, {"frames_in_sequence", seq.frames.size()},
                       {"notes", seq.notes}};
  extra["mode"] = mode;
  extra["runs"] = {{"s", runs_s}, {"m", runs_m}, {"physics", runs_physics}};
  if (weights) extra["model"] = {{"path", o.model_path}, {"config", weights->config.summary()}, {"channel_order", rgb ? "rgb" : "bgr"}};
  if (mode == "physics") extra["physics"] = {{"contrast", prm.contrast}, {"contrast_source", contrast_source}, {"gamma", prm.gamma}};
  if (weights) {
    nlohmann::json tj{{"tile", tile_options.tile}, {"tile_used", tile_used}, {"halo", tile_options.halo}, {"sparse", o.sparse},
                      {"sparse_threshold", o.sparse_threshold}, {"tiles_per_target", tiles_per_target},
                      {"tiles", tiles_total}, {"tiles_run", tiles_run},
                      {"active_tile_fraction", tiles_total ? double(tiles_run) / double(tiles_total) : 0.0},
                      {"work_ratio", target_active.empty() ? 0.0 : work_pixels / double(target_active.size())}};
    if (!target_active.empty()) {
      double lo = 1, hi = 0, sum = 0;
      for (double a : target_active) lo = std::min(lo, a), hi = std::max(hi, a), sum += a;
      tj["target_active_fraction"] = {{"min", lo}, {"mean", sum / target_active.size()}, {"max", hi}};
    }
    extra["tiling"] = tj;
  }
  extra["frames"] = frames.size();
  extra["targets"] = total_targets;
  extra["backend"] = ctx ? "vulkan" : "cpu";
  if (ctx) extra["device"] = ctx->info().name;
  nlohmann::json per_frame;
  for (const auto& [name, ms] : stage_ms) per_frame[name] = total_targets ? ms / total_targets : 0.0;
  extra["ms_per_gs_frame"] = per_frame;
  extra["ms_per_gs_frame_total"] = total_targets ? total_ms / total_targets : 0.0;
  uint64_t peak = ctx ? ctx->allocator().stats().peak_used_bytes : 0;
  if (auto* vb = dynamic_cast<VulkanBackend*>(backend.get())) peak = std::max<uint64_t>(peak, vb->device_peak_bytes());
  extra["peak_device_bytes"] = peak;
  extra["notes"] = nlohmann::json::array();
  for (const auto& [n, c] : notes) extra["notes"].push_back(n + (c > 1 ? " (x" + std::to_string(c) + ")" : ""));
  nlohmann::json summary = output.finish(extra);

  if (!o.quiet) {
    std::cerr << "unroll: " << frames.size() << " frame(s), " << total_targets << " GS frame(s), mode " << mode
              << ", " << (total_targets ? total_ms / total_targets : 0.0) << " ms per GS frame";
    std::cerr << " (read " << per_frame["read"].get<double>() << ", event tensors " << per_frame["event_tensors"].get<double>()
              << ", E-IC " << per_frame["eic"].get<double>() << ", MOA " << per_frame["moa"].get<double>() << ", physics "
              << per_frame["physics"].get<double>() << ", write " << per_frame["write"].get<double>() << ")";
    std::cerr << ", peak device memory " << (peak >> 20) << " MiB\n";
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
