// vkunroll-bench-report: the speed-against-error report. Simulated sequences with ground truth
// (static background with small movers, full camera motion, noisy events) at several sizes are
// unrolled by `vkunroll unroll` (run_unroll) in every configuration a user can pick: the physics
// unroller, SelfUnroll-S and -M, dense and sparse at several thresholds, the shipped model and the
// published configuration (random weights: speed only). Per row: ms per GS frame on this device,
// PSNR, SSIM, max abs difference to the dense fp32 result of the same mode, active tile fraction.
//
//   vkunroll-bench-report [--out DIR] [--sizes 346x260,640x480] [--frames 3] [--gt-per-frame 2]
//                         [--scenes static,camera,noisy] [--model FILE] [--published-size WxH|none]
//                         [--thresholds 0.002,0.01,0.05] [--variant FILE|none] [--no-fp16]
//
// fp16 rows (`--precision fp16`: S, M dense and S sparse exact) are compared against the fp32 dense
// row of the same mode. The model rows run the shipped default model (--model: another); --variant
// FILE adds a second model's rows (S and M dense, S sparse, S fp16) beside them.
//
// Writes DIR/report.md, DIR/report.json and DIR/report.png (PSNR against ms per GS frame).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <optional>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "bench_args.hpp"
#include "vkunroll/host/unroll/metrics.hpp"
#include "vkunroll/host/sim/recording.hpp"
#include "vkunroll/host/unroll/default_model.hpp"
#include "vkunroll/host/unroll/unroll.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/base/stopwatch.hpp"

using namespace vkunroll;
namespace fs = std::filesystem;

namespace {

struct Size {
  int w = 0, h = 0;
  std::string str() const { return std::to_string(w) + "x" + std::to_string(h); }
};

Size parse_size(const std::string& s) {
  const BenchSize z = bench_size_arg("vkunroll-bench-report", "size", s, 1, 16384);
  return {static_cast<int>(z.w), static_cast<int>(z.h)};
}

std::vector<std::string> split(const std::string& s, char sep = ',') {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, sep))
    if (!item.empty()) out.push_back(item);
  return out;
}

// One scene kind of the report.
struct SceneKind {
  std::string name, description;
  sim::MotionKind motion;
  std::string preset;
  int sprites;
};

const std::vector<SceneKind>& scene_kinds() {
  static const std::vector<SceneKind> kinds = {
      {"static", "static camera, two small moving sprites, clean events", sim::MotionKind::Static, "clean", 2},
      {"camera", "full camera motion (mixed pan/rotation/shake), realistic events", sim::MotionKind::Mixed, "realistic", 2},
      {"noisy", "camera pan, noisy events (shot noise, leak, threshold mismatch)", sim::MotionKind::Pan, "noisy", 2},
  };
  return kinds;
}

// A configuration of `vkunroll unroll` the report measures.
struct RowSpec {
  std::string label;
  std::string mode;        // physics | s | m | choose
  std::string sparse = "off";
  double threshold = 0.0;  // fast: active when events per pixel >= threshold
  bool published = false;  // the published configuration, random weights (speed only)
  std::string reference;   // label of the dense row this one is compared against ("" = none)
  int64_t tile = 0, halo = 64;  // tiling of the model passes (0: untiled when it fits)
  std::string precision = "fp32";
  bool variant = false;  // the physics-informed variant (--variant) instead of --model
};

struct RowResult {
  RowSpec spec;
  std::string scene, size;
  double ms_compute = 0, ms_total = 0, psnr = NAN, ssim = NAN, rs_psnr = NAN, max_diff = NAN, active = NAN;
  int targets = 0;
  std::string note;
};

std::vector<fs::path> frame_files(const fs::path& dir) {
  std::vector<fs::path> out;
  if (!fs::exists(dir / "frames")) return out;
  for (const auto& e : fs::directory_iterator(dir / "frames"))
    if (e.path().extension() == ".png") out.push_back(e.path());
  std::sort(out.begin(), out.end());
  return out;
}

