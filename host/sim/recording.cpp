#include "vkunroll/host/sim/recording.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <tuple>

#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "vkunroll/host/events/event_writer.hpp"
#include "vkunroll/host/sim/random.hpp"
#include "vkunroll/base/error.hpp"

namespace vkunroll::sim {

namespace fs = std::filesystem;

namespace {
constexpr uint64_t kStreamFrameNoise = 0xF4A3E;
constexpr double kTwoPi = 6.283185307179586;

std::string num(double v) {
  char b[64];
  std::snprintf(b, sizeof b, "%g", v);
  return b;
}

std::string fmt_us(double v) {
  char b[64];
  std::snprintf(b, sizeof b, "%.1f us", v);
  return b;
}
}  // namespace

nlohmann::json FrameNoiseParams::to_json() const { return {{"full_well_e", full_well_e}, {"read_noise", read_noise}}; }

nlohmann::json TimeStepStats::to_json() const {
  return {{"samples", samples},   {"rejected", rejected},   {"over_limit", over_limit},
          {"color_renders", color_renders}, {"luminance_renders", luminance_renders},
          {"min_dt_us", min_dt_us}, {"mean_dt_us", mean_dt_us}};
}

SimulationConfig simulation_preset(const std::string& preset) {
  SimulationConfig c;
  c.preset = preset;
  c.events = event_preset(preset);  // throws on an unknown name
  if (preset == "realistic") {
    c.frame_noise.full_well_e = 10000.0;  // DAVIS346 APS-class pixel; 1% shot noise at full scale
    c.frame_noise.read_noise = 0.002;     // ~0.5 DN at 8 bits
  } else if (preset == "noisy") {
    c.frame_noise.full_well_e = 1500.0;   // low light: few electrons per pixel
    c.frame_noise.read_noise = 0.008;
  }
  return c;
}

void SimulationConfig::validate() const {
  // `text` names options with opt(); the error is the OptionError of `field`.
  auto fail = [](const std::string& field, const std::string& text) { throw OptionError(field, "", text, "simulate: " + text); };
  if (width < 2 || height < 2 || width > 8192 || height > 8192)
    fail("size", opt("size") + " " + std::to_string(width) + "x" + std::to_string(height) + " out of range (2x2 .. 8192x8192)");
  if (frames < 1 || frames > 100000) fail("frames", opt("frames") + " " + std::to_string(frames) + " must be in 1..100000");
  if (gt_per_frame < 0 || gt_per_frame > 1000) fail("gt_per_frame", opt("gt_per_frame") + " " + std::to_string(gt_per_frame) + " must be in 0..1000");
  if (!(fps > 0) || fps > 1e5) fail("fps", opt("fps") + " must be in (0, 100000]");
  if (!(line_delay_us >= 0)) fail("line_delay_us", opt("line_delay_us") + " must be >= 0");
  if (!(exposure_us > 0)) fail("exposure_us", opt("exposure_us") + " must be > 0");
  if (!(lead_in_us >= 0 && lead_in_us <= 1e7)) fail("lead_in_us", opt("lead_in_us") + " " + num(lead_in_us) + " must be in [0, 1e7] us (10 s)");
  if (!(speed_scale >= 0 && speed_scale <= 1000)) fail("speed_scale", opt("speed_scale") + " " + num(speed_scale) + " must be in [0, 1000]");
  // Plausible sensor ranges (docs/simulator.md): beyond them a run only grows without bound.
  for (const auto& [value, name, hi] : {std::tuple<double, const char*, double>{events.shot_hz, "shot_hz", 1e4},
                                        {events.leak_hz, "leak_hz", 1e4}, {events.refractory_us, "refractory_us", 1e7},
                                        {events.sigma, "sigma", 1.0}, {events.c_on, "c_on", 5.0}, {events.c_off, "c_off", 5.0},
                                        {events.cutoff_hz, "cutoff_hz", 1e9}, {events.eps, "eps", 1.0},
                                        {events.hot_fraction, "hot_fraction", 1.0}, {events.hot_hz, "hot_hz", 1e4},
                                        {events.jitter_us, "jitter_us", 1e6},
                                        {flicker_hz, "flicker_hz", 1e5}})
    if (!(value >= 0 && value <= hi)) fail(name, opt(name) + " " + num(value) + " must be in [0, " + num(hi) + "]");
  const double period = frame_period_us(), readout_time = (height - 1) * line_delay_us;
  if (readout_time > period)
    fail("line_delay_us", opt("line_delay_us") + " " + num(line_delay_us) + " x " + std::to_string(height - 1) + " rows = " +
         fmt_us(readout_time) + " of readout, longer than the frame period " + fmt_us(period) + " of " + opt("fps") + " " + num(fps) + " (a rolling shutter reads each frame out before the next)");
  if (exposure_us > period)
    fail("exposure_us", opt("exposure_us") + " " + num(exposure_us) + " is longer than the frame period " + fmt_us(period));
  if (readout != "top-down" && readout != "bottom-up") fail("readout", opt("readout") + " '" + readout + "': expected top-down or bottom-up");
  if (bit_depth != 8 && bit_depth != 16) fail("bit_depth", opt("bit_depth") + " " + std::to_string(bit_depth) + ": expected 8 or 16");
  if (events_format != "h5" && events_format != "txt" && events_format != "both")
    fail("events_format", opt("events_format") + " '" + events_format + "': expected h5, txt or both");
  if (!(gamma > 0.1 && gamma < 10)) fail("gamma", opt("gamma") + " must be in (0.1, 10)");
  if (sprites < 0 || sprites > 64) fail("sprites", opt("sprites") + " must be in 0..64");
  if (supersample < 1 || supersample > 8) fail("supersample", opt("supersample") + " must be in 1..8");
  if (!(step_fraction > 0 && step_fraction <= 4)) fail("step_fraction", opt("step_fraction") + " " + num(step_fraction) + " must be in (0, 4]");
  if (!(dt_min_us > 0) || !(dt_max_us >= dt_min_us)) fail("dt_min_us", "time step bounds need 0 < dt_min <= dt_max");
  if (flicker_amplitude < 0 || flicker_amplitude >= 1) fail("flicker_amplitude", opt("flicker_amplitude") + " must be in [0, 1)");
  if (flicker_amplitude > 0 && !(flicker_hz > 0)) fail("flicker_hz", opt("flicker_hz") + " must be > 0");
  if (frame_noise.full_well_e < 0 || frame_noise.read_noise < 0) fail("full_well_e", "frame noise parameters must be >= 0");
}

nlohmann::json SimulationConfig::to_json() const {
  return {{"preset", preset},
          {"seed", seed},
          {"width", width},
          {"height", height},
          {"frames", frames},
          {"fps", fps},
          {"frame_period_us", frame_period_us()},
          {"line_delay_us", line_delay_us},
          {"exposure_us", exposure_us},
          {"readout", readout},
          {"lead_in_us", lead_in_us},
          {"events_span_us", {0.0, end_us()}},
          {"gt_per_frame", gt_per_frame},
          {"motion", motion_kind_name(motion)},
          {"texture", texture_file.empty() ? std::string(texture_kind_name(texture)) : texture_file},
          {"sprites", sprites},
          {"speed_scale", speed_scale},
          {"flicker_amplitude", flicker_amplitude},
          {"flicker_hz", flicker_hz},
          {"supersample", supersample},
          {"gamma", gamma},
          {"bit_depth", bit_depth},
          {"color", color},
          {"events_format", events_format},
          {"event_model", [&] {
             EventSimParams p = events;
             p.seed = seed;
             return p.to_json();
           }()},
          {"frame_noise", frame_noise.to_json()},
          {"step_fraction", step_fraction},
          {"dt_min_us", dt_min_us},
          {"dt_max_us", dt_max_us}};
}

SimulatedSequence simulate(const SimulationConfig& config) {
  config.validate();
  SceneOptions o;
  o.width = config.width;
  o.height = config.height;
  o.supersample = config.supersample;
  o.texture = config.texture;
  o.texture_file = config.texture_file;
  o.motion = config.motion;
  o.speed_scale = config.speed_scale;
  o.sprites = config.sprites;
  o.flicker_amplitude = config.flicker_amplitude;
  o.flicker_hz = config.flicker_hz;
  o.duration_us = config.end_us();
  o.gamma = config.gamma;
  o.seed = config.seed;
  Scene scene(build_scene(o));
  return simulate(config, scene);
}

namespace {
// An RS frame from its accumulated row integrals: the average over the exposure, then the frame
// sensor's noise, clipped to [0, 1]. Releases `acc`.
cv::Mat finish_rs_frame(cv::Mat& acc, const SimulationConfig& config, int k) {
  const int W = config.width, H = config.height;
  cv::Mat img = acc.empty() ? cv::Mat(H, W, CV_32FC3, cv::Scalar::all(0)) : acc;
  img *= 1.0 / config.exposure_us;  // in place: no second copy of every frame
  acc.release();
  const FrameNoiseParams& n = config.frame_noise;
  if (n.full_well_e > 0 || n.read_noise > 0) {
    for (int y = 0; y < H; ++y) {
      float* p = img.ptr<float>(y);
      for (int i = 0; i < W * 3; ++i) {
        const uint64_t idx = (static_cast<uint64_t>(y) * W * 3 + i) * 2;
        const uint64_t stream = kStreamFrameNoise + static_cast<uint64_t>(k);
        const double z = normal_from(hash3(config.seed, stream, idx), hash3(config.seed, stream, idx + 1));
        const double v = std::max(0.0f, p[i]);
        const double var = (n.full_well_e > 0 ? v / n.full_well_e : 0.0) + n.read_noise * n.read_noise;
        p[i] = static_cast<float>(v + std::sqrt(var) * z);
      }
    }
  }
  cv::min(cv::max(img, 0.0), 1.0, img);
  return img;
}

// Ground truth: the sharp image at gt_per_frame instants per frame period.
void add_ground_truth(const SimulationConfig& config, Scene& scene, SimulatedSequence& seq) {
  const int M = config.gt_per_frame, H = config.height;
  for (int k = 0; k < config.frames; ++k) {
    const double s0 = config.frame_t0_us(k), span = (H - 1) * config.line_delay_us + config.exposure_us;
    for (int j = 0; j < M; ++j) {
      GroundTruthFrame g;
      g.frame = k;
      g.index = j;
      g.t_us = s0 + (j + 0.5) / M * config.frame_period_us();
      g.tau = (g.t_us - s0) / span;
      scene.render(g.t_us, g.image);
      cv::min(cv::max(g.image, 0.0), 1.0, g.image);
      char name[96];
      std::snprintf(name, sizeof name, "gs/f%06d_i%02d_t%010lldus.png", k, j, static_cast<long long>(std::llround(g.t_us)));
      g.file = name;
      seq.gt.push_back(std::move(g));
    }
  }
}
// Per-frame row exposure windows, and the span in which any row of a frame is exposing.
struct ExposureWindows {
  std::vector<std::vector<double>> row_start;  // [frame][row]: when the row starts exposing
  std::vector<double> span_lo, span_hi;        // [frame]
  bool overlaps(int k, double a, double b) const { return span_lo[k] < b && a < span_hi[k]; }
  // Whether any frame is exposing in (a, b): a step there needs the color image.
  bool any_overlaps(double a, double b) const {
    for (int k = 0; k < static_cast<int>(span_lo.size()); ++k)
      if (overlaps(k, a, b)) return true;
    return false;
  }
};

ExposureWindows exposure_windows(const SimulationConfig& config) {
  const int K = config.frames, H = config.height;
  ExposureWindows w{std::vector<std::vector<double>>(K, std::vector<double>(H)), std::vector<double>(K),
                    std::vector<double>(K)};
  for (int k = 0; k < K; ++k) {
    for (int y = 0; y < H; ++y) w.row_start[k][y] = config.row_start_us(k, y);
    w.span_lo[k] = config.frame_t0_us(k);
    w.span_hi[k] = w.span_lo[k] + (H - 1) * config.line_delay_us + config.exposure_us;
  }
  return w;
}

// One simulation run: adaptive time steps through the scene, each feeding the event simulator and,
// where a frame is exposing, the rolling-shutter frames' integrals.
class Recorder {
 public:
  Recorder(const SimulationConfig& config, Scene& scene, SimulatedSequence& seq)
      : config_(config), scene_(scene), seq_(seq), windows_(exposure_windows(config)), acc_(config.frames),
        events_(config.width, config.height, event_params(config)) {
    limit_ = config.step_fraction * std::min(config.events.c_on, config.events.c_off);
    dt_max_ = config.dt_max_us;
    // The photoreceptor filter is integrated per step: keep steps well below its time constant.
    if (config.events.cutoff_hz > 0)
      dt_max_ = std::min(dt_max_, std::max(config.dt_min_us, 0.5e6 / (kTwoPi * config.events.cutoff_hz)));
  }

