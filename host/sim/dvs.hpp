// DVS event generation from a sequence of luminance images (ESIM / v2e style): per-pixel log
// intensity with a memorized reference level, linear interpolation between samples, per-pixel
// ON/OFF thresholds with mismatch, optional photoreceptor low-pass, refractory period, leak and
// shot noise. Every event carries its own interpolated crossing time (rounded to integer us).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "vkunroll/base/events.hpp"

namespace vkunroll::sim {

struct EventSimParams {
  double c_on = 0.2;            // mean ON threshold, log-intensity units
  double c_off = 0.2;           // mean OFF threshold
  double sigma = 0.0;           // per-pixel threshold mismatch (std, absolute log units, like v2e's sigma_thres)
  double c_min = 0.01;          // thresholds drawn below this are clipped to it
  double refractory_us = 0.0;   // after an event a pixel cannot fire for this long (changes still tracked)
  double leak_hz = 0.0;         // ON "leak" events per second per pixel (reference drifts down)
  double shot_hz = 0.0;         // shot-noise events per second per pixel in the dark (ON and OFF halves)
  double cutoff_hz = 0.0;       // photoreceptor 3 dB bandwidth at full intensity; 0 = unlimited
  double eps = 0.05;            // log(eps + I): dark floor of the log response (I linear in [0, 1])
  // Readout artefacts, applied to the whole stream after simulation (add_readout_artifacts):
  double hot_fraction = 0.0;    // fraction of pixels that are hot (fire regardless of the signal)
  double hot_hz = 0.0;          // each hot pixel's event rate (Poisson, its own fixed ON share)
  double jitter_us = 0.0;       // std of the Gaussian timestamp jitter of every event
  uint64_t seed = 1;            // thresholds, noise and leak phases

  nlohmann::json to_json() const;
};

// Named parameter sets: "clean", "realistic", "noisy" (values and reasons in docs/simulator.md).
EventSimParams event_preset(const std::string& name);

struct EventSimStats {
  uint64_t on = 0, off = 0;              // emitted events by polarity (all causes)
  uint64_t shot = 0;                     // of which shot noise
  uint64_t hot = 0;                      // of which hot-pixel events
  uint64_t dropped_refractory = 0;       // threshold crossings suppressed by the refractory period
  uint64_t samples = 0;                  // luminance samples processed (after the first)
  nlohmann::json to_json() const;
};

// Hot pixels and timestamp jitter on a finished stream covering [t_begin, t_end) us: each hot
// pixel (drawn by the seed) adds Poisson events at hot_hz, then every timestamp moves by
// N(0, jitter_us) clamped into the interval, and the stream is re-sorted by (t, y, x, p).
// Deterministic for a given stream and seed; counts the hot events into `stats`.
void add_readout_artifacts(EventStream& events, const EventSimParams& params, double t_begin_us, double t_end_us,
                           EventSimStats& stats);

class EventSimulator {
 public:
  EventSimulator(int width, int height, const EventSimParams& params);

  // Starts at time t with the given luminance (CV_32FC1, linear): reference levels are set to it.
  void reset(double t_us, const cv::Mat& luminance);
  // Prepares a candidate next sample and returns the largest |change of log(eps + I)| of any
  // pixel since the last accepted sample (what an adaptive time step controls).
  double propose(const cv::Mat& luminance);
  // Accepts the proposed sample at time t (> the last time) and emits the events in between.
  void accept(double t_us);
  // propose + accept.
  void advance(double t_us, const cv::Mat& luminance) {
    propose(luminance);
    accept(t_us);
  }

  double time_us() const { return t_; }
  const EventStream& events() const { return events_; }
  EventStream take_events();
  const EventSimStats& stats() const { return stats_; }
  const EventSimParams& params() const { return params_; }
  // The per-pixel thresholds actually used (CV_32FC1), for tests and diagnostics.
  cv::Mat thresholds_on() const { return c_on_; }
  cv::Mat thresholds_off() const { return c_off_; }

 private:
  struct RawEvent {
    int64_t t;
    uint16_t x, y;
    int8_t p;
  };
  // What one accepted step (last sample -> t_end) is, the same for every row.
  struct Step {
    double t_start = 0, t_end = 0, duration = 0;
    float leak_per_on_threshold = 0;  // reference drift this step, in units of the pixel's ON threshold
    bool lowpass = false;             // photoreceptor bandwidth limited (cutoff_hz > 0)
    bool series_update = false;       // the low-pass factor from its series (exact exp() beyond)
    float bandwidth_exponent = 0;     // 2 pi f_c dt: the low-pass exponent at full intensity
  };
  // One row's output of a step: its events and what it counted.
  struct RowEvents {
    std::vector<RawEvent>& events;
    uint64_t dropped_refractory = 0, shot = 0;
  };
  // One row's log levels at the step's start and end (after the photoreceptor), and which pixels
  // cross a threshold; scratch reused by the rows a thread runs.
  struct RowLevels {
    std::vector<float> at_start, at_end;
    std::vector<uint8_t> crosses;
  };
  void log_of(const cv::Mat& luminance, cv::Mat& out) const;
  // The next random draw of pixel i's shot-noise stream (each pixel has its own counter).
  uint64_t draw_shot(size_t i);
  Step step_to(double t_end) const;
  void photoreceptor_row(int y, const Step& step, RowLevels& levels);
  void leak_and_flag_row(int y, const Step& step, RowLevels& levels);
  bool shot_due_in_row(int y, double t_end) const;
  void emit_row(int y, const Step& step, const RowLevels& levels, bool shot_due, RowEvents& row);
  double emit_threshold_crossings(int x, int y, const Step& step, double level_start, double level_end,
                                  double reference, RowEvents& row);
  double emit_shot_noise(int x, int y, const Step& step, float level_end, double reference, RowEvents& row);
  void emit(RowEvents& row, int x, int y, double t_us, int8_t polarity);
  void gather_events();

  int width_, height_;
  EventSimParams params_;
  bool started_ = false;
  bool proposed_ = false;
  double t_ = 0.0;
  cv::Mat log_prev_, log_next_;          // raw log intensity at the last / proposed sample
  cv::Mat lum_prev_, lum_next_;          // linear luminance (noise and bandwidth depend on it)
  cv::Mat filtered_log_;                 // low-pass-filtered log intensity (when cutoff_hz > 0)
  cv::Mat reference_;                    // memorized reference level per pixel
  cv::Mat c_on_, c_off_;                 // per-pixel thresholds
  std::vector<double> last_event_;       // per-pixel time of the last emitted event
  std::vector<double> next_shot_;        // per-pixel time of the next shot-noise candidate
  std::vector<uint32_t> shot_draws_;     // per-pixel counter of random draws
  std::vector<std::vector<RawEvent>> row_events_;
  std::vector<uint64_t> row_dropped_, row_shot_;
  std::vector<RawEvent> step_events_;    // one step's events of every row, sorted
  EventStream events_;
  EventSimStats stats_;
};

}  // namespace vkunroll::sim
