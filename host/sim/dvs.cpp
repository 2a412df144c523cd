#include "vkunroll/host/sim/dvs.hpp"

#include <algorithm>
#include <cmath>

#include <opencv2/core/utility.hpp>

#include "vkunroll/host/sim/random.hpp"
#include "vkunroll/base/error.hpp"

namespace vkunroll::sim {

namespace {
constexpr double kTwoPi = 6.283185307179586;
// Random streams (second hash argument) so that each use of randomness is independent.
constexpr uint64_t kStreamOn = 0x0A11, kStreamOff = 0x0B22, kStreamLeak = 0x0C33, kStreamShot = 0x0D44,
                   kStreamHot = 0x0E55, kStreamJitter = 0x0F66;

// v2e's intensity-dependent photoreceptor bandwidth and shot-noise rate use the intensity in DN
// with a 20 DN floor: (I * 255 + 20) / 275, clipped to [0, 1].
inline double intensity01(float linear) { return std::clamp((static_cast<double>(linear) * 255.0 + 20.0) / 275.0, 0.0, 1.0); }

// The stream's order, (t, y, x, p): the same bytes under any threading and any artefacts.
template <class Event>
bool before(const Event& a, const Event& b) {
  if (a.t != b.t) return a.t < b.t;
  if (a.y != b.y) return a.y < b.y;
  if (a.x != b.x) return a.x < b.x;
  return a.p < b.p;
}
}  // namespace

nlohmann::json EventSimParams::to_json() const {
  return {{"c_on", c_on},           {"c_off", c_off},         {"sigma", sigma},   {"c_min", c_min},
          {"refractory_us", refractory_us}, {"leak_hz", leak_hz}, {"shot_hz", shot_hz}, {"cutoff_hz", cutoff_hz},
          {"eps", eps},             {"hot_fraction", hot_fraction}, {"hot_hz", hot_hz}, {"jitter_us", jitter_us},
          {"seed", seed}};
}

nlohmann::json EventSimStats::to_json() const {
  return {{"on", on},   {"off", off}, {"shot", shot}, {"hot", hot}, {"dropped_refractory", dropped_refractory},
          {"samples", samples}};
}

EventSimParams event_preset(const std::string& name) {
  EventSimParams p;
  if (name == "clean") {
    // Ideal sensor: every threshold crossing, exact thresholds, no noise, no bandwidth limit.
    p.c_on = p.c_off = 0.2;
  } else if (name == "realistic") {
    // DAVIS346 at default biases, indoor light (see docs/simulator.md for the sources).
    p.c_on = 0.2;
    p.c_off = 0.25;
    p.sigma = 0.03;
    p.refractory_us = 300.0;
    p.leak_hz = 0.1;
    p.shot_hz = 0.5;
    p.cutoff_hz = 300.0;
  } else if (name == "noisy") {
    // v2e's "noisy" parameter set: low light, strong mismatch, slow photoreceptor.
    p.c_on = p.c_off = 0.2;
    p.sigma = 0.05;
    p.refractory_us = 500.0;
    p.leak_hz = 0.1;
    p.shot_hz = 5.0;
    p.cutoff_hz = 30.0;
  } else {
    throw UsageError("unknown event preset '" + name + "': expected clean, realistic or noisy");
  }
  return p;
}

EventSimulator::EventSimulator(int width, int height, const EventSimParams& params)
    : width_(width), height_(height), params_(params) {
  if (width < 1 || height < 1 || width > 65535 || height > 65535)
    throw UsageError("event simulator: size " + std::to_string(width) + "x" + std::to_string(height) + " out of range");
  if (!(params.c_on > 0) || !(params.c_off > 0)) throw UsageError("event simulator: thresholds c_on and c_off must be > 0");
  if (!(params.c_min > 0)) throw UsageError("event simulator: c_min must be > 0");
  if (params.sigma < 0 || params.refractory_us < 0 || params.leak_hz < 0 || params.shot_hz < 0 || params.cutoff_hz < 0)
    throw UsageError("event simulator: sigma, refractory_us, leak_hz, shot_hz and cutoff_hz must be >= 0");
  if (!(params.eps > 0)) throw UsageError("event simulator: eps must be > 0 (log(eps + I))");
  if (!(params.hot_fraction >= 0 && params.hot_fraction <= 1) || !(params.hot_hz >= 0) || !(params.jitter_us >= 0))
    throw UsageError("event simulator: hot_fraction must be in [0, 1], hot_hz and jitter_us >= 0");
  events_.width = width;
  events_.height = height;
  c_on_.create(height, width, CV_32FC1);
  c_off_.create(height, width, CV_32FC1);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      const uint64_t i = static_cast<uint64_t>(y) * width + x;
      double on = params.c_on, off = params.c_off;
      if (params.sigma > 0) {
        on += params.sigma * normal_from(hash3(params.seed, kStreamOn, 2 * i), hash3(params.seed, kStreamOn, 2 * i + 1));
        off += params.sigma * normal_from(hash3(params.seed, kStreamOff, 2 * i), hash3(params.seed, kStreamOff, 2 * i + 1));
      }
      c_on_.at<float>(y, x) = static_cast<float>(std::max(params.c_min, on));
      c_off_.at<float>(y, x) = static_cast<float>(std::max(params.c_min, off));
    }
  row_events_.resize(height);
  row_dropped_.assign(height, 0);
  row_shot_.assign(height, 0);
}