  // Runs to the end; the events, step statistics and RS integrals go into the sequence.
  void run();

 private:
  static EventSimParams event_params(const SimulationConfig& config) {
    EventSimParams p = config.events;
    p.seed = config.seed;  // one seed drives everything (events.seed is for standalone use)
    return p;
  }
  void render(double t, bool color, cv::Mat& c, cv::Mat& l);
  // The end of the next step from t: the proposed sample split until no pixel's log change passes
  // the limit (or the step is at its minimum); `dt` is the step to try, shrunk by the splits.
  double propose_step(double t, double& dt, bool& color, double& change);
  // Each row integrates the piecewise-linear signal over [start, start + exposure] within the step.
  void integrate_rows(int k, double t_start, double t_end);

  const SimulationConfig& config_;
  Scene& scene_;
  SimulatedSequence& seq_;
  const ExposureWindows windows_;
  std::vector<cv::Mat> acc_;  // per frame: the rows' integrals so far
  EventSimulator events_;
  double limit_ = 0, dt_max_ = 0;
  cv::Mat color_start_, color_end_, lum_start_, lum_end_;  // color and luminance at the step's ends
};

void Recorder::render(double t, bool color, cv::Mat& c, cv::Mat& l) {
  if (color) {
    scene_.render(t, c);
    cv::transform(c, l, cv::Matx13f(static_cast<float>(kLumB), static_cast<float>(kLumG), static_cast<float>(kLumR)));
    ++seq_.steps.color_renders;
  } else {
    scene_.render_luminance(t, l);
    ++seq_.steps.luminance_renders;
  }
}

double Recorder::propose_step(double t, double& dt, bool& color, double& change) {
  const double t_end = config_.end_us();
  for (;;) {
    double tb = std::min(t_end, t + dt);
    if (t_end - tb < config_.dt_min_us) tb = t_end;  // no sliver step at the end
    color = windows_.any_overlaps(t, tb);
    render(tb, color, color_end_, lum_end_);
    change = events_.propose(lum_end_);
    if (change > limit_ && tb - t > config_.dt_min_us) {
      // Split: shrink toward the step that would just meet the limit.
      dt = std::max(config_.dt_min_us, (tb - t) * std::clamp(0.8 * limit_ / change, 0.1, 0.5));
      ++seq_.steps.rejected;
      continue;
    }
    return tb;
  }
}

void Recorder::integrate_rows(int k, double t_start, double t_end) {
  const int W = config_.width, H = config_.height;
  const double e = config_.exposure_us, span = t_end - t_start;
  if (acc_[k].empty()) acc_[k] = cv::Mat(H, W, CV_32FC3, cv::Scalar::all(0));
  const std::vector<double>& row_start = windows_.row_start[k];
  cv::parallel_for_(cv::Range(0, H), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      const double lo = std::max(t_start, row_start[y]), hi = std::min(t_end, row_start[y] + e);
      if (!(hi > lo)) continue;
      const double u = (0.5 * (lo + hi) - t_start) / span;
      const float wa = static_cast<float>((hi - lo) * (1.0 - u)), wb = static_cast<float>((hi - lo) * u);
      float* dst = acc_[k].ptr<float>(y);
      const float* pa = color_start_.ptr<float>(y);
      const float* pb = color_end_.ptr<float>(y);
      for (int i = 0; i < W * 3; ++i) dst[i] += wa * pa[i] + wb * pb[i];
    }
  });
}

