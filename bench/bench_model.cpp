// vkunroll-bench-model: SelfUnroll with the published configuration (random weights, fixed seed)
// on one target, Vulkan (the device vkunroll picks; lavapipe here) against the PyTorch mirror on
// the CPU with the same weights and inputs, in the same run: ms per GS frame, the ratio, and the
// max abs difference of every output.
//
// usage: vkunroll-bench-model [--size 346x260] [--mode m|s] [--no-torch] [--torch-threads N] [--profile] [--runs N]
//                             [--precision fp32|fp16] [--per-layer] [--model W.safetensors] [--inputs IN.safetensors]
//                             [--torch-device cpu|cuda] [--conv-choice heuristic|auto|cached|measured|retune|gpu]
//                             [--winograd-tile 6|8] [--trace FILE.json]
//
// --conv-choice (default heuristic): the conv algorithm per shape (host/model/conv_choice.hpp), from
// the device's table in the cache directory; measured / retune first time the missing / every shape
// in an untimed full-size run (reported) and save the table; a committed table of this GPU model
// (models/conv_choices/) lies under the device's own. gpu: the GPU kernels' rule on any device.
// The race: with --torch-device cuda the peer is the PyTorch mirror on the same GPU (CUDA, best of
// --runs after a full-size warm-up, in the same precision), and the ratio is vulkan / torch.
// --precision fp16 runs the Vulkan side in fp16 (the mirror stays fp32, so the diffs are fp16's error).
// --per-layer (with --precision fp16) runs fp32 and fp16 on the same input and prints, for every conv
// in call order, the largest |value| in fp32 and fp16's max abs and relative error against it.
// --model uses those weights instead of random ones; --inputs reads rs, ev1, ev2, ev3 [, phys]
// (vkunroll infer's layout; tools/data/make_model_inputs.py makes it from a sequence) instead of random ones.
//
// --runs N times N full-size runs and reports the best (the first run also grows the workspaces and
// allocates device memory, which on a discrete GPU costs more than the run) and the first.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <random>
#include <string>
#include <utility>
#include <unistd.h>

#include "bench_args.hpp"
#include "bench_model_inputs.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/model/backend.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/model/conv_choice.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/model/safetensors.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/memory.hpp"
#include "vkunroll/runtime/profiler.hpp"
#include "vkunroll/runtime/trace.hpp"
#include <deque>
#include <iostream>

using namespace vkunroll;