void EventSimulator::log_of(const cv::Mat& luminance, cv::Mat& out) const {
  if (luminance.type() != CV_32FC1 || luminance.rows != height_ || luminance.cols != width_)
    throw InternalError("event simulator: luminance must be CV_32FC1 of " + std::to_string(width_) + "x" +
                std::to_string(height_) + ", got " + std::to_string(luminance.cols) + "x" + std::to_string(luminance.rows) +
                " type " + std::to_string(luminance.type()));
  cv::max(luminance, 0.0, out);
  out += params_.eps;
  cv::log(out, out);
}

uint64_t EventSimulator::draw_shot(size_t i) {
  return hash3(params_.seed, kStreamShot, (static_cast<uint64_t>(i) << 32) | shot_draws_[i]++);
}

void EventSimulator::reset(double t_us, const cv::Mat& luminance) {
  log_of(luminance, log_prev_);
  luminance.copyTo(lum_prev_);
  log_prev_.copyTo(filtered_log_);
  log_prev_.copyTo(reference_);
  const size_t n = static_cast<size_t>(width_) * height_;
  last_event_.assign(n, -1e300);
  next_shot_.assign(n, 1e300);
  shot_draws_.assign(n, 0);
  for (size_t i = 0; i < n; ++i) {
    float* reference = reference_.ptr<float>() + i;
    // Leak: random initial distance to the ON threshold, so leak events are not synchronized.
    if (params_.leak_hz > 0)
      *reference -= static_cast<float>(to_unit(hash3(params_.seed, kStreamLeak, i)) * c_on_.ptr<float>()[i]);
    if (params_.shot_hz > 0)
      next_shot_[i] = t_us - std::log(to_unit_open0(draw_shot(i))) / params_.shot_hz * 1e6;
  }
  t_ = t_us;
  started_ = true;
  proposed_ = false;
}

double EventSimulator::propose(const cv::Mat& luminance) {
  if (!started_) throw InternalError("event simulator: propose() before reset()");
  log_of(luminance, log_next_);
  luminance.copyTo(lum_next_);
  proposed_ = true;
  cv::Mat change;
  cv::absdiff(log_next_, log_prev_, change);
  double largest = 0;
  cv::minMaxLoc(change, nullptr, &largest);
  return largest;
}

EventSimulator::Step EventSimulator::step_to(double t_end) const {
  Step step;
  step.t_start = t_;
  step.t_end = t_end;
  step.duration = t_end - t_;
  step.leak_per_on_threshold = static_cast<float>(params_.leak_hz * step.duration * 1e-6);
  step.lowpass = params_.cutoff_hz > 0;
  // Photoreceptor update factor a = 1 - exp(-dt / tau(I)), tau = 1 / (2 pi f_c intensity01(I)), so
  // a = 1 - exp(-k intensity01) with k = 2 pi f_c dt: a 5th-order series for k <= 0.5 (error < 3e-5,
  // vectorizes), the exact exp() beyond.
  const double exponent = kTwoPi * params_.cutoff_hz * step.duration * 1e-6;
  step.series_update = exponent <= 0.5;
  step.bandwidth_exponent = static_cast<float>(exponent);
  return step;
}

