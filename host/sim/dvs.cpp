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
constexpr uint64_t kStreamOn = 0x0A11, kStreamOff = 0x0B22, kStreamLeak = 0x0C33, kStreamShot = 0x0D44;

// v2e's intensity-dependent photoreceptor bandwidth and shot-noise rate use the intensity in DN
// with a 20 DN floor: (I * 255 + 20) / 275, clipped to [0, 1].
inline double inten01(float linear) { return std::clamp((static_cast<double>(linear) * 255.0 + 20.0) / 275.0, 0.0, 1.0); }
}  // namespace

nlohmann::json EventSimParams::to_json() const {
  return {{"c_on", c_on},           {"c_off", c_off},         {"sigma", sigma},   {"c_min", c_min},
          {"refractory_us", refractory_us}, {"leak_hz", leak_hz}, {"shot_hz", shot_hz}, {"cutoff_hz", cutoff_hz},
          {"eps", eps},             {"seed", seed}};
}

nlohmann::json EventSimStats::to_json() const {
  return {{"on", on}, {"off", off}, {"shot", shot}, {"dropped_refractory", dropped_refractory}, {"samples", samples}};
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
    throw Error("unknown event preset '" + name + "': expected clean, realistic or noisy");
  }
  return p;
}

EventSimulator::EventSimulator(int width, int height, const EventSimParams& params)
    : width_(width), height_(height), params_(params) {
  if (width < 1 || height < 1 || width > 65535 || height > 65535)
    throw Error("event simulator: size " + std::to_string(width) + "x" + std::to_string(height) + " out of range");
  if (!(params.c_on > 0) || !(params.c_off > 0)) throw Error("event simulator: thresholds c_on and c_off must be > 0");
  if (!(params.c_min > 0)) throw Error("event simulator: c_min must be > 0");
  if (params.sigma < 0 || params.refractory_us < 0 || params.leak_hz < 0 || params.shot_hz < 0 || params.cutoff_hz < 0)
    throw Error("event simulator: sigma, refractory_us, leak_hz, shot_hz and cutoff_hz must be >= 0");
  if (!(params.eps > 0)) throw Error("event simulator: eps must be > 0 (log(eps + I))");
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
    throw Error("event simulator: luminance must be CV_32FC1 of " + std::to_string(width_) + "x" +
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
  log_prev_.copyTo(filt_);
  log_prev_.copyTo(ref_);
  const size_t n = static_cast<size_t>(width_) * height_;
  last_event_.assign(n, -1e300);
  next_shot_.assign(n, 1e300);
  shot_draws_.assign(n, 0);
  for (size_t i = 0; i < n; ++i) {
    float* ref = ref_.ptr<float>() + i;
    // Leak: random initial distance to the ON threshold, so leak events are not synchronized.
    if (params_.leak_hz > 0)
      *ref -= static_cast<float>(to_unit(hash3(params_.seed, kStreamLeak, i)) * c_on_.ptr<float>()[i]);
    if (params_.shot_hz > 0)
      next_shot_[i] = t_us - std::log(to_unit_open0(draw_shot(i))) / params_.shot_hz * 1e6;
  }
  t_ = t_us;
  started_ = true;
  proposed_ = false;
}

double EventSimulator::propose(const cv::Mat& luminance) {
  if (!started_) throw Error("event simulator: propose() before reset()");
  log_of(luminance, log_next_);
  luminance.copyTo(lum_next_);
  proposed_ = true;
  cv::Mat diff;
  cv::absdiff(log_next_, log_prev_, diff);
  double mx = 0;
  cv::minMaxLoc(diff, nullptr, &mx);
  return mx;
}

void EventSimulator::accept(double t_us) {
  if (!proposed_) throw Error("event simulator: accept() without a proposed sample");
  if (!(t_us > t_)) throw Error("event simulator: sample time " + std::to_string(t_us) + " us is not after " + std::to_string(t_) + " us");
  const double ta = t_, tb = t_us, dt = tb - ta;
  const double leak_drop_per_on = params_.leak_hz * dt * 1e-6;  // times c_on: reference drift this step
  const bool lowpass = params_.cutoff_hz > 0;
  const double refr = params_.refractory_us;

  // Photoreceptor update factor a = 1 - exp(-dt / tau(I)), tau = 1 / (2 pi f_c inten01(I)), so
  // a = 1 - exp(-k inten01) with k = 2 pi f_c dt: a 5th-order series for k <= 0.5 (error < 3e-5,
  // vectorizes), the exact exp() beyond.
  const double k_lp = kTwoPi * params_.cutoff_hz * dt * 1e-6;
  const bool series = k_lp <= 0.5;
  const float kf = static_cast<float>(k_lp), ldpo = static_cast<float>(leak_drop_per_on);
  // Rows are independent and each writes only its own buffers: deterministic under any threading.
  cv::parallel_for_(cv::Range(0, height_), [&](const cv::Range& rows) {
    std::vector<float> sa_buf(width_), sb_buf(width_);
    std::vector<uint8_t> flag(width_);
    for (int y = rows.start; y < rows.end; ++y) {
      std::vector<RawEvent>& out = row_events_[y];
      out.clear();
      uint64_t dropped = 0, shots = 0;
      const float* lp = log_prev_.ptr<float>(y);
      const float* ln = log_next_.ptr<float>(y);
      const float* ia = lum_prev_.ptr<float>(y);
      const float* ib = lum_next_.ptr<float>(y);
      float* filt = filt_.ptr<float>(y);
      float* ref = ref_.ptr<float>(y);
      const float* con = c_on_.ptr<float>(y);
      const float* coff = c_off_.ptr<float>(y);
      float* sa = sa_buf.data();
      float* sb = sb_buf.data();
      uint8_t* fl = flag.data();
      // Pass 1 (branch-free, vectorizable): filter, leak, and flag the pixels that cross a threshold.
      if (lowpass) {
        for (int x = 0; x < width_; ++x) {
          // First-order photoreceptor whose bandwidth grows with intensity (v2e's model).
          const float i01 = std::min(1.0f, std::max(0.0f, (ib[x] * 255.0f + 20.0f) * (1.0f / 275.0f)));
          const float xk = kf * i01;
          const float a = series ? xk * (1.0f - xk * (0.5f - xk * (1.0f / 6 - xk * (1.0f / 24 - xk * (1.0f / 120)))))
                                 : static_cast<float>(-std::expm1(-static_cast<double>(xk)));
          sa[x] = filt[x];
          sb[x] = sa[x] + a * (ln[x] - sa[x]);
          filt[x] = sb[x];
        }
      } else {
        for (int x = 0; x < width_; ++x) {
          sa[x] = lp[x];
          sb[x] = ln[x];
        }
      }
      for (int x = 0; x < width_; ++x) {
        const float r = ref[x] - ldpo * con[x];  // the reference drifts down: leak
        const float db = sb[x] - r;
        ref[x] = r;
        fl[x] = static_cast<uint8_t>((db >= con[x]) | (db <= -coff[x]));
      }
      bool shot_due = false;
      if (params_.shot_hz > 0) {
        const double* ns = next_shot_.data() + static_cast<size_t>(y) * width_;
        for (int x = 0; x < width_; ++x) shot_due |= ns[x] <= tb;
      }
      // Pass 2: the few pixels with events.
      for (int x = 0; x < width_; ++x) {
        if (!fl[x] && !shot_due) continue;
        const size_t i = static_cast<size_t>(y) * width_ + x;
        const double c_on = con[x], c_off = coff[x];
        double r = ref[x];
        const double da = sa[x] - (r + ldpo * con[x]), db = sb[x] - r;
        auto emit = [&](double t, int8_t p) {
          if (t - last_event_[i] < refr) {
            ++dropped;
            return;
          }
          last_event_[i] = t;
          out.push_back({std::llround(t), static_cast<uint16_t>(x), static_cast<uint16_t>(y), p});
        };
        if (fl[x]) {
          if (db >= c_on) {
            // Crossings of ref + c_on, ref + 2 c_on, ... along the linear segment, each at its own time.
            const int n = static_cast<int>(std::floor(db / c_on));
            for (int k = 1; k <= n; ++k) {
              const double u = std::clamp((k * c_on - da) / (db - da), 0.0, 1.0);
              emit(ta + u * dt, 1);
            }
            r += n * c_on;
          } else if (db <= -c_off) {
            const int n = static_cast<int>(std::floor(-db / c_off));
            for (int k = 1; k <= n; ++k) {
              const double u = std::clamp((-k * c_off - da) / (db - da), 0.0, 1.0);
              emit(ta + u * dt, -1);
            }
            r -= n * c_off;
          }
        }
        // Shot noise: Poisson candidates at the dark rate, thinned to v2e's intensity dependence
        // (rate x (1 - 0.75 intensity)); a noise event resets the pixel to the current level.
        while (next_shot_[i] <= tb) {
          const double ts = next_shot_[i];
          const double u_accept = to_unit(draw_shot(i));
          const double u_pol = to_unit(draw_shot(i));
          const double frac = (ts - ta) / dt;
          const float inten = static_cast<float>(ia[x] + frac * (ib[x] - ia[x]));
          if (u_accept < 1.0 - 0.75 * inten01(inten)) {
            const size_t before = out.size();
            emit(ts, u_pol < 0.5 ? int8_t{1} : int8_t{-1});
            if (out.size() > before) ++shots;
            r = sb[x];
          }
          next_shot_[i] = ts - std::log(to_unit_open0(draw_shot(i))) / params_.shot_hz * 1e6;
        }
        ref[x] = static_cast<float>(r);
      }
      row_dropped_[y] = dropped;
      row_shot_[y] = shots;
    }
  });

  // Gather in a fixed order and sort by (t, y, x, p): independent of how rows were scheduled.
  batch_.clear();
  for (int y = 0; y < height_; ++y) {
    batch_.insert(batch_.end(), row_events_[y].begin(), row_events_[y].end());
    stats_.dropped_refractory += row_dropped_[y];
    stats_.shot += row_shot_[y];
  }
  std::sort(batch_.begin(), batch_.end(), [](const RawEvent& a, const RawEvent& b) {
    if (a.t != b.t) return a.t < b.t;
    if (a.y != b.y) return a.y < b.y;
    if (a.x != b.x) return a.x < b.x;
    return a.p < b.p;
  });
  for (const RawEvent& e : batch_) {
    events_.push(e.t, e.x, e.y, e.p);
    (e.p > 0 ? stats_.on : stats_.off) += 1;
  }
  std::swap(log_prev_, log_next_);
  std::swap(lum_prev_, lum_next_);
  if (!lowpass) log_prev_.copyTo(filt_);
  t_ = tb;
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

}  // namespace vkunroll::sim