// Largest |a - b| over every frame pair, in units of full scale (16-bit PNGs: 1.5e-5 resolution).
double max_abs_diff(const fs::path& a_dir, const fs::path& b_dir) {
  const auto a = frame_files(a_dir), b = frame_files(b_dir);
  if (a.size() != b.size() || a.empty()) return NAN;
  double m = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const cv::Mat x = to_unit_float(cv::imread(a[i].string(), cv::IMREAD_UNCHANGED));
    const cv::Mat y = to_unit_float(cv::imread(b[i].string(), cv::IMREAD_UNCHANGED));
    if (x.size() != y.size()) return NAN;
    cv::Mat d;
    cv::absdiff(x, y, d);
    double mx = 0;
    cv::minMaxLoc(d.reshape(1), nullptr, &mx);
    m = std::max(m, mx);
  }
  return m;
}

double compute_ms(const nlohmann::json& s) {
  const auto& p = s.at("ms_per_gs_frame");
  double ms = 0;
  // Everything but setup and files: host planning, recording and conversions, and the device wait.
  for (const char* k : {"upload", "event_tensors", "physics", "model", "download", "wait"})
    if (p.contains(k)) ms += p[k].get<double>();
  return ms;
}

std::string fmt(double v, int prec) {
  if (std::isnan(v)) return "-";
  if (std::isinf(v)) return "inf";
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", prec, v);
  return buf;
}