// Pass 1a (branch-free, vectorizable): the row's log levels at the step's ends, through the
// first-order photoreceptor whose bandwidth grows with intensity (v2e's model) when it is limited.
void EventSimulator::photoreceptor_row(int y, const Step& step, RowLevels& levels) {
  float* at_start = levels.at_start.data();
  float* at_end = levels.at_end.data();
  const float* log_prev = log_prev_.ptr<float>(y);
  const float* log_next = log_next_.ptr<float>(y);
  if (!step.lowpass) {
    for (int x = 0; x < width_; ++x) {
      at_start[x] = log_prev[x];
      at_end[x] = log_next[x];
    }
    return;
  }
  const float* lum_next = lum_next_.ptr<float>(y);
  float* filtered = filtered_log_.ptr<float>(y);
  const float k = step.bandwidth_exponent;
  for (int x = 0; x < width_; ++x) {
    const float intensity = std::min(1.0f, std::max(0.0f, (lum_next[x] * 255.0f + 20.0f) * (1.0f / 275.0f)));
    const float kx = k * intensity;
    const float update = step.series_update
                             ? kx * (1.0f - kx * (0.5f - kx * (1.0f / 6 - kx * (1.0f / 24 - kx * (1.0f / 120)))))
                             : static_cast<float>(-std::expm1(-static_cast<double>(kx)));
    at_start[x] = filtered[x];
    at_end[x] = at_start[x] + update * (log_next[x] - at_start[x]);
    filtered[x] = at_end[x];
  }
}

// Pass 1b (vectorizable): the reference drifts down (leak); flag the pixels whose level at the
// step's end crosses a threshold.
void EventSimulator::leak_and_flag_row(int y, const Step& step, RowLevels& levels) {
  float* reference = reference_.ptr<float>(y);
  const float* on_threshold = c_on_.ptr<float>(y);
  const float* off_threshold = c_off_.ptr<float>(y);
  const float* at_end = levels.at_end.data();
  uint8_t* crosses = levels.crosses.data();
  for (int x = 0; x < width_; ++x) {
    const float drifted = reference[x] - step.leak_per_on_threshold * on_threshold[x];
    const float change = at_end[x] - drifted;
    reference[x] = drifted;
    crosses[x] = static_cast<uint8_t>((change >= on_threshold[x]) | (change <= -off_threshold[x]));
  }
}

bool EventSimulator::shot_due_in_row(int y, double t_end) const {
  if (!(params_.shot_hz > 0)) return false;
  const double* next_shot = next_shot_.data() + static_cast<size_t>(y) * width_;
  bool due = false;
  for (int x = 0; x < width_; ++x) due |= next_shot[x] <= t_end;
  return due;
}

// An event of pixel (x, y) at t, unless it falls within the refractory period of the pixel's last.
void EventSimulator::emit(RowEvents& row, int x, int y, double t_us, int8_t polarity) {
  const size_t i = static_cast<size_t>(y) * width_ + x;
  if (t_us - last_event_[i] < params_.refractory_us) {
    ++row.dropped_refractory;
    return;
  }
  last_event_[i] = t_us;
  row.events.push_back({std::llround(t_us), static_cast<uint16_t>(x), static_cast<uint16_t>(y), polarity});
}

