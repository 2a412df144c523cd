// A whole simulated recording: rolling-shutter frames integrated row by row over their exposure
// windows, sharp global-shutter ground truth at chosen instants, and the event stream, all from
// one scene; written in the generic sequence layout (docs/simulator.md, sequence-format.md).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "vkunroll/base/events.hpp"
#include "vkunroll/host/sim/dvs.hpp"
#include "vkunroll/host/sim/scene.hpp"

namespace vkunroll::sim {

// Noise of the frame sensor, added to the integrated linear image (intensity 1 = full well).
struct FrameNoiseParams {
  double full_well_e = 0.0;  // electrons at intensity 1: photon shot noise std = sqrt(I * fw) / fw; 0 = none
  double read_noise = 0.0;   // Gaussian read noise std, fraction of full scale
  nlohmann::json to_json() const;
};

struct SimulationConfig {
  std::string preset = "realistic";   // clean | realistic | noisy: event and frame noise parameters
  uint64_t seed = 1;
  // Sensor and timing (defaults: DAVIS346-sized, skew clearly visible).
  int width = 346, height = 260;
  int frames = 10;
  double fps = 20.0;
  double line_delay_us = 100.0;       // row y starts line_delay later than row y-1 (25.9 ms readout)
  double exposure_us = 3000.0;
  std::string readout = "top-down";   // or "bottom-up"
  double lead_in_us = 10000.0;        // events start this long before frame 0 (targets before t0 are legal)
  // Ground truth: `gt_per_frame` instants per frame period, at t0_k + (j + 0.5) / M * period: some
  // inside the frame's exposure span, some between frames.
  int gt_per_frame = 5;
  // Scene.
  MotionKind motion = MotionKind::Mixed;
  TextureKind texture = TextureKind::Mixed;
  std::string texture_file;
  int sprites = 2;
  double speed_scale = 1.0;
  double flicker_amplitude = 0.0, flicker_hz = 100.0;
  int supersample = 1;
  // Output encoding.
  double gamma = 2.2;                 // PNG value = linear^(1/gamma); textures are linearized with it
  int bit_depth = 8;                  // 8 or 16
  bool color = true;                  // 3-channel PNG (what the network expects) or gray
  std::string events_format = "h5";   // h5 | txt | both
  // Physics.
  EventSimParams events;              // from the preset unless overridden; simulate() uses `seed`, not events.seed
  FrameNoiseParams frame_noise;
  double step_fraction = 0.5;         // adaptive step: no pixel's log intensity moves > this x min(C)
  double dt_min_us = 1.0, dt_max_us = 1000.0;

  double frame_period_us() const { return 1e6 / fps; }
  double frame_t0_us(int k) const { return lead_in_us + k * frame_period_us(); }
  // Exposure start of row y of frame k (readout direction applied).
  double row_start_us(int k, int y) const {
    return frame_t0_us(k) + (readout == "bottom-up" ? height - 1 - y : y) * line_delay_us;
  }
  double end_us() const { return frame_t0_us(frames); }  // events cover [0, end)
  void validate() const;               // throws Error naming the offending setting
  nlohmann::json to_json() const;
};

// The defaults with the preset's event and frame noise parameters filled in.
SimulationConfig simulation_preset(const std::string& preset);

// The background texture: a procedural kind by name, else an image file (InputMissingError naming
// `texture` when it is neither). Used by `vkunroll simulate`, `vkunroll demo` and Python's simulate.
void set_texture(SimulationConfig& c, const std::string& texture);

struct GroundTruthFrame {
  int frame = 0;        // the RS frame period it belongs to
  int index = 0;        // instant index within that period
  double t_us = 0;
  double tau = 0;       // (t - start[0]) / (end[H-1] - start[0]) of that frame; > 1 is between frames
  cv::Mat image;        // CV_32FC3 linear
  std::string file;     // relative path in the written layout
};

struct TimeStepStats {
  uint64_t samples = 0;          // accepted time samples
  uint64_t rejected = 0;         // proposed steps that moved some pixel too far and were split
  uint64_t over_limit = 0;       // accepted at dt_min although some pixel still moved too far
  uint64_t color_renders = 0, luminance_renders = 0;
  double min_dt_us = 0, mean_dt_us = 0;
  nlohmann::json to_json() const;
};

struct SimulatedSequence {
  int width = 0, height = 0;
  std::vector<double> frame_t0_us;
  std::vector<cv::Mat> rs;                 // CV_32FC3 linear, noise applied, clipped to [0, 1]
  std::vector<GroundTruthFrame> gt;
  EventStream events;
  EventSimStats event_stats;
  TimeStepStats steps;
  nlohmann::json scene;                    // Scene::describe()
};

// Simulates the configured sequence; `scene` overrides the scene built from the config.
SimulatedSequence simulate(const SimulationConfig& config);
SimulatedSequence simulate(const SimulationConfig& config, Scene& scene);

// Linear image -> 8/16-bit PNG-ready image (BGR or gray) with the output gamma.
cv::Mat encode_image(const cv::Mat& linear_bgr, double gamma, int bit_depth, bool color);

// Writes rs/, gs/, events.h5 and/or events.txt, meta.json under `dir` (created if needed).
// Returns the meta.json it wrote.
nlohmann::json write_sequence(const SimulationConfig& config, const SimulatedSequence& seq, const std::string& dir);

}  // namespace vkunroll::sim
