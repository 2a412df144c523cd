#include "vkunroll/host/unroll/unroll_options.hpp"

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/unroll/value_list.hpp"

namespace vkunroll {

UnrollMode parse_unroll_mode(const std::string& s, const std::string& what) {
  if (s == "auto") return UnrollMode::automatic;
  if (s == "s") return UnrollMode::s;
  if (s == "m") return UnrollMode::m;
  if (s == "physics") return UnrollMode::physics;
  if (s == "choose") return UnrollMode::choose;
  throw Error(what + " '" + s + "' (expected s, m, choose, physics or auto)");
}

const char* unroll_mode_name(UnrollMode m) {
  switch (m) {
    case UnrollMode::automatic: return "auto";
    case UnrollMode::s: return "s";
    case UnrollMode::m: return "m";
    case UnrollMode::physics: return "physics";
    case UnrollMode::choose: return "choose";
  }
  return "?";
}

BackendKind parse_backend_kind(const std::string& s, const std::string& what) {
  if (s == "vulkan") return BackendKind::vulkan;
  if (s == "cpu") return BackendKind::cpu;
  throw Error(what + " '" + s + "' (expected vulkan or cpu)");
}

const char* backend_kind_name(BackendKind b) { return b == BackendKind::cpu ? "cpu" : "vulkan"; }

ChannelOrder parse_channel_order(const std::string& s, const std::string& what) {
  if (s == "rgb") return ChannelOrder::rgb;
  if (s == "bgr") return ChannelOrder::bgr;
  throw Error(what + " '" + s + "' (expected rgb or bgr)");
}

TargetTimes parse_target_times(const std::string& times, const std::string& times_us) {
  if (!times_us.empty()) return {TargetTimes::Kind::absolute_us, parse_value_list(times_us, "--times-us")};
  if (times == "gt") return {TargetTimes::Kind::ground_truth, {}};
  return {TargetTimes::Kind::normalized, parse_value_list(times, "--times")};
}

void validate_unroll_options(const UnrollOptions& o) {
  if (o.sequence.empty()) throw Error("unroll: no SEQUENCE folder given");
  if (o.out_dir.empty()) throw Error("unroll: --out DIR is required");
  const bool needs_model = o.mode == UnrollMode::s || o.mode == UnrollMode::m || o.mode == UnrollMode::choose;
  if (needs_model && o.session.model_path.empty())
    throw Error(std::string("--mode ") + unroll_mode_name(o.mode) + " needs --model FILE.safetensors");
  if (o.session.precision == Precision::fp16 && o.session.backend == BackendKind::cpu)
    throw Error("--precision fp16 needs --backend vulkan (the CPU backend computes the fp32 reference)");
  if (o.tile < 0 || o.tile % kTileAlign)
    throw Error("--tile " + std::to_string(o.tile) + ": expected 0 (automatic) or a positive multiple of " + std::to_string(kTileAlign));
  if (o.halo < -1 || (o.halo >= 0 && o.halo % kTileAlign))
    throw Error("--halo " + std::to_string(o.halo) + ": expected -1 (automatic) or a non-negative multiple of " + std::to_string(kTileAlign));
  if (!(o.sparse_threshold >= 0))
    throw Error("--sparse-threshold " + std::to_string(o.sparse_threshold) + ": expected >= 0 events per pixel");
  if (o.output.bit_depth != 8 && o.output.bit_depth != 16)
    throw Error("--bit-depth " + std::to_string(o.output.bit_depth) + ": expected 8 or 16");
  if (o.contrast && !(*o.contrast > 0)) throw Error("--contrast " + std::to_string(*o.contrast) + ": expected a positive value");
  if (o.gamma && !(*o.gamma > 0)) throw Error("--gamma " + std::to_string(*o.gamma) + ": expected a positive value");
  if (o.times.kind != TargetTimes::Kind::ground_truth && o.times.values.empty())
    throw Error(o.times.kind == TargetTimes::Kind::absolute_us ? "--times-us: no target given" : "--times: no target given");
  for (int k : o.frames)
    if (k < 0) throw Error("--frames: frame index " + std::to_string(k) + " is negative");
}

}  // namespace vkunroll