// PSNR against log10(ms): one marker shape per mode, one colour per scene/size.
void plot(const std::vector<RowResult>& rows, const std::string& path) {
  const int W = 1100, H = 700, L = 90, R = 330, T = 50, B = 70;
  cv::Mat img(H, W, CV_8UC3, cv::Scalar(255, 255, 255));
  std::vector<const RowResult*> pts;
  for (const auto& r : rows)
    if (!std::isnan(r.psnr) && !std::isinf(r.psnr) && r.ms_compute > 0) pts.push_back(&r);
  if (pts.empty()) {
    cv::imwrite(path, img);
    return;
  }
  double x0 = 1e30, x1 = -1e30, y0 = 1e30, y1 = -1e30;
  for (const auto* r : pts) {
    x0 = std::min(x0, std::log10(r->ms_compute)), x1 = std::max(x1, std::log10(r->ms_compute));
    y0 = std::min(y0, r->psnr), y1 = std::max(y1, r->psnr);
  }
  x0 = std::floor(x0), x1 = std::ceil(x1 + 1e-9);
  if (x1 <= x0) x1 = x0 + 1;
  y0 = std::floor(y0 - 0.5), y1 = std::ceil(y1 + 0.5);
  auto px = [&](double ms) { return L + int((std::log10(ms) - x0) / (x1 - x0) * (W - L - R)); };
  auto py = [&](double db) { return H - B - int((db - y0) / (y1 - y0) * (H - T - B)); };
  const cv::Scalar black(0, 0, 0), grid(225, 225, 225);
  for (double d = x0; d <= x1 + 1e-9; d += 1) {
    for (int k = 1; k < 10 && d + std::log10(k) <= x1 + 1e-9; ++k)
      cv::line(img, {px(std::pow(10, d) * k), T}, {px(std::pow(10, d) * k), H - B}, grid, 1);
    cv::putText(img, fmt(std::pow(10, d), 0), {px(std::pow(10, d)) - 15, H - B + 22}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black, 1,
                cv::LINE_AA);
  }
  for (double db = y0; db <= y1 + 1e-9; db += 1) {
    cv::line(img, {L, py(db)}, {W - R, py(db)}, grid, 1);
    cv::putText(img, fmt(db, 0), {L - 35, py(db) + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black, 1, cv::LINE_AA);
  }
  cv::rectangle(img, {L, T}, {W - R, H - B}, black, 1);
  cv::putText(img, "ms per GS frame (log scale, this device)", {L + 180, H - 20}, cv::FONT_HERSHEY_SIMPLEX, 0.6, black, 1,
              cv::LINE_AA);
  cv::putText(img, "PSNR (dB)", {10, T - 8}, cv::FONT_HERSHEY_SIMPLEX, 0.6, black, 1, cv::LINE_AA);
  cv::putText(img, "vkunroll: speed against error (simulated sequences with ground truth)", {L + 100, 22},
              cv::FONT_HERSHEY_SIMPLEX, 0.6, black, 1, cv::LINE_AA);
  static const cv::Scalar palette[] = {{200, 80, 20}, {30, 140, 30}, {20, 20, 200}, {160, 30, 160}, {20, 150, 200}, {90, 90, 90}};
  std::map<std::string, int> series;
  for (const auto* r : pts) series.emplace(r->scene + " " + r->size, 0);
  int i = 0;
  for (auto& [k, v] : series) v = i++;
  auto marker = [&](const RowResult& r, cv::Point p, const cv::Scalar& c) {
    if (r.spec.mode == "physics")
      cv::drawMarker(img, p, c, cv::MARKER_DIAMOND, 12, 2);
    else if (r.spec.sparse != "off")
      cv::drawMarker(img, p, c, cv::MARKER_TRIANGLE_UP, 12, 2);
    else if (r.spec.mode == "m")
      cv::rectangle(img, p - cv::Point(5, 5), p + cv::Point(5, 5), c, 2);
    else
      cv::circle(img, p, 6, c, 2);
  };
  for (const auto* r : pts) marker(*r, {px(r->ms_compute), py(r->psnr)}, palette[series[r->scene + " " + r->size] % 6]);
  int ly = T + 10;
  for (const auto& [k, v] : series) {
    cv::line(img, {W - R + 20, ly}, {W - R + 45, ly}, palette[v % 6], 3);
    cv::putText(img, k, {W - R + 55, ly + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black, 1, cv::LINE_AA);
    ly += 22;
  }
  ly += 10;
  const std::pair<const char*, RowSpec> legend[] = {{"physics", {"", "physics"}},
                                                    {"S dense", {"", "s"}},
                                                    {"M dense", {"", "m"}},
                                                    {"sparse (S or M)", {"", "s", "fast"}}};
  for (const auto& [name, spec] : legend) {
    RowResult r;
    r.spec = spec;
    marker(r, {W - R + 32, ly}, black);
    cv::putText(img, name, {W - R + 55, ly + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black, 1, cv::LINE_AA);
    ly += 22;
  }
  cv::imwrite(path, img);
}

constexpr const char* kBench = "vkunroll-bench-report";

struct ReportArgs {
  std::string out = "report", model;  // empty model: the shipped default, looked up once the arguments are read
  std::string sizes = "346x260,640x480", scenes = "static,camera,noisy", published_size = "346x260";
  std::string thresholds = "0.002,0.01,0.05";
  int frames = 3, gt_per_frame = 2;
  int64_t sparse_tile = 64, sparse_halo = 32;
  bool sparse_rows = true, fp16_rows = true;
  std::string variant = "none";
  std::string plot_from;  // redraw this report.json's PNG instead of measuring
  bool help = false;
};

ReportArgs parse_report_args(int argc, char** argv) {
  ReportArgs a;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) throw Error(std::string(kBench) + ": " + k + " needs a value");
      return argv[++i];
    };
    if (k == "--out") a.out = next();
    else if (k == "--sizes") a.sizes = next();
    else if (k == "--scenes") a.scenes = next();
    else if (k == "--model") a.model = next();
    else if (k == "--frames") a.frames = static_cast<int>(bench_int_arg(kBench, k, next(), 1, 100000));
    else if (k == "--gt-per-frame") a.gt_per_frame = static_cast<int>(bench_int_arg(kBench, k, next(), 1, 1000));
    else if (k == "--published-size") a.published_size = next();
    else if (k == "--thresholds") a.thresholds = next();
    else if (k == "--no-sparse") a.sparse_rows = false;
    else if (k == "--no-fp16") a.fp16_rows = false;
    else if (k == "--variant") a.variant = next();
    else if (k == "--plot-from") a.plot_from = next();
    else if (k == "--sparse-tile") a.sparse_tile = bench_int_arg(kBench, k, next(), 1, 4096);
    else if (k == "--sparse-halo") a.sparse_halo = bench_int_arg(kBench, k, next(), 0, 4096);
    else if (k == "--help" || k == "-h") a.help = true;
    else throw Error(std::string(kBench) + ": unknown argument '" + k + "' (see --help)");
  }
  return a;
}

// Redraws the PNG of an earlier run's report.json (no measurement).
void plot_from(const std::string& json_path) {
  std::ifstream f(json_path);
  if (!f) throw Error(std::string(kBench) + ": cannot read " + json_path);
  const nlohmann::json j = nlohmann::json::parse(f);
  std::vector<RowResult> rows;
  for (const auto& r : j.at("rows")) {
    RowResult x;
    x.spec.label = r.value("row", "");
    x.spec.mode = r.value("mode", "");
    x.spec.sparse = r.value("sparse", "off");
    x.scene = r.value("scene", "");
    x.size = r.value("size", "");
    x.ms_compute = r["ms_per_gs_frame"].is_number() ? r["ms_per_gs_frame"].get<double>() : NAN;
    x.psnr = r["psnr"].is_number() ? r["psnr"].get<double>() : NAN;
    rows.push_back(x);
  }
  const std::string png = (fs::path(json_path).parent_path() / "report.png").string();
  plot(rows, png);
  std::cout << "wrote " << png << "\n";
}

