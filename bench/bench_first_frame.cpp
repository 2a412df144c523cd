// vkunroll-bench-first-frame: what the first model frame of a run costs, with the pipelines compiled
// on the context's worker threads while the frame is recorded (ContextOptions::pipeline_compile_threads;
// default, or --threads N) against each one compiled when it is first asked for (0 threads),
// in alternating rounds of one run. Each round makes a fresh context without the persistent pipeline
// cache (as a first run, or any run on lavapipe, whose cache stores nothing), runs one frame (the
// first: builds and all) and a second (warm), and checks that both settings give the same outputs.
//
// usage: vkunroll-bench-first-frame [--size 160x120] [--mode s|m] [--rounds 3] [--threads N]
//                                   [--model W.safetensors]
// Without --model: the published configuration with random weights (fixed seed).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "bench_args.hpp"
#include "bench_model_inputs.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline_compiler.hpp"

using namespace vkunroll;

namespace {

struct FirstFrame {
  double first_ms = 0, warm_ms = 0, build_ms = 0;
  uint32_t threads = 0;
  uint64_t submits = 0;  // in the first frame: each ends the recording that its pipelines compile during
  std::map<ModelOutput, HostTensor> out;
};

FirstFrame run_once(const Weights& w, const ModelInputs& in, Mode mode, std::optional<uint32_t> threads) {
  ContextOptions co;
  co.announce = false;
  co.persistent_pipeline_cache = false;
  co.pipeline_compile_threads = threads;
  Context ctx(co);
  VulkanBackend vk(ctx);
  Model model(vk, w);
  RunOptions o;
  o.mode = mode;
  FirstFrame f;
  f.threads = ctx.pipeline_compiler().threads();
  auto t = Clock::now();
  f.out = model.run(in, o);
  f.first_ms = ms_since(t);
  f.build_ms = ctx.traffic().pipeline_build_ms;
  f.submits = ctx.traffic().submits;
  t = Clock::now();
  model.run(in, o);
  f.warm_ms = ms_since(t);
  return f;
}

double max_abs_diff(const std::map<ModelOutput, HostTensor>& a, const std::map<ModelOutput, HostTensor>& b) {
  double d = 0;
  for (const auto& [name, t] : a) {
    const auto it = b.find(name);
    if (it == b.end() || it->second.data.size() != t.data.size()) return INFINITY;
    for (size_t i = 0; i < t.data.size(); ++i) d = std::max(d, double(std::fabs(t.data[i] - it->second.data[i])));
  }
  return d;
}

}  // namespace

int main(int argc, char** argv) {
  const char* bench = "vkunroll-bench-first-frame";
  long long W = 160, H = 120, rounds = 3;
  std::optional<uint32_t> threads;
  std::string mode = "s", model_path;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--size" && i + 1 < argc) {
      const BenchSize z = bench_size_arg(bench, a, argv[++i], 2, 4096);
      W = z.w, H = z.h;
    } else if (a == "--mode" && i + 1 < argc && (std::string(argv[i + 1]) == "s" || std::string(argv[i + 1]) == "m")) {
      mode = argv[++i];
    } else if (a == "--rounds" && i + 1 < argc) {
      rounds = bench_int_arg(bench, a, argv[++i], 1, 100);
    } else if (a == "--threads" && i + 1 < argc) {
      threads = static_cast<uint32_t>(bench_int_arg(bench, a, argv[++i], 1, 64));
    } else if (a == "--model" && i + 1 < argc) {
      model_path = argv[++i];
    } else {
      std::fprintf(stderr, "usage: %s [--size WxH] [--mode s|m] [--rounds N] [--threads N] [--model W.safetensors]\n", bench);
      return 2;
    }
  }
  try {
    const Weights w = model_path.empty() ? random_weights(ModelConfig::published(), 2024) : load_weights(model_path);
    const Mode md = mode == "m" ? Mode::m : Mode::s;
    const ModelInputs in = random_model_inputs(w.config, md == Mode::m ? 2 : 1, H, W);
    std::printf("first model frame, %s %lldx%lld, %s; fresh context each, no persistent pipeline cache\n",
                model_path.empty() ? "published S/M (random weights)" : model_path.c_str(), W, H, mode.c_str());
    std::printf("%-6s %-8s %10s %10s %12s %14s %8s\n", "round", "threads", "first ms", "warm ms", "first-warm", "build wait ms",
                "submits");
    std::vector<double> serial, parallel;  // first - warm: what the first frame adds
    double diff = 0;
    for (long long r = 0; r < rounds; ++r) {
      const FirstFrame s = run_once(w, in, md, 0u), p = run_once(w, in, md, threads);
      for (const FirstFrame* f : {&s, &p})
        std::printf("%-6lld %-8u %10.1f %10.1f %12.1f %14.1f %8llu\n", r + 1, f->threads, f->first_ms, f->warm_ms,
                    f->first_ms - f->warm_ms, f->build_ms, static_cast<unsigned long long>(f->submits));
      serial.push_back(s.first_ms - s.warm_ms);
      parallel.push_back(p.first_ms - p.warm_ms);
      diff = std::max(diff, max_abs_diff(s.out, p.out));
    }
    std::sort(serial.begin(), serial.end());
    std::sort(parallel.begin(), parallel.end());
    const double ms = serial[serial.size() / 2], mp = parallel[parallel.size() / 2];
    std::printf("median first-frame cost: %.1f ms compiled when asked for, %.1f ms on workers: %.2fx; outputs max abs diff %.3g\n",
                ms, mp, ms / mp, diff);
    return diff == 0 ? 0 : 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: %s\n", bench, e.what());
    return 1;
  }
}