void Recorder::run() {
  const double t_end = config_.end_us();
  double t = 0.0;
  bool color_start_valid = windows_.any_overlaps(0.0, 0.0);
  render(0.0, color_start_valid, color_start_, lum_start_);
  events_.reset(0.0, lum_start_);
  double dt = std::min(dt_max_, 100.0), min_dt = 1e300;
  while (t < t_end) {
    dt = std::min(dt, dt_max_);
    bool color = false;
    double change = 0;
    const double tb = propose_step(t, dt, color, change);
    if (change > limit_) ++seq_.steps.over_limit;
    // The previous step was luminance-only: this one needs color at its start.
    if (color && !color_start_valid) render(t, true, color_start_, lum_start_);
    events_.accept(tb);
    if (color)
      for (int k = 0; k < config_.frames; ++k)
        if (windows_.overlaps(k, t, tb)) integrate_rows(k, t, tb);
    min_dt = std::min(min_dt, tb - t);
    std::swap(color_start_, color_end_);
    std::swap(lum_start_, lum_end_);
    color_start_valid = color;
    // Next step: aim at 80% of the limit, growing at most 2x per step.
    const double step = tb - t;
    dt = step * std::clamp(change > 0 ? 0.8 * limit_ / change : 2.0, 0.5, 2.0);
    t = tb;
  }
  seq_.steps.samples = events_.stats().samples;
  seq_.steps.min_dt_us = min_dt;
  seq_.steps.mean_dt_us = t_end / std::max<uint64_t>(1, seq_.steps.samples);
  seq_.event_stats = events_.stats();
  seq_.events = events_.take_events();
  add_readout_artifacts(seq_.events, events_.params(), 0.0, t_end, seq_.event_stats);
  for (int k = 0; k < config_.frames; ++k) seq_.rs.push_back(finish_rs_frame(acc_[k], config_, k));
}
}  // namespace