// Every row of a scene: physics, S, M and choose dense; sparse exact and fast; fp16; the variant's.
std::vector<RowSpec> row_specs(const ReportArgs& a) {
  std::vector<RowSpec> specs = {{"physics", "physics"}, {"S dense", "s"}, {"M dense", "m"}};
  specs.push_back({"choose (S in frame, M between)", "choose"});
  if (a.sparse_rows) {
    const int64_t T = a.sparse_tile, Hh = a.sparse_halo;
    specs.push_back({"S sparse exact", "s", "exact", 0.0, false, "S dense", T, Hh});
    specs.push_back({"M sparse exact", "m", "exact", 0.0, false, "M dense", T, Hh});
    for (const auto& t : split(a.thresholds)) {
      specs.push_back({"S sparse fast " + t, "s", "fast", std::stod(t), false, "S dense", T, Hh});
      specs.push_back({"M sparse fast " + t, "m", "fast", std::stod(t), false, "M dense", T, Hh});
    }
  }
  if (a.fp16_rows) {
    specs.push_back({"S dense fp16", "s", "off", 0.0, false, "S dense", 0, 64, "fp16"});
    specs.push_back({"M dense fp16", "m", "off", 0.0, false, "M dense", 0, 64, "fp16"});
    if (a.sparse_rows)
      specs.push_back({"S sparse exact fp16", "s", "exact", 0.0, false, "S dense", a.sparse_tile, a.sparse_halo, "fp16"});
  }
  if (a.variant != "none") {
    if (!fs::exists(a.variant))
      throw Error(std::string(kBench) + ": --variant " + a.variant + ": no such file (none: no variant rows)");
    specs.push_back({"variant S dense", "s", "off", 0.0, false, "", 0, 64, "fp32", true});
    // M is the variant's mode on the natural held-out suite (unroll --mode auto): timed beside S.
    specs.push_back({"variant M dense", "m", "off", 0.0, false, "", 0, 64, "fp32", true});
    if (a.sparse_rows)
      specs.push_back({"variant S sparse exact", "s", "exact", 0.0, false, "variant S dense", a.sparse_tile, a.sparse_halo, "fp32", true});
    if (a.fp16_rows) specs.push_back({"variant S dense fp16", "s", "off", 0.0, false, "variant S dense", 0, 64, "fp16", true});
  }
  for (auto& s : specs)
    if (s.reference.empty() && s.mode != "physics") s.reference = s.label;
  return specs;
}

// The scene's sequence at this size, simulated once into DATA/<scene>_<size>.
fs::path scene_sequence(const ReportArgs& a, const SceneKind& kind, const Size& size, uint64_t seed) {
  sim::SimulationConfig cfg = sim::simulation_preset(kind.preset);
  cfg.width = size.w, cfg.height = size.h, cfg.frames = a.frames, cfg.gt_per_frame = a.gt_per_frame;
  cfg.motion = kind.motion, cfg.sprites = kind.sprites, cfg.bit_depth = 8, cfg.seed = seed;
  cfg.line_delay_us = 25900.0 / size.h;  // the same 25.9 ms readout at every size
  const fs::path seq_dir = fs::path(a.out) / "data" / (kind.name + "_" + size.str());
  if (!fs::exists(seq_dir / "meta.json")) {
    std::cerr << "report: simulating " << seq_dir.string() << " (" << kind.description << ")\n";
    const sim::SimulatedSequence seq = sim::simulate(cfg);
    sim::write_sequence(cfg, seq, seq_dir.string());
  }
  return seq_dir;
}

