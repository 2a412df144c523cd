// `vkunroll unroll`: a recording (sequence folder) -> GS frames at chosen instants, with the
// learned model (SelfUnroll-S/-M) or the weight-free physics unroller, streaming frame by frame.
#pragma once
#include <cstdint>
#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "vkunroll/host/events/sequence.hpp"

namespace vkunroll {

struct UnrollOptions {
  std::string sequence;          // folder
  SequenceOptions sequence_options;
  std::string out_dir;
  std::string model_path;        // safetensors; empty: physics
  // s | m | physics | auto (M when the next frame exists, else S; physics without model) | choose (per
  // target: S when t* lies in the frame's exposure span, M between frames when the next frame exists)
  std::string mode = "auto";
  std::string times = "0.5";     // normalized targets per frame ("0:1:9", "-0.25,0.5,1.25"), or "gt"
  std::string times_us;          // absolute targets (µs); each goes to the frame whose span holds it
  std::string frames;            // "A:B" (inclusive) or a list; empty: all frames
  std::string channel_order;     // rgb | bgr; empty: the model's
  std::string device;
  std::string backend = "vulkan";  // vulkan | cpu
  std::string precision = "fp32";
  std::optional<double> contrast;  // physics: c; empty: estimated (see estimate_contrast)
  std::optional<double> gamma;     // physics: decode gamma of the PNGs; empty: meta.json's source.gamma or 1
  bool quiet = false;
  bool video = true;
  int bit_depth = 8;
  // Tiled / sparse model execution (host/model/tiling.hpp, docs/tiling.md).
  // Defaults from the speed-against-error report (bench/bench_report.cpp, README): sparse exact on
  // 32-pixel tiles with a 32-pixel halo never lost PSNR there and ran 1.8-2x faster on a static scene.
  int64_t tile = 0;               // interior side, multiple of 32; 0: sparse: 32; dense: untiled if it fits, else the largest that fits
  int64_t halo = -1;              // multiple of 32; -1: sparse 32, dense tiles 64
  std::string sparse = "exact";   // off | exact | fast
  double sparse_threshold = 0.05; // fast: ev1 + ev2 events per pixel of a tile's input rect
};

// Runs the whole job; returns summary.json's content (also written to out_dir).
nlohmann::json run_unroll(const UnrollOptions& options);

// The contrast threshold c for the physics unroller, estimated from the sequence: for up to
// three pairs of consecutive frames, both frames are unrolled to the instant halfway between
// their mid-exposures, and c is the value on a grid (0.05 .. 0.6, step 0.025) that makes the two
// estimates agree best (least mean |log difference|) — the temporal consistency SelfUnroll
// trains on. Returns 0.2 when the sequence has a single frame.
double estimate_contrast(const Sequence& seq, const std::vector<int>& frames, double gamma);

}  // namespace vkunroll