// Crossings of reference + c_on, reference + 2 c_on, ... (or the OFF ones) along the linear segment
// of the level's change from the reference, each at its own time. Returns the new reference.
double EventSimulator::emit_threshold_crossings(int x, int y, const Step& step, double change_at_start,
                                                double change_at_end, double reference, RowEvents& row) {
  const double c_on = c_on_.ptr<float>(y)[x], c_off = c_off_.ptr<float>(y)[x];
  if (change_at_end >= c_on) {
    const int crossings = static_cast<int>(std::floor(change_at_end / c_on));
    for (int k = 1; k <= crossings; ++k) {
      const double u = std::clamp((k * c_on - change_at_start) / (change_at_end - change_at_start), 0.0, 1.0);
      emit(row, x, y, step.t_start + u * step.duration, 1);
    }
    return reference + crossings * c_on;
  }
  if (change_at_end <= -c_off) {
    const int crossings = static_cast<int>(std::floor(-change_at_end / c_off));
    for (int k = 1; k <= crossings; ++k) {
      const double u = std::clamp((-k * c_off - change_at_start) / (change_at_end - change_at_start), 0.0, 1.0);
      emit(row, x, y, step.t_start + u * step.duration, -1);
    }
    return reference - crossings * c_off;
  }
  return reference;
}

// Shot noise: Poisson candidates at the dark rate, thinned to v2e's intensity dependence
// (rate x (1 - 0.75 intensity)); a noise event resets the pixel to the current level. Returns the
// new reference.
double EventSimulator::emit_shot_noise(int x, int y, const Step& step, float level_end, double reference,
                                       RowEvents& row) {
  const size_t i = static_cast<size_t>(y) * width_ + x;
  const float lum_prev = lum_prev_.ptr<float>(y)[x], lum_next = lum_next_.ptr<float>(y)[x];
  while (next_shot_[i] <= step.t_end) {
    const double t_shot = next_shot_[i];
    const double u_accept = to_unit(draw_shot(i));
    const double u_polarity = to_unit(draw_shot(i));
    const double fraction = (t_shot - step.t_start) / step.duration;
    const float lum = static_cast<float>(lum_prev + fraction * (lum_next - lum_prev));
    if (u_accept < 1.0 - 0.75 * intensity01(lum)) {
      const size_t before = row.events.size();
      emit(row, x, y, t_shot, u_polarity < 0.5 ? int8_t{1} : int8_t{-1});
      if (row.events.size() > before) ++row.shot;
      reference = level_end;
    }
    next_shot_[i] = t_shot - std::log(to_unit_open0(draw_shot(i))) / params_.shot_hz * 1e6;
  }
  return reference;
}

// Pass 2: the few pixels with events (a crossing, or a shot-noise candidate due in the row).
void EventSimulator::emit_row(int y, const Step& step, const RowLevels& levels, bool shot_due, RowEvents& row) {
  float* reference = reference_.ptr<float>(y);
  const float* on_threshold = c_on_.ptr<float>(y);
  for (int x = 0; x < width_; ++x) {
    const bool crosses = levels.crosses[x] != 0;
    if (!crosses && !shot_due) continue;
    double r = reference[x];
    if (crosses) {
      // The change from the reference at the step's start (before this step's leak) and end.
      const double change_at_start = levels.at_start[x] - (r + step.leak_per_on_threshold * on_threshold[x]);
      const double change_at_end = levels.at_end[x] - r;
      r = emit_threshold_crossings(x, y, step, change_at_start, change_at_end, r, row);
    }
    r = emit_shot_noise(x, y, step, levels.at_end[x], r, row);
    reference[x] = static_cast<float>(r);
  }
}

// Gather in a fixed order and sort by (t, y, x, p): independent of how rows were scheduled.
void EventSimulator::gather_events() {
  step_events_.clear();
  for (int y = 0; y < height_; ++y) {
    step_events_.insert(step_events_.end(), row_events_[y].begin(), row_events_[y].end());
    stats_.dropped_refractory += row_dropped_[y];
    stats_.shot += row_shot_[y];
  }
  std::sort(step_events_.begin(), step_events_.end(), before<RawEvent>);
  for (const RawEvent& e : step_events_) {
    events_.push(e.t, e.x, e.y, e.p);
    (e.p > 0 ? stats_.on : stats_.off) += 1;
  }
}