// One row: the unroll of `seq_dir` as `spec` asks, scored; `dirs` holds the outputs of the rows so far.
RowResult run_row(const ReportArgs& a, const RowSpec& spec, const std::string& scene, const Size& size, const fs::path& seq_dir,
                  std::map<std::string, fs::path>& dirs) {
  RowResult r;
  r.spec = spec, r.scene = scene, r.size = size.str();
  const fs::path dir = fs::path(a.out) / "runs" / (scene + "_" + size.str()) / spec.label;
  fs::remove_all(dir);
  UnrollOptions o;
  o.sequence = seq_dir.string();
  o.out_dir = dir.string();
  o.session.model_path = spec.mode == "physics" ? "" : spec.variant ? a.variant : a.model;
  o.session.precision = parse_precision(spec.precision, "precision");
  o.mode = parse_unroll_mode(spec.mode, "mode");
  o.times = {TargetTimes::Kind::ground_truth, {}};
  o.quiet = true;
  o.output.write_video = false;
  o.output.frame_format = FrameFormat::png16;
  o.sparse = parse_sparse_policy(spec.sparse, "sparse");
  o.sparse_threshold = spec.threshold;
  o.tile = spec.tile;
  o.halo = spec.halo;
  std::cerr << "report: " << scene << " " << size.str() << " " << spec.label << " ..." << std::flush;
  try {
    const nlohmann::json s = run_unroll(o);
    r.ms_compute = compute_ms(s);
    r.ms_total = s.value("ms_per_gs_frame_total", 0.0);
    r.targets = s.value("targets", 0);
    if (s.contains("metrics")) {
      r.psnr = s["metrics"].value("mean_psnr", NAN);
      r.ssim = s["metrics"].value("mean_ssim", NAN);
      r.rs_psnr = s["metrics"].value("rs_mean_psnr", NAN);
    }
    if (s.contains("tiling")) r.active = s["tiling"].value("active_tile_fraction", NAN);
    dirs[spec.label] = dir;
    if (!spec.reference.empty() && dirs.count(spec.reference)) r.max_diff = max_abs_diff(dirs[spec.reference], dir);
    std::cerr << " " << fmt(r.ms_compute, 1) << " ms/frame, PSNR " << fmt(r.psnr, 2) << "\n";
  } catch (const std::exception& e) {
    r.note = e.what();
    std::cerr << " failed: " << e.what() << "\n";
  }
  return r;
}

// The published configuration with random weights: speed only (its output means nothing).
RowResult published_row(const ReportArgs& a) {
  const Size size = parse_size(a.published_size);
  const fs::path wfile = fs::path(a.out) / "published_random.safetensors";
  if (!fs::exists(wfile)) save_weights(wfile.string(), random_weights(ModelConfig::published(), 2024));
  RowResult r;
  r.spec = {"published config (random weights) S", "s", "off", 0.0, true, ""};
  r.scene = "camera", r.size = size.str();
  UnrollOptions o;
  o.sequence = (fs::path(a.out) / "data" / ("camera_" + size.str())).string();
  o.out_dir = (fs::path(a.out) / "runs" / ("published_" + size.str())).string();
  o.output.existing = ExistingOutput::overwrite;  // the report's own folder from an earlier report
  o.session.model_path = wfile.string();
  o.mode = UnrollMode::s;
  o.times = {TargetTimes::Kind::normalized, {Rational(1, 2)}};
  o.frames = {0};
  o.quiet = true;
  o.output.write_video = false;
  std::cerr << "report: published configuration, one target at " << size.str() << " ..." << std::flush;
  try {
    const nlohmann::json s = run_unroll(o);
    r.ms_compute = compute_ms(s);
    r.ms_total = s.value("ms_per_gs_frame_total", 0.0);
    r.targets = s.value("targets", 0);
    r.note = "speed only: random weights";
    std::cerr << " " << fmt(r.ms_compute, 0) << " ms\n";
  } catch (const std::exception& e) {
    r.note = e.what();
    std::cerr << " failed: " << e.what() << "\n";
  }
  return r;
}

nlohmann::json report_json(const std::vector<RowResult>& results, double minutes) {
  nlohmann::json j;
  j["device_note"] = "ms per GS frame = event tensors + E-IC + MOA + physics (+ sparse planning), without PNG read/write";
  j["fp16"] = "rows marked fp16: weights and activations stored in fp16, fp32 arithmetic inside (docs/kernels.md "
              "\"Precision\"); their max abs diff is against the fp32 dense row of the same mode and model";
  j["minutes"] = minutes;
  j["rows"] = nlohmann::json::array();
  for (const auto& r : results) {
    auto num = [](double v) { return std::isnan(v) || std::isinf(v) ? nlohmann::json(nullptr) : nlohmann::json(v); };
    j["rows"].push_back({{"scene", r.scene}, {"size", r.size}, {"row", r.spec.label}, {"mode", r.spec.mode},
                         {"sparse", r.spec.sparse}, {"threshold", r.spec.threshold}, {"published", r.spec.published},
                         {"precision", r.spec.precision}, {"variant", r.spec.variant}, {"ms_per_gs_frame", num(r.ms_compute)}, {"ms_total", num(r.ms_total)},
                         {"psnr", num(r.psnr)}, {"ssim", num(r.ssim)}, {"rs_psnr", num(r.rs_psnr)},
                         {"max_abs_diff_to_dense", num(r.max_diff)}, {"active_tile_fraction", num(r.active)},
                         {"targets", r.targets}, {"note", r.note}});
  }
  return j;
}