SimulatedSequence simulate(const SimulationConfig& config, Scene& scene) {
  config.validate();
  if (scene.width() != config.width || scene.height() != config.height)
    throw UsageError("simulate: scene size " + std::to_string(scene.width()) + "x" + std::to_string(scene.height()) +
                " differs from the configured " + std::to_string(config.width) + "x" + std::to_string(config.height));
  SimulatedSequence seq;
  seq.width = config.width;
  seq.height = config.height;
  seq.scene = scene.describe();
  for (int k = 0; k < config.frames; ++k) seq.frame_t0_us.push_back(config.frame_t0_us(k));
  Recorder(config, scene, seq).run();
  add_ground_truth(config, scene, seq);
  return seq;
}

cv::Mat encode_image(const cv::Mat& linear_bgr, double gamma, int bit_depth, bool color) {
  if (linear_bgr.type() != CV_32FC3) throw InternalError("encode_image: expected a CV_32FC3 linear image");
  cv::Mat src = linear_bgr;
  if (!color)
    cv::transform(linear_bgr, src, cv::Matx13f(static_cast<float>(kLumB), static_cast<float>(kLumG), static_cast<float>(kLumR)));
  cv::Mat enc;
  cv::pow(cv::min(cv::max(src, 0.0), 1.0), 1.0 / gamma, enc);
  cv::Mat out;
  const double full = bit_depth == 16 ? 65535.0 : 255.0;
  enc.convertTo(out, bit_depth == 16 ? CV_16U : CV_8U, full);  // rounds to nearest, saturates
  return out;
}