void EventSimulator::accept(double t_us) {
  if (!proposed_) throw InternalError("event simulator: accept() without a proposed sample");
  if (!(t_us > t_)) throw InternalError("event simulator: sample time " + std::to_string(t_us) + " us is not after " + std::to_string(t_) + " us");
  const Step step = step_to(t_us);
  // Rows are independent and each writes only its own buffers: deterministic under any threading.
  cv::parallel_for_(cv::Range(0, height_), [&](const cv::Range& rows) {
    RowLevels levels{std::vector<float>(width_), std::vector<float>(width_), std::vector<uint8_t>(width_)};
    for (int y = rows.start; y < rows.end; ++y) {
      RowEvents row{row_events_[y]};
      row.events.clear();
      photoreceptor_row(y, step, levels);
      leak_and_flag_row(y, step, levels);
      emit_row(y, step, levels, shot_due_in_row(y, step.t_end), row);
      row_dropped_[y] = row.dropped_refractory;
      row_shot_[y] = row.shot;
    }
  });
  gather_events();
  std::swap(log_prev_, log_next_);
  std::swap(lum_prev_, lum_next_);
  if (!step.lowpass) log_prev_.copyTo(filtered_log_);
  t_ = t_us;
  proposed_ = false;
  ++stats_.samples;
}

EventStream EventSimulator::take_events() {
  EventStream out = std::move(events_);
  events_ = EventStream{};
  events_.width = width_;
  events_.height = height_;
  return out;
}

namespace {
struct StreamEvent {
  int64_t t;
  uint16_t x, y;
  int8_t p;
};

// Hot pixels: about hot_fraction of the pixels, each with its own ON share and Poisson times.
void append_hot_pixels(std::vector<StreamEvent>& out, const EventStream& shape, const EventSimParams& p, double t0,
                       double t1, EventSimStats& stats) {
  if (!(p.hot_fraction > 0 && p.hot_hz > 0) || !(t1 > t0)) return;
  const uint64_t pixels = static_cast<uint64_t>(shape.width) * shape.height;
  for (uint64_t i = 0; i < pixels; ++i) {
    if (!(to_unit(hash3(p.seed, kStreamHot, 4 * i)) < p.hot_fraction)) continue;
    const double on_share = to_unit(hash3(p.seed, kStreamHot, 4 * i + 1));
    const uint16_t x = static_cast<uint16_t>(i % shape.width), y = static_cast<uint16_t>(i / shape.width);
    uint64_t draw = 0;
    auto next = [&] { return hash3(p.seed ^ (i + 1) * 0x9E3779B97F4A7C15ull, kStreamHot, draw++); };
    for (double t = t0 - std::log(to_unit_open0(next())) / p.hot_hz * 1e6; t < t1;
         t -= std::log(to_unit_open0(next())) / p.hot_hz * 1e6) {
      out.push_back({std::llround(t), x, y, to_unit(next()) < on_share ? int8_t{1} : int8_t{-1}});
      ++stats.hot;
      (out.back().p > 0 ? stats.on : stats.off) += 1;
    }
  }
}
}  // namespace

void add_readout_artifacts(EventStream& events, const EventSimParams& p, double t_begin_us, double t_end_us,
                           EventSimStats& stats) {
  const bool hot = p.hot_fraction > 0 && p.hot_hz > 0, jitter = p.jitter_us > 0;
  if (!hot && !jitter) return;
  std::vector<StreamEvent> all(events.size());
  for (size_t k = 0; k < events.size(); ++k) all[k] = {events.t[k], events.x[k], events.y[k], events.p[k]};
  append_hot_pixels(all, events, p, t_begin_us, t_end_us, stats);
  if (jitter) {
    // Clamped into the stream's interval so that every event stays inside the recording.
    const int64_t lo = static_cast<int64_t>(std::ceil(t_begin_us)), hi = static_cast<int64_t>(std::ceil(t_end_us)) - 1;
    for (size_t k = 0; k < all.size(); ++k) {
      const double dt = p.jitter_us * normal_from(hash3(p.seed, kStreamJitter, 2 * k), hash3(p.seed, kStreamJitter, 2 * k + 1));
      all[k].t = std::clamp<int64_t>(all[k].t + std::llround(dt), lo, std::max(lo, hi));
    }
  }
  std::sort(all.begin(), all.end(), before<StreamEvent>);
  EventStream out;
  out.width = events.width;
  out.height = events.height;
  out.reserve(all.size());
  for (const StreamEvent& e : all) out.push(e.t, e.x, e.y, e.p);
  events = std::move(out);
}

}  // namespace vkunroll::sim