namespace {

double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

HostTensor input_tensor(const SafetensorsFile& f, const std::string& path, const std::string& name) {
  if (!f.has(name)) throw Error(path + ": tensor '" + name + "' is missing (expected rs, ev1, ev2, ev3 [B, C, H, W])");
  const SafetensorsTensor& t = f.get(name);
  if (t.shape.size() != 4) throw Error(path + ": tensor '" + name + "' is not 4-D [B, C, H, W]");
  return HostTensor(Shape{t.shape[0], t.shape[1], t.shape[2], t.shape[3]}, t.to_f32());
}

// fp32 and fp16 on the same input, every conv's output compared (the fp16 precision report).
int per_layer_report(Context& ctx, const Weights& w, const ModelInputs& in, Mode md) {
  VulkanBackend::LayerProbe p32, p16;
  RunOptions opt;
  opt.mode = md;
  std::map<ModelOutput, HostTensor> o32, o16;
  {
    VulkanBackend vk(ctx);
    vk.set_layer_probe(&p32);
    Model m(vk, w);
    o32 = m.run(in, opt);
  }
  {
    VulkanBackend vk(ctx, nullptr, kPoolFlushBytes, Precision::fp16);
    vk.set_layer_probe(&p16);
    Model m(vk, w);
    o16 = m.run(in, opt);
  }
  if (p32.size() != p16.size()) throw Error("per-layer report: fp32 and fp16 ran different conv sequences");
  auto compare = [](const std::string& name, const std::vector<float>& a, const std::vector<float>& b) {
    double mx = 0, mx16 = 0, err = 0;
    bool finite = true;
    for (size_t i = 0; i < a.size(); ++i) {
      mx = std::max(mx, double(std::fabs(a[i])));
      mx16 = std::max(mx16, double(std::fabs(b[i])));
      finite = finite && std::isfinite(b[i]);
      err = std::max(err, double(std::fabs(a[i] - b[i])));
    }
    std::printf("  %-44s %10.4g %10.4g %10.3g %9.2e%s\n", name.c_str(), mx, mx16, err, err / std::max(mx, 1e-30),
                finite ? "" : "  NOT FINITE");
  };
  std::printf("per-layer fp16 error against fp32 (every conv in call order; rel = max abs error / max |fp32|)\n");
  std::printf("  %-44s %10s %10s %10s %9s\n", "layer", "max|fp32|", "max|fp16|", "max abs", "rel");
  for (size_t i = 0; i < p32.size(); ++i) {
    if (p32[i].first != p16[i].first) throw Error("per-layer report: conv " + std::to_string(i) + " differs in name");
    compare(p32[i].first, p32[i].second, p16[i].second);
  }
  std::printf("outputs:\n");
  for (const auto& [o, a] : o32) compare(output_name(o), a.data, o16.at(o).data);
  return 0;
}

// The network on inputs uploaded once, each run downloading only its final image (S: fused, M: out):
// what `unroll` does per GS frame (event tensors built on the device, one frame written) and what
// the PyTorch peer times (inputs and outputs on the GPU). Best wall seconds of `runs`, and that
// run's device ms, and the final image; seconds 0 (said) where the inputs need more than one chunk.
struct ResidentTiming {
  double seconds = 0, gpu_ms = 0;
  std::vector<float> image;
};
ResidentTiming time_resident(Context& ctx, Backend& vk, Model& model, const ModelInputs& in, Mode md, int runs) {
  const int64_t B = in.rs.shape.n, H = in.rs.shape.h, W = in.rs.shape.w;
  if (model.items_per_chunk(H, W, md, 0) < B) {
    std::printf("  vulkan : resident timing skipped: the %lld items need more than one chunk\n", static_cast<long long>(B));
    return {};
  }
  std::vector<Buffer> keep;
  const ModelBuffers bufs = model.upload_inputs(in, 0, B, keep);  // the timed runs checked these inputs
  vk.flush();
  RunOptions o;
  o.mode = md;
  o.outputs = {md == Mode::m ? ModelOutput::out : ModelOutput::fused};
  ResidentTiming best{1e30, 0, {}};
  for (int r = 0; r < std::max(1, runs); ++r) {
    const DeviceTraffic before = ctx.traffic();
    const auto t = Clock::now();
    const std::map<ModelOutput, Buffer> outs = model.run_on_backend(bufs, o);
    std::vector<float> image = vk.download(outs.begin()->second.whole());
    const double s = seconds_since(t);
    if (s < best.seconds) best = {s, (ctx.traffic() - before).gpu_ms, std::move(image)};
  }
  return best;
}

// Everything the command line sets.
struct BenchArgs {
  int W = 346, H = 260, torch_threads = 0, runs = 1;
  bool torch = true, profile = false, per_layer = false;
  std::string mode = "m", model_path, inputs_path, torch_device = "cpu";
  std::string trace_path;  // --trace: the timed runs' timeline (runtime/trace.hpp)
  ConvChoice conv_choice = ConvChoice::heuristic;
  Precision precision = Precision::fp32;
  ConvOptions conv_options;  // --winograd-tile: 5x5 convs as F(4x4, 5x5) (8) or four F(4x4, 3x3) (6)
};

constexpr const char* kUsage =
    "usage: vkunroll-bench-model [--size WxH] [--mode m|s] [--no-torch] [--torch-threads N] [--profile] [--runs N]\n"
    "                            [--precision fp32|fp16] [--per-layer] [--model W.safetensors] [--inputs IN.safetensors]\n"
    "                            [--torch-device cpu|cuda] [--conv-choice heuristic|auto|cached|measured|retune|gpu]\n"
    "                            [--winograd-tile 6|8] [--trace FILE.json]\n";

// -1: parsed, run the bench; else the exit status (a bad argument is said on stderr).
int parse_args(int argc, char** argv, BenchArgs& a) {
  for (int i = 1; i < argc; ++i) {
    const std::string f = argv[i];
    const bool has_value = i + 1 < argc;
    try {
      if (f == "--size" && has_value) {
        const BenchSize z = bench_size_arg("vkunroll-bench-model", f, argv[++i], 2, 16384);
        a.W = static_cast<int>(z.w);
        a.H = static_cast<int>(z.h);
      } else if (f == "--mode" && has_value) {
        a.mode = argv[++i];
      } else if (f == "--profile") {
        a.profile = true;
      } else if (f == "--trace" && has_value) {
        a.trace_path = argv[++i];
      } else if (f == "--no-torch") {
        a.torch = false;
      } else if (f == "--runs" && has_value) {
        a.runs = static_cast<int>(bench_int_arg("vkunroll-bench-model", f, argv[++i], 1, 1000));
      } else if (f == "--torch-threads" && has_value) {
        a.torch_threads = static_cast<int>(bench_int_arg("vkunroll-bench-model", f, argv[++i], 1, 1024));
      } else if (f == "--precision" && has_value) {
        a.precision = parse_precision(argv[++i], "--precision");
      } else if (f == "--conv-choice" && has_value) {
        a.conv_choice = parse_conv_choice(argv[++i], "--conv-choice");
      } else if (f == "--winograd-tile" && has_value) {  // the convs check the tile
        a.conv_options.winograd_tile = static_cast<int>(bench_int_arg("vkunroll-bench-model", f, argv[++i], 0, 64));
      } else if (f == "--per-layer") {
        a.per_layer = true;
      } else if (f == "--model" && has_value) {
        a.model_path = argv[++i];
      } else if (f == "--inputs" && has_value) {
        a.inputs_path = argv[++i];
      } else if (f == "--torch-device" && has_value) {
        a.torch_device = argv[++i];
        if (a.torch_device != "cpu" && a.torch_device != "cuda") {
          std::fprintf(stderr, "--torch-device '%s': expected cpu or cuda\n", a.torch_device.c_str());
          return 2;
        }
      } else {
        std::fprintf(stderr, "%s", kUsage);
        return 2;
      }
    } catch (const Error& e) {
      std::fprintf(stderr, "%s\n", e.what());
      return 2;
    }
  }
  if (a.per_layer && a.precision != Precision::fp16) {
    std::fprintf(stderr, "--per-layer compares fp16 with fp32: give --precision fp16\n");
    return 2;
  }
  return -1;
}

// --inputs' tensors (and their size into a.W, a.H), else random inputs of B items.
ModelInputs load_inputs(BenchArgs& a, const ModelConfig& cfg, int64_t B) {
  if (a.inputs_path.empty()) return random_model_inputs(cfg, B, a.H, a.W);
  const SafetensorsFile f = read_safetensors(a.inputs_path);
  ModelInputs in{input_tensor(f, a.inputs_path, "rs"), input_tensor(f, a.inputs_path, "ev1"),
                 input_tensor(f, a.inputs_path, "ev2"), input_tensor(f, a.inputs_path, "ev3")};
  if (f.has("phys")) in.phys = input_tensor(f, a.inputs_path, "phys");
  a.H = static_cast<int>(in.rs.shape.h);
  a.W = static_cast<int>(in.rs.shape.w);
  return in;
}

// Warm-up on a 32x32 crop: compiles every pipeline variant, so that the timed runs are steady-state.
void warm_up(Model& model, const ModelInputs& in, Mode md, double prep) {
  auto crop = [](const HostTensor& a) {
    HostTensor r;
    r.shape = {a.shape.n, a.shape.c, 32, 32};
    for (int64_t n = 0; n < a.shape.n; ++n)
      for (int64_t c = 0; c < a.shape.c; ++c)
        for (int64_t y = 0; y < 32; ++y)
          for (int64_t x = 0; x < 32; ++x) r.data.push_back(a.data[size_t(((n * a.shape.c + c) * a.shape.h + y) * a.shape.w + x)]);
    return r;
  };
  ModelInputs small{crop(in.rs), crop(in.ev1), crop(in.ev2), crop(in.ev3)};
  if (!in.phys.data.empty()) small.phys = crop(in.phys);
  RunOptions o;
  o.mode = md;
  const auto t = Clock::now();
  model.run(small, o);
  // Progress on stderr (unbuffered): a run stopped by a time limit still says how far it got.
  std::fprintf(stderr, "progress: weights prepared in %.2f s; the 32x32 warm-up (every pipeline built) took %.2f s\n", prep,
               seconds_since(t));
}

// Where committed conv tables are looked for: VKUNROLL_CONV_TABLES, else the source tree's. (The
// unroll layer's conv_table_dirs() would link the unroll layer, and OpenCV's codecs with it, into
// the device bundle's copy of this bench: 135 more libraries.)
std::vector<std::string> committed_table_dirs() {
  if (const char* d = std::getenv("VKUNROLL_CONV_TABLES"); d && *d) return {d};
  return {std::string(VKUNROLL_SOURCE_DIR) + "/models/conv_choices"};
}

// Sets --conv-choice on the backend: the device's table (its cache file with a committed table under
// it), timing what it lacks first (measured) or everything (retune) in an untimed run, then saved;
// gpu: the GPU kernels' rule, no table.
void apply_conv_choice(const BenchArgs& a, Context& ctx, VulkanBackend& vk, Model& model, const ModelInputs& in, Mode md) {
  if (a.conv_choice == ConvChoice::heuristic) return;
  if (a.conv_choice == ConvChoice::gpu) {
    vk.set_conv_choice(nullptr, ConvChoice::gpu);
    return;
  }
  std::vector<std::string> warnings;
  const DeviceConvTable d = load_device_conv_table(ctx, committed_table_dirs(), &warnings);
  for (const auto& wn : warnings) std::fprintf(stderr, "warning: %s\n", wn.c_str());
  if (!d.committed.empty()) std::printf("  conv choice: committed table %s (%s)\n", d.committed.c_str(), d.committed_how.c_str());
  vk.set_conv_choice(d.table, a.conv_choice);
  vk.on_conv_timed([](const std::string& key, const ConvChoiceEntry& e, double s) {
    std::fprintf(stderr, "progress: timed %s in %.2f s: %s (%s)\n", key.c_str(), s, e.algo.c_str(), e.timings.c_str());
  });
  if (a.conv_choice != ConvChoice::measured && a.conv_choice != ConvChoice::retune) return;
  RunOptions o;
  o.mode = md;
  const auto t = Clock::now();
  model.run(in, o);  // untimed: times the shapes the table lacks (retune: all)
  std::printf("  conv choice %s: %llu shapes timed in %.1f s (table %s)\n", conv_choice_name(a.conv_choice),
              static_cast<unsigned long long>(vk.convs_timed()), seconds_since(t), d.path.empty() ? "not saved" : d.path.c_str());
  if (!d.path.empty()) d.table->save(d.path, conv_choice_header(ctx), conv_device_identity(ctx));
  vk.set_conv_choice(d.table, ConvChoice::cached);
}

// The timed runs: the best and the first wall seconds, the best run's device ms and outputs; with a
// conv choice other than the heuristic, a heuristic run after each on the same input (interleaved, so
// the shared machine's load drifts over both alike).
struct TimedRuns {
  double best_s = 1e30, first_s = 0, gpu_ms = 0, heuristic_s = 1e30, heuristic_gpu_ms = 0;
  uint64_t from_table = 0, dispatches = 0, transfers = 0;  // of the best run
  std::map<ModelOutput, HostTensor> out;
};

TimedRuns timed_runs(const BenchArgs& a, Context& ctx, VulkanBackend& vk, Model& model, const ModelInputs& in, Mode md,
                     Profiler& profiler) {
  RunOptions opt;
  opt.mode = md;
  TimedRuns r;
  const bool compare = a.conv_choice != ConvChoice::heuristic;
  const std::shared_ptr<ConvChoiceTable> table = vk.conv_choice_table();
  const ConvChoice chosen = a.conv_choice == ConvChoice::automatic || a.conv_choice == ConvChoice::gpu ? a.conv_choice
                                                                                                         : ConvChoice::cached;
  auto one_run = [&](double& best, double& best_gpu, std::map<ModelOutput, HostTensor>* result) {
    const DeviceTraffic before = ctx.traffic();
    const auto t = Clock::now();
    auto o = model.run(in, opt);
    const double s = seconds_since(t);
    const DeviceTraffic d = ctx.traffic() - before;
    if (s < best) best = s, best_gpu = d.gpu_ms;
    if (result) *result = std::move(o), r.dispatches = d.dispatches, r.transfers = d.transfers;
    return s;
  };
  Trace trace;
  if (!a.trace_path.empty()) ctx.set_trace(&trace);
  for (int i = 0; i < a.runs; ++i) {
    if (i > 0) profiler.clear();  // the table shows the last run
    const auto run_start = Clock::now();
    const uint64_t ft = vk.convs_from_table();
    const double s = one_run(r.best_s, r.gpu_ms, &r.out);
    std::fprintf(stderr, "progress: run %d took %.1f ms\n", i + 1, 1000 * s);
    trace.host_span("host stages", "run " + std::to_string(i + 1), run_start, Clock::now());
    r.from_table = vk.convs_from_table() - ft;
    if (i == 0) r.first_s = s;
    if (!compare) continue;
    vk.set_conv_choice(nullptr, ConvChoice::heuristic);
    one_run(r.heuristic_s, r.heuristic_gpu_ms, nullptr);
    vk.set_conv_choice(table, chosen);
  }
  ctx.set_trace(nullptr);
  if (!a.trace_path.empty()) {
    trace.write(a.trace_path);
    std::printf("  trace  : %zu spans of the timed runs in %s\n", trace.spans(), a.trace_path.c_str());
  }
  return r;
}

void print_vulkan(const BenchArgs& a, Context& ctx, const VulkanBackend& vk, const ModelConfig& cfg, Mode md, double prep,
                  const TimedRuns& r) {
  std::printf("vkunroll-bench-model: SelfUnroll-%s, %s (%lld parameters), %dx%d, %s, device %s\n", md == Mode::m ? "M" : "S",
              a.model_path.empty() ? "published configuration" : a.model_path.c_str(), static_cast<long long>(parameter_count(cfg)),
              a.W, a.H, precision_name(a.precision), ctx.info().name.c_str());
  std::printf("  vulkan : %.1f ms per GS frame (weights prepared in %.2f s; peak intermediates %.1f MiB, "
              "device buffers peak %.1f MiB, allocator peak %.1f MiB incl. %.1f MiB of weights as given)\n",
              1000 * r.best_s, prep, vk.peak_bytes() / 1048576.0, vk.device_peak_bytes() / 1048576.0,
              ctx.allocator().stats().peak_used_bytes / 1048576.0, vk.weight_bytes() / 1048576.0);
  if (a.runs > 1) std::printf("  vulkan : best of %d runs; the first took %.1f ms\n", a.runs, 1000 * r.first_s);
  std::printf("  vulkan : %llu dispatches and %llu transfers (copies, fills) per GS frame\n",
              static_cast<unsigned long long>(r.dispatches), static_cast<unsigned long long>(r.transfers));
  if (a.conv_choice != ConvChoice::heuristic) {
    if (a.conv_choice != ConvChoice::gpu)
      std::printf("  vulkan : conv algorithms: %llu of the run's convs took the measured table's choice\n",
                  static_cast<unsigned long long>(r.from_table));
    std::printf("  vulkan : with the heuristic conv choice %.1f ms per GS frame (device %.1f ms; runs interleaved); "
                "%s / heuristic = %.2f\n", 1000 * r.heuristic_s, r.heuristic_gpu_ms,
                a.conv_choice == ConvChoice::gpu ? "gpu" : "measured", r.best_s / r.heuristic_s);
  }
  std::printf("  vulkan : device time %.1f ms of the %.1f ms frame (%.0f%%; the rest is host work and waits)\n", r.gpu_ms,
              1000 * r.best_s, 100 * r.gpu_ms / (1000 * r.best_s));
}

// The resident timing (time_resident) beside the timed runs; its seconds (0: skipped).
double print_resident(Context& ctx, VulkanBackend& vk, Model& model, const ModelInputs& in, Mode md, int runs,
                      const TimedRuns& r) {
  const ResidentTiming resident = time_resident(ctx, vk, model, in, md, runs);
  if (resident.seconds <= 0) return 0;
  // The same network on the same inputs: its image must equal the timed runs' (a check of the path timed).
  const std::vector<float>& ref = r.out.at(md == Mode::m ? ModelOutput::out : ModelOutput::fused).data;
  double diff = ref.size() == resident.image.size() ? 0.0 : 1e30;
  for (size_t i = 0; diff < 1e30 && i < ref.size(); ++i) diff = std::max(diff, double(std::fabs(ref[i] - resident.image[i])));
  std::printf("  vulkan : resident inputs, only the final image downloaded: %.1f ms per GS frame (device %.1f ms, %.0f%%; "
              "max abs diff to the timed runs' image %.3g)\n", 1000 * resident.seconds, resident.gpu_ms,
              100 * resident.gpu_ms / (1000 * resident.seconds), diff);
  return resident.seconds;
}

// The PyTorch mirror on the same weights and inputs (tools/bench/bench_mirror.py): its time, the ratios and
// every output's difference. The exit status (1: the mirror failed).
int run_torch_peer(const BenchArgs& a, const Weights& w, const ModelInputs& in, const TimedRuns& r, double res_s) {
  const auto dir = std::filesystem::temp_directory_path() / ("vkunroll_bench_model_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  save_weights((dir / "w.safetensors").string(), w);
  std::vector<SafetensorsTensorRef> views;
  std::vector<std::pair<const char*, const HostTensor*>> named{{"rs", &in.rs}, {"ev1", &in.ev1}, {"ev2", &in.ev2}, {"ev3", &in.ev3}};
  if (!in.phys.data.empty()) named.push_back({"phys", &in.phys});
  for (auto [name, t] : named)
    views.push_back({name, StDType::F32, {t->shape.n, t->shape.c, t->shape.h, t->shape.w}, t->data.data(), t->data.size() * 4});
  write_safetensors((dir / "in.safetensors").string(), views);
  // CPU PyTorch has no fp16 convs: there the peer stays fp32 and the diffs are fp16's error.
  const std::string torch_precision = a.torch_device == "cuda" ? precision_name(a.precision) : "fp32";
  // tools/ is a package run from the source root (the mirror imports tools.model); the paths below are absolute.
  const std::string cmd = "cd " + std::string(VKUNROLL_SOURCE_DIR) + " && /usr/bin/python3 -m tools.bench.bench_mirror " +
                          (dir / "w.safetensors").string() + " " + (dir / "in.safetensors").string() + " " +
                          (dir / "out.safetensors").string() + " --mode " + a.mode +
                          (a.torch_threads ? " --threads " + std::to_string(a.torch_threads) : "") + " --device " +
                          a.torch_device + " --precision " + torch_precision + " --runs " + std::to_string(a.runs);
  if (std::system(cmd.c_str()) != 0) {
    std::fprintf(stderr, "the PyTorch mirror failed: %s\n", cmd.c_str());
    std::filesystem::remove_all(dir);
    return 1;
  }
  const SafetensorsFile ref = read_safetensors((dir / "out.safetensors").string());
  const double torch_s = std::stod(ref.metadata.at("seconds"));
  std::printf("  torch  : %.1f ms per GS frame (PyTorch mirror, %s, %s, %s)\n", 1000 * torch_s, a.torch_device.c_str(),
              torch_precision.c_str(), ref.metadata.count("device") ? ref.metadata.at("device").c_str() : "?");
  if (ref.metadata.count("settings"))  // on CUDA: every PyTorch setting tried, the fastest is the peer
    std::printf("  torch  : settings %s; fastest %s\n", ref.metadata.at("settings").c_str(), ref.metadata.at("setting").c_str());
  std::printf("  ratio  : vulkan / torch = %.2f\n", r.best_s / torch_s);
  if (res_s > 0) std::printf("  ratio  : resident vulkan / torch = %.2f (both with inputs on the device)\n", res_s / torch_s);
  for (const auto& [name, arr] : r.out) {
    const std::vector<float> v = ref.get(output_name(name)).to_f32();
    double err = 0, mx = 0;
    for (size_t i = 0; i < v.size(); ++i) {
      err = std::max(err, double(std::fabs(v[i] - arr.data[i])));
      mx = std::max(mx, double(std::fabs(v[i])));
    }
    std::printf("  max abs diff %-6s %.3g (max |value| %.3g)\n", output_name(name), err, mx);
  }
  std::filesystem::remove_all(dir);
  return 0;
}

int run_bench(BenchArgs& a) {
  const Mode md = a.mode == "s" ? Mode::s : Mode::m;
  const Weights w = a.model_path.empty() ? random_weights(ModelConfig::published(), 2024) : load_weights(a.model_path);
  const ModelInputs in = load_inputs(a, w.config, md == Mode::m ? 2 : 1);
  Context ctx;
  if (a.per_layer) return per_layer_report(ctx, w, in, md);
  Profiler profiler;
  VulkanBackend vk(ctx, a.profile ? &profiler : nullptr, kPoolFlushBytes, a.precision);
  vk.set_conv_options(a.conv_options);
  const auto t = Clock::now();
  Model model(vk, w);
  const double prep = seconds_since(t);
  warm_up(model, in, md, prep);  // the heuristic's pipelines, which the interleaved runs also take
  apply_conv_choice(a, ctx, vk, model, in, md);
  if (a.conv_choice == ConvChoice::gpu) warm_up(model, in, md, prep);  // the GPU rule's pipelines
  vk.reset_peak();
  profiler.clear();
  ctx.allocator().reset_peak();
  const TimedRuns r = timed_runs(a, ctx, vk, model, in, md, profiler);
  print_vulkan(a, ctx, vk, w.config, md, prep, r);
  if (a.profile) profiler.print(std::cout);  // the last timed run's dispatches, before the resident runs add theirs
  const double res_s = print_resident(ctx, vk, model, in, md, a.runs, r);
  return a.torch ? run_torch_peer(a, w, in, r, res_s) : 0;
}

}  // namespace

int main(int argc, char** argv) {
  BenchArgs a;
  if (const int status = parse_args(argc, argv, a); status >= 0) return status;
  try {
    return run_bench(a);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "vkunroll-bench-model: %s\n", e.what());
    return 1;
  }
}