std::string report_markdown(const std::vector<RowResult>& results, const nlohmann::json& j) {
  std::ostringstream md;
  md << "| scene | size | row | ms / GS frame | PSNR (dB) | SSIM | max abs diff to dense | active tiles | note |\n"
     << "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | --- |\n";
  std::string last;
  for (const auto& r : results) {
    const std::string key = r.scene + r.size;
    if (key != last && !r.spec.published)
      md << "| " << r.scene << " | " << r.size << " | RS input | - | " << fmt(r.rs_psnr, 2) << " | - | - | - | |\n";
    last = key;
    md << "| " << r.scene << " | " << r.size << " | " << r.spec.label << " | " << fmt(r.ms_compute, 1) << " | "
       << fmt(r.psnr, 2) << " | " << fmt(r.ssim, 3) << " | " << fmt(r.max_diff, 4) << " | " << fmt(r.active, 2) << " | "
       << r.note << " |\n";
  }
  md << "\nfp16: " << j["fp16"].get<std::string>() << ".\n";
  return md.str();
}

const char* kUsage =
    "usage: vkunroll-bench-report [--out DIR] [--sizes 346x260,640x480] [--scenes static,camera,noisy]\n"
    "         [--frames 3] [--gt-per-frame 2] [--model FILE] [--published-size WxH|none]\n"
    "         [--thresholds 0.002,0.01,0.05] [--sparse-tile 64] [--sparse-halo 32] [--no-sparse]\n"
    "         [--variant FILE|none] [--no-fp16]\n"
    "       vkunroll-bench-report --plot-from DIR/report.json   (redraws DIR/report.png)\n";

}  // namespace

int main(int argc, char** argv) try {
  ReportArgs a = parse_report_args(argc, argv);
  if (a.help) {
    std::cout << kUsage;
    return 0;
  }
  if (!a.plot_from.empty()) {
    plot_from(a.plot_from);
    return 0;
  }
  if (a.model.empty()) a.model = vkunroll::find_default_model().path;
  if (a.model.empty()) throw Error(std::string(kBench) + ": no default model found; --model FILE");
  fs::create_directories(a.out);
  const std::vector<RowSpec> specs = row_specs(a);
  std::vector<RowResult> results;
  const Stopwatch since_start;
  for (const auto& size_s : split(a.sizes)) {
    const Size size = parse_size(size_s);
    for (const auto& scene_name : split(a.scenes)) {
      const auto& kinds = scene_kinds();
      auto it = std::find_if(kinds.begin(), kinds.end(), [&](const SceneKind& k) { return k.name == scene_name; });
      if (it == kinds.end()) throw Error(std::string(kBench) + ": unknown scene '" + scene_name + "' (static, camera, noisy)");
      const fs::path seq_dir = scene_sequence(a, *it, size, 7000 + results.size());
      std::map<std::string, fs::path> dirs;
      for (const auto& spec : specs) results.push_back(run_row(a, spec, it->name, size, seq_dir, dirs));
    }
  }
  if (a.published_size != "none") results.push_back(published_row(a));
  const double minutes = since_start.seconds() / 60;
  const nlohmann::json j = report_json(results, minutes);
  std::ofstream(fs::path(a.out) / "report.json") << j.dump(2) << "\n";
  const std::string md = report_markdown(results, j);
  std::ofstream(fs::path(a.out) / "report.md") << md;
  plot(results, (fs::path(a.out) / "report.png").string());
  std::cout << md << "\nwrote " << a.out << "/report.md, report.json, report.png (" << fmt(minutes, 1) << " min)\n";
  return 0;
} catch (const std::exception& e) {
  std::cerr << "vkunroll-bench-report: " << e.what() << "\n";
  return 1;
}