nlohmann::json write_sequence(const SimulationConfig& config, const SimulatedSequence& seq, const std::string& dir) {
  std::error_code ec;
  fs::create_directories(fs::path(dir) / "rs", ec);
  if (ec) throw IoError("simulate: cannot create output folder '" + (fs::path(dir) / "rs").string() + "': " + ec.message());
  if (!seq.gt.empty()) {
    fs::create_directories(fs::path(dir) / "gs", ec);
    if (ec) throw IoError("simulate: cannot create output folder '" + (fs::path(dir) / "gs").string() + "': " + ec.message());
  }
  auto write_png = [&](const std::string& rel, const cv::Mat& linear) {
    const std::string path = (fs::path(dir) / rel).string();
    const cv::Mat img = encode_image(linear, config.gamma, config.bit_depth, config.color);
    if (!cv::imwrite(path, img)) throw IoError("simulate: cannot write image '" + path + "'");
  };
  nlohmann::json frames = nlohmann::json::array(), gt = nlohmann::json::array();
  for (size_t k = 0; k < seq.rs.size(); ++k) {
    char name[64];
    std::snprintf(name, sizeof name, "rs/%06zu.png", k);
    write_png(name, seq.rs[k]);
    frames.push_back({{"file", name}, {"t0_us", seq.frame_t0_us[k]}});
  }
  for (const GroundTruthFrame& g : seq.gt) {
    write_png(g.file, g.image);
    gt.push_back({{"file", g.file}, {"t_us", g.t_us}, {"frame", g.frame}, {"index", g.index}, {"tau", g.tau}});
  }
  std::string events_file;
  if (config.events_format == "h5" || config.events_format == "both") {
    write_events_hdf5((fs::path(dir) / "events.h5").string(), seq.events);
    events_file = "events.h5";
  }
  if (config.events_format == "txt" || config.events_format == "both") {
    write_events_text((fs::path(dir) / "events.txt").string(), seq.events);
    if (events_file.empty()) events_file = "events.txt";
  }
  nlohmann::json meta = {
      {"width", seq.width},
      {"height", seq.height},
      {"line_delay_us", config.line_delay_us},
      {"exposure_us", config.exposure_us},
      {"readout", config.readout},
      {"frames", frames},
      {"events", events_file},
      {"ground_truth", gt},
      {"source",
       {{"generator", "vkunroll simulate"},
        {"version", VKUNROLL_VERSION},
        {"preset", config.preset},
        {"seed", config.seed},
        {"settings", config.to_json()},
        {"scene", seq.scene},
        {"event_count", seq.events.size()},
        {"event_stats", seq.event_stats.to_json()},
        {"time_steps", seq.steps.to_json()},
        {"notes",
         "Synthetic. RS row y of frame k is exposed over [t0_k + r(y) * line_delay, + exposure], r(y) = y "
         "(top-down) or H-1-y (bottom-up), integrated in linear intensity; PNG = linear^(1/gamma). "
         "Ground truth is the sharp global-shutter image at t_us (tau > 1: between frames)."}}}};
  if (config.events_format == "both") meta["source"]["events_text"] = "events.txt";
  const std::string meta_path = (fs::path(dir) / "meta.json").string();
  std::ofstream f(meta_path, std::ios::binary | std::ios::trunc);
  if (!f) throw IoError("simulate: cannot write '" + meta_path + "'");
  f << meta.dump(2) << "\n";
  if (!f) throw IoError("simulate: error writing '" + meta_path + "'");
  return meta;
}

void set_texture(SimulationConfig& c, const std::string& texture) {
  try {
    c.texture = parse_texture_kind(texture);
  } catch (const Error&) {  // not a procedural name: an image file
    if (!std::ifstream(texture))
      throw InputMissingError("texture '" + texture + "' (" + opt("texture") + ") is neither checkerboard, bars, noise, text, mixed nor a readable image file");
    c.texture_file = texture;
  }
}

}  // namespace vkunroll::sim
