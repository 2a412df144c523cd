// vkunroll-bench-dispatch: the host cost of a dispatch, side by side in one run.
//
// 1. Push descriptors (VK_KHR_push_descriptor) against descriptor sets from pools: a chain of small
//    elementwise dispatches (the model's shape: many small ops) is recorded and submitted; the host
//    time to record one dispatch and the whole submit's wall time per path, with the ratio.
// 2. A model frame (SelfUnroll-S, the published configuration with random weights, or --model) at a
//    tiny size (--frame-size, default 32x32: the device's work is negligible, so the frame's wall time
//    is host work): every frame recorded again with timestamps around every command (the stream as
//    it was before issue 49: `per-frame recording`) against the frame recorded once and replayed,
//    without timestamps (`recorded once`, the default now). Host time per dispatch is the frame's
//    wall time less the waits for the device, over its dispatches; wall time per dispatch beside it.
// Both alternate the paths `--reps` times and keep each path's best.
//
// usage: vkunroll-bench-dispatch [--dispatches 2000] [--elements 4096] [--reps 5] [--frame-size 32x32] [--frames 10]
//                                [--model W.safetensors] [--no-chain]
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>

#include "bench_args.hpp"
#include "bench_model_inputs.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/kernels/elementwise.hpp"
#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/context.hpp"

using namespace vkunroll;

namespace {
struct Times {
  double record_us_per_dispatch = 1e30, submit_ms = 1e30;
};

void run(Context& ctx, int dispatches, int64_t elements, Times& best) {
  Tensor a(ctx, {1, 1, 1, elements}), b(ctx, {1, 1, 1, elements}), c(ctx, {1, 1, 1, elements});
  CommandStream cs(ctx);
  add(cs, Slice(a), Slice(b), Slice(c));  // compiles the pipeline outside the timing
  cs.submit_and_wait();
  const double wait0 = ctx.traffic().wait_ms;  // the stream submits every 256 commands: its waits are not recording
  const Stopwatch clock;
  for (int i = 0; i < dispatches; ++i) add(cs, Slice(i % 2 ? c : a), Slice(b), Slice(i % 2 ? a : c));
  const double record_ms = clock.ms() - (ctx.traffic().wait_ms - wait0);
  cs.submit_and_wait();
  const double submit_ms = clock.ms();
  best.record_us_per_dispatch = std::min(best.record_us_per_dispatch, 1e3 * record_ms / dispatches);
  best.submit_ms = std::min(best.submit_ms, submit_ms);
}
// One path of the frame comparison: its own context, backend and model.
struct FramePath {
  const char* name;
  Context ctx;
  VulkanBackend vk;
  Model model;
  double wall_ms = 1e30, host_ms = 1e30;  // per frame, best of the reps
  DeviceTraffic per_frame;                // of the best rep, per frame
  FramePath(const char* n, const ContextOptions& o, const Weights& w) : name(n), ctx(o), vk(ctx), model(vk, w) {}
};

void run_frames(FramePath& p, const ModelInputs& in, int frames) {
  RunOptions ro;
  ro.mode = Mode::s;
  const DeviceTraffic before = p.ctx.traffic();
  const Stopwatch clock;
  for (int f = 0; f < frames; ++f) p.model.run(in, ro);
  const double wall = clock.ms() / frames;
  const DeviceTraffic d = p.ctx.traffic() - before;
  if (wall < p.wall_ms) {
    p.wall_ms = wall;
    p.host_ms = wall - d.wait_ms / frames;
    p.per_frame = d;
  }
}

int frame_comparison(const std::string& model_path, BenchSize size, int frames, int reps) {
  const Weights w = model_path.empty() ? random_weights(ModelConfig::published(), 2024) : load_weights(model_path);
  const ModelInputs in = random_model_inputs(w.config, 1, size.h, size.w);
  ContextOptions before, after;
  before.announce = after.announce = false;
  before.timestamps = true, before.command_replay = false;
  after.timestamps = false, after.command_replay = true;
  FramePath paths[2] = {{"per-frame recording", before, w}, {"recorded once", after, w}};
  for (FramePath& p : paths) run_frames(p, in, 3);  // pipelines built; a repeated frame's buffers kept and seen twice
  for (FramePath& p : paths) p.wall_ms = p.host_ms = 1e30;
  for (int r = 0; r < reps; ++r)
    for (FramePath& p : paths) run_frames(p, in, frames);
  std::printf("vkunroll-bench-dispatch: SelfUnroll-S frames, %s, %lldx%lld, %d frames per rep, best of %d, device %s\n",
              model_path.empty() ? "published configuration (random weights)" : model_path.c_str(), size.w, size.h, frames, reps,
              paths[0].ctx.info().name.c_str());
  for (const FramePath& p : paths) {
    const double n = static_cast<double>(p.per_frame.dispatches) / frames;
    std::printf("  %-20s: %.1f dispatches + %.1f transfers per frame, %.1f submits, %.0f%% of commands replayed; "
                "%.2f us host time per dispatch, %.2f us wall per dispatch (%.2f ms per frame)\n",
                p.name, n, static_cast<double>(p.per_frame.transfers) / frames, static_cast<double>(p.per_frame.submits) / frames,
                100.0 * static_cast<double>(p.per_frame.replayed_commands) /
                    std::max(1.0, static_cast<double>(p.per_frame.dispatches + p.per_frame.transfers)),
                1000 * p.host_ms / n, 1000 * p.wall_ms / n, p.wall_ms);
  }
  std::printf("  ratio (recorded once / per-frame recording): host time per dispatch %.2f, wall per dispatch %.2f\n",
              paths[1].host_ms / paths[0].host_ms, paths[1].wall_ms / paths[0].wall_ms);
  return 0;
}
}  // namespace

