// vkunroll-bench-model: SelfUnroll with the published configuration (random weights, fixed seed)
// on one target, Vulkan (the device vkunroll picks; lavapipe here) against the PyTorch mirror on
// the CPU with the same weights and inputs, in the same run: ms per GS frame, the ratio, and the
// max abs difference of every output.
//
// usage: vkunroll-bench-model [--size 346x260] [--mode m|s] [--no-torch] [--torch-threads N] [--profile] [--runs N]
//                             [--precision fp32|fp16] [--per-layer] [--model W.safetensors] [--inputs IN.safetensors]
//                             [--torch-device cpu|cuda] [--conv-choice heuristic|auto|cached|measured|retune]
//                             [--winograd-tile 6|8]
//
// --conv-choice (default heuristic): the conv algorithm per shape (host/model/conv_choice.hpp), from
// the device's table in the cache directory; measured / retune first time the missing / every shape
// in an untimed full-size run (reported) and save the table.
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
#include "vkunroll/host/model/backend.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/model/conv_choice.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/model/safetensors.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/memory.hpp"
#include "vkunroll/runtime/profiler.hpp"
#include <deque>
#include <iostream>

using namespace vkunroll;

namespace {

double seconds_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
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
    const auto t = std::chrono::steady_clock::now();
    const std::map<ModelOutput, Buffer> outs = model.run_on_backend(bufs, o);
    std::vector<float> image = vk.download(outs.begin()->second.whole());
    const double s = seconds_since(t);
    if (s < best.seconds) best = {s, (ctx.traffic() - before).gpu_ms, std::move(image)};
  }
  return best;
}

}  // namespace

int run_bench(int W, int H, int torch_threads, int runs, bool torch, bool profile, bool per_layer, const std::string& mode,
              const std::string& model_path, const std::string& inputs_path, Precision precision, const std::string& torch_device,
              ConvChoice conv_choice, const ConvOptions& conv_options);

int main(int argc, char** argv) {
  int W = 346, H = 260, torch_threads = 0, runs = 1;
  bool torch = true, profile = false, per_layer = false;
  std::string mode = "m", model_path, inputs_path, torch_device = "cpu";
  ConvChoice conv_choice = ConvChoice::heuristic;
  Precision precision = Precision::fp32;
  ConvOptions conv_options;  // --winograd-tile: 5x5 convs as F(4x4, 5x5) (8) or four F(4x4, 3x3) (6)
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--size" && i + 1 < argc) {
      const BenchSize z = bench_size_arg("vkunroll-bench-model", a, argv[++i], 2, 16384);
      W = static_cast<int>(z.w);
      H = static_cast<int>(z.h);
    } else if (a == "--mode" && i + 1 < argc) {
      mode = argv[++i];
    } else if (a == "--profile") {
      profile = true;
    } else if (a == "--no-torch") {
      torch = false;
    } else if (a == "--runs" && i + 1 < argc) {
      runs = static_cast<int>(bench_int_arg("vkunroll-bench-model", a, argv[++i], 1, 1000));
    } else if (a == "--torch-threads" && i + 1 < argc) {
      torch_threads = static_cast<int>(bench_int_arg("vkunroll-bench-model", a, argv[++i], 1, 1024));
    } else if (a == "--precision" && i + 1 < argc) {
      try {
        precision = parse_precision(argv[++i], "--precision");
      } catch (const Error& e) {
        std::fprintf(stderr, "%s\n", e.what());
        return 2;
      }
    } else if (a == "--conv-choice" && i + 1 < argc) {
      try {
        conv_choice = parse_conv_choice(argv[++i], "--conv-choice");
      } catch (const Error& e) {
        std::fprintf(stderr, "%s\n", e.what());
        return 2;
      }
    } else if (a == "--winograd-tile" && i + 1 < argc) {
      conv_options.winograd_tile = static_cast<int>(bench_int_arg("vkunroll-bench-model", a, argv[++i], 0, 64));  // the convs check the tile
    } else if (a == "--per-layer") {
      per_layer = true;
    } else if (a == "--model" && i + 1 < argc) {
      model_path = argv[++i];
    } else if (a == "--inputs" && i + 1 < argc) {
      inputs_path = argv[++i];
    } else if (a == "--torch-device" && i + 1 < argc) {
      torch_device = argv[++i];
      if (torch_device != "cpu" && torch_device != "cuda") {
        std::fprintf(stderr, "--torch-device '%s': expected cpu or cuda\n", torch_device.c_str());
        return 2;
      }
    } else {
      std::fprintf(stderr, "usage: vkunroll-bench-model [--size WxH] [--mode m|s] [--no-torch] [--torch-threads N] [--profile] [--runs N]\n"
                           "                            [--precision fp32|fp16] [--per-layer] [--model W.safetensors] [--inputs IN.safetensors]\n"
                           "                            [--torch-device cpu|cuda] [--conv-choice heuristic|auto|cached|measured|retune]\n"
                           "                            [--winograd-tile 6|8]\n");
      return 2;
    }
  }
  if (per_layer && precision != Precision::fp16) {
    std::fprintf(stderr, "--per-layer compares fp16 with fp32: give --precision fp16\n");
    return 2;
  }
  try {
    return run_bench(W, H, torch_threads, runs, torch, profile, per_layer, mode, model_path, inputs_path, precision, torch_device,
                     conv_choice, conv_options);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "vkunroll-bench-model: %s\n", e.what());
    return 1;
  }
}