constexpr const char* kBench = "vkunroll-bench-dispatch";
int chain_comparison(int dispatches, int64_t elements, int reps);

int main(int argc, char** argv) {
  int dispatches = 2000, reps = 5, frames = 10;
  int64_t elements = 4096;
  BenchSize frame_size{32, 32};
  std::string model_path;
  bool chain = true;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--dispatches" && i + 1 < argc) dispatches = static_cast<int>(bench_int_arg(kBench, a, argv[++i], 1, 1000000));
    else if (a == "--elements" && i + 1 < argc) elements = bench_int_arg(kBench, a, argv[++i], 1, 1LL << 30);
    else if (a == "--reps" && i + 1 < argc) reps = static_cast<int>(bench_int_arg(kBench, a, argv[++i], 1, 1000));
    else if (a == "--frames" && i + 1 < argc) frames = static_cast<int>(bench_int_arg(kBench, a, argv[++i], 1, 100000));
    else if (a == "--frame-size" && i + 1 < argc) frame_size = bench_size_arg(kBench, a, argv[++i], 32, 8192);
    else if (a == "--model" && i + 1 < argc) model_path = argv[++i];
    else if (a == "--no-chain") chain = false;
    else {
      std::fprintf(stderr, "usage: vkunroll-bench-dispatch [--dispatches N] [--elements N] [--reps N] [--frame-size WxH] [--frames N]\n"
                           "                               [--model W.safetensors] [--no-chain]\n");
      return 2;
    }
  }
  try {
    if (chain && chain_comparison(dispatches, elements, reps) != 0) return 1;
    return frame_comparison(model_path, frame_size, frames, reps);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: %s\n", kBench, e.what());
    return 1;
  }
}

int chain_comparison(int dispatches, int64_t elements, int reps) {
  ContextOptions po, so;
  po.command_replay = so.command_replay = false;  // the recording paths, not the replay
  so.push_descriptors = false;
  so.announce = false;
  Context pushed(po), sets(so);
  if (!pushed.uses_push_descriptors()) {
    std::fprintf(stderr, "device '%s' has no VK_KHR_push_descriptor: nothing to compare\n", pushed.info().name.c_str());
    return 1;
  }
  Times tp, ts;
  for (int r = 0; r < reps; ++r) {
    run(pushed, dispatches, elements, tp);
    run(sets, dispatches, elements, ts);
  }
  std::printf("vkunroll-bench-dispatch: %d dependent add dispatches of %lld floats, recorded afresh, best of %d, device %s\n",
              dispatches, static_cast<long long>(elements), reps, pushed.info().name.c_str());
  std::printf("  push descriptors : %.2f us host time to record a dispatch, %.1f ms record + submit + wait\n",
              tp.record_us_per_dispatch, tp.submit_ms);
  std::printf("  descriptor sets  : %.2f us host time to record a dispatch, %.1f ms record + submit + wait\n",
              ts.record_us_per_dispatch, ts.submit_ms);
  std::printf("  ratio (push / sets): record %.2f, whole submit %.2f\n", tp.record_us_per_dispatch / ts.record_us_per_dispatch,
              tp.submit_ms / ts.submit_ms);
  return 0;
}