int run_bench(int W, int H, int torch_threads, int runs, bool torch, bool profile, bool per_layer, const std::string& mode,
              const std::string& model_path, const std::string& inputs_path, Precision precision, const std::string& torch_device,
              ConvChoice conv_choice, const ConvOptions& conv_options) {
  const Mode md = mode == "s" ? Mode::s : Mode::m;
  const int64_t B = md == Mode::m ? 2 : 1;
  const Weights w = model_path.empty() ? random_weights(ModelConfig::published(), 2024) : load_weights(model_path);
  const ModelConfig& cfg = w.config;
  ModelInputs in;
  if (!inputs_path.empty()) {
    const SafetensorsFile f = read_safetensors(inputs_path);
    in = {input_tensor(f, inputs_path, "rs"), input_tensor(f, inputs_path, "ev1"), input_tensor(f, inputs_path, "ev2"),
          input_tensor(f, inputs_path, "ev3")};
    if (f.has("phys")) in.phys = input_tensor(f, inputs_path, "phys");
    H = static_cast<int>(in.rs.shape.h);
    W = static_cast<int>(in.rs.shape.w);
  } else {
    in = random_model_inputs(cfg, B, H, W);
  }

  Context ctx;
  if (per_layer) return per_layer_report(ctx, w, in, md);
  Profiler profiler;
  VulkanBackend vk(ctx, profile ? &profiler : nullptr, kPoolFlushBytes, precision);
  vk.set_conv_options(conv_options);
  auto t = std::chrono::steady_clock::now();
  Model model(vk, w);
  const double prep = seconds_since(t);
  // Warm-up on a small crop: compiles every pipeline variant, so the timed run is steady-state.
  {
    ModelInputs small;
    auto crop = [](const HostTensor& a) {
      HostTensor r;
      r.shape = {a.shape.n, a.shape.c, 32, 32};
      for (int64_t n = 0; n < a.shape.n; ++n)
        for (int64_t c = 0; c < a.shape.c; ++c)
          for (int64_t y = 0; y < 32; ++y)
            for (int64_t x = 0; x < 32; ++x) r.data.push_back(a.data[size_t(((n * a.shape.c + c) * a.shape.h + y) * a.shape.w + x)]);
      return r;
    };
    small = {crop(in.rs), crop(in.ev1), crop(in.ev2), crop(in.ev3)};
    if (!in.phys.data.empty()) small.phys = crop(in.phys);
    RunOptions o;
    o.mode = md;
    t = std::chrono::steady_clock::now();
    model.run(small, o);
    // Progress on stderr (unbuffered): a run stopped by a time limit still says how far it got.
    std::fprintf(stderr, "progress: weights prepared in %.2f s; the 32x32 warm-up (every pipeline built) took %.2f s\n", prep,
                 seconds_since(t));
  }
  if (conv_choice != ConvChoice::heuristic) {
    const std::string path = conv_choice_path(ctx);
    std::vector<std::string> warnings;
    auto table = std::make_shared<ConvChoiceTable>(path.empty() ? ConvChoiceTable{} : ConvChoiceTable::load(path, &warnings));
    for (const auto& wn : warnings) std::fprintf(stderr, "warning: %s\n", wn.c_str());
    vk.set_conv_choice(table, conv_choice);
    vk.on_conv_timed([](const std::string& key, const ConvChoiceEntry& e, double s) {
      std::fprintf(stderr, "progress: timed %s in %.2f s: %s (%s)\n", key.c_str(), s, e.algo.c_str(), e.timings.c_str());
    });
    if (conv_choice == ConvChoice::measured || conv_choice == ConvChoice::retune) {
      RunOptions o;
      o.mode = md;
      t = std::chrono::steady_clock::now();
      model.run(in, o);  // untimed: times the shapes the table lacks (retune: all)
      std::printf("  conv choice %s: %llu shapes timed in %.1f s (table %s)\n", conv_choice_name(conv_choice),
                  static_cast<unsigned long long>(vk.convs_timed()), seconds_since(t), path.empty() ? "not saved" : path.c_str());
      if (!path.empty()) table->save(path, conv_choice_header(ctx));
      vk.set_conv_choice(table, ConvChoice::cached);
    }
  }
  vk.reset_peak();
  profiler.clear();
  ctx.allocator().reset_peak();
  RunOptions opt;
  opt.mode = md;
  double vk_s = 1e30, first_s = 0, gpu_ms = 0;
  std::map<ModelOutput, HostTensor> out;
  // With a measured choice, each timed run is followed by one with the kernels' heuristic on the same
  // input (interleaved, so the shared machine's load drifts over both alike).
  const bool compare = conv_choice != ConvChoice::heuristic;
  const std::shared_ptr<ConvChoiceTable> table = vk.conv_choice_table();
  const ConvChoice chosen = conv_choice == ConvChoice::automatic ? ConvChoice::automatic : ConvChoice::cached;
  double h_s = 1e30, h_gpu = 0;
  uint64_t from_table = 0;
  // One run: its wall seconds; `best` and `best_gpu` keep the fastest run's seconds and device ms;
  // `result` (when given) receives the outputs (the measured choice's are the ones compared).
  auto timed_run = [&](double& best, double& best_gpu, std::map<ModelOutput, HostTensor>* result) {
    const DeviceTraffic before = ctx.traffic();
    t = std::chrono::steady_clock::now();
    auto o = model.run(in, opt);
    const double s = seconds_since(t);
    if (s < best) best = s, best_gpu = (ctx.traffic() - before).gpu_ms;
    if (result) *result = std::move(o);
    return s;
  };
  for (int r = 0; r < runs; ++r) {
    if (r > 0) profiler.clear();  // the table shows the last run
    const uint64_t ft = vk.convs_from_table();
    const double s = timed_run(vk_s, gpu_ms, &out);
    std::fprintf(stderr, "progress: run %d took %.1f ms\n", r + 1, 1000 * s);
    from_table = vk.convs_from_table() - ft;
    if (r == 0) first_s = s;
    if (!compare) continue;
    vk.set_conv_choice(nullptr, ConvChoice::heuristic);
    timed_run(h_s, h_gpu, nullptr);
    vk.set_conv_choice(table, chosen);
  }
  const double frames = 1.0;  // one GS frame (one target) per run
  std::printf("vkunroll-bench-model: SelfUnroll-%s, %s (%lld parameters), %dx%d, %s, device %s\n", md == Mode::m ? "M" : "S",
              model_path.empty() ? "published configuration" : model_path.c_str(), static_cast<long long>(parameter_count(cfg)), W, H,
              precision_name(precision), ctx.info().name.c_str());
  std::printf("  vulkan : %.1f ms per GS frame (weights prepared in %.2f s; peak intermediates %.1f MiB, "
              "device buffers peak %.1f MiB, allocator peak %.1f MiB incl. %.1f MiB of weights as given)\n",
              1000 * vk_s / frames, prep, vk.peak_bytes() / 1048576.0, vk.device_peak_bytes() / 1048576.0,
              ctx.allocator().stats().peak_used_bytes / 1048576.0, vk.weight_bytes() / 1048576.0);
  if (runs > 1) std::printf("  vulkan : best of %d runs; the first took %.1f ms\n", runs, 1000 * first_s);
  if (compare) {
    std::printf("  vulkan : conv algorithms: %llu of the run's convs took the measured table's choice\n",
                static_cast<unsigned long long>(from_table));
    std::printf("  vulkan : with the heuristic conv choice %.1f ms per GS frame (device %.1f ms; runs interleaved); "
                "measured / heuristic = %.2f\n", 1000 * h_s, h_gpu, vk_s / h_s);
  }
  std::printf("  vulkan : device time %.1f ms of the %.1f ms frame (%.0f%%; the rest is host work and waits)\n", gpu_ms,
              1000 * vk_s, 100 * gpu_ms / (1000 * vk_s));
  if (profile) profiler.print(std::cout);  // the last timed run's dispatches, before the resident runs add theirs
  const ResidentTiming resident = time_resident(ctx, vk, model, in, md, runs);
  const double res_s = resident.seconds;
  if (res_s > 0) {
    // The same network on the same inputs: its image must equal the timed runs' (a check of the path timed).
    const std::vector<float>& ref = out.at(md == Mode::m ? ModelOutput::out : ModelOutput::fused).data;
    double diff = ref.size() == resident.image.size() ? 0.0 : 1e30;
    for (size_t i = 0; diff < 1e30 && i < ref.size(); ++i) diff = std::max(diff, double(std::fabs(ref[i] - resident.image[i])));
    std::printf("  vulkan : resident inputs, only the final image downloaded: %.1f ms per GS frame (device %.1f ms, %.0f%%; "
                "max abs diff to the timed runs' image %.3g)\n", 1000 * res_s, resident.gpu_ms, 100 * resident.gpu_ms / (1000 * res_s), diff);
  }
  if (!torch) return 0;

  const auto dir = std::filesystem::temp_directory_path() / ("vkunroll_bench_model_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  save_weights((dir / "w.safetensors").string(), w);
  std::vector<SafetensorsTensorRef> views;
  std::vector<std::pair<const char*, const HostTensor*>> named{{"rs", &in.rs}, {"ev1", &in.ev1}, {"ev2", &in.ev2}, {"ev3", &in.ev3}};
  if (!in.phys.data.empty()) named.push_back({"phys", &in.phys});
  for (auto [name, a] : named)
    views.push_back({name, StDType::F32, {a->shape.n, a->shape.c, a->shape.h, a->shape.w}, a->data.data(), a->data.size() * 4});
  write_safetensors((dir / "in.safetensors").string(), views);
  // CPU PyTorch has no fp16 convs: there the peer stays fp32 and the diffs are fp16's error.
  const std::string torch_precision = torch_device == "cuda" ? precision_name(precision) : "fp32";
  // tools/ is a package run from the source root (the mirror imports tools.model); the paths below are absolute.
  const std::string cmd = "cd " + std::string(VKUNROLL_SOURCE_DIR) + " && /usr/bin/python3 -m tools.bench.bench_mirror " +
                          (dir / "w.safetensors").string() + " " + (dir / "in.safetensors").string() + " " +
                          (dir / "out.safetensors").string() + " --mode " + mode +
                          (torch_threads ? " --threads " + std::to_string(torch_threads) : "") + " --device " + torch_device +
                          " --precision " + torch_precision + " --runs " + std::to_string(runs);
  if (std::system(cmd.c_str()) != 0) {
    std::fprintf(stderr, "the PyTorch mirror failed: %s\n", cmd.c_str());
    std::filesystem::remove_all(dir);
    return 1;
  }
  const SafetensorsFile ref = read_safetensors((dir / "out.safetensors").string());
  const double torch_s = std::stod(ref.metadata.at("seconds"));
  std::printf("  torch  : %.1f ms per GS frame (PyTorch mirror, %s, %s, %s)\n", 1000 * torch_s / frames, torch_device.c_str(),
              torch_precision.c_str(), ref.metadata.count("device") ? ref.metadata.at("device").c_str() : "?");
  if (ref.metadata.count("settings"))  // on CUDA: every PyTorch setting tried, the fastest is the peer
    std::printf("  torch  : settings %s; fastest %s\n", ref.metadata.at("settings").c_str(), ref.metadata.at("setting").c_str());
  std::printf("  ratio  : vulkan / torch = %.2f\n", vk_s / torch_s);
  if (res_s > 0) std::printf("  ratio  : resident vulkan / torch = %.2f (both with inputs on the device)\n", res_s / torch_s);
  for (const auto& [name, arr] : out) {
    const std::vector<float> r = ref.get(output_name(name)).to_f32();
    double err = 0, mx = 0;
    for (size_t i = 0; i < r.size(); ++i) {
      err = std::max(err, double(std::fabs(r[i] - arr.data[i])));
      mx = std::max(mx, double(std::fabs(r[i])));
    }
    std::printf("  max abs diff %-6s %.3g (max |value| %.3g)\n", output_name(name), err, mx);
  }
  std::filesystem::remove_all(dir);
  return 0;
}
