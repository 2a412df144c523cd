// vkunroll-bench-tune: `vkunroll tune` (host/model/conv_choice_tune.hpp) for the device bundle
// (tools/device/), whose binaries carry no CLI: the CLI links OpenCV's video stack, about 245 shared
// libraries, far over what the device tool carries. The same engine, flags and output.
//
// usage: vkunroll-bench-tune --model W.safetensors|published [--size WxH[,WxH]] [--modes s|m|s,m] [--tile N] [--halo N]
//                            [--precision fp32|fp16|all] [--reps N] [--candidate-ms MS] [--warm-ms MS]
//                            [--budget-s S] [--plan] [--no-compare]
#include <cstdio>
#include <sstream>
#include <string>

#include "bench_args.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/host/model/conv_choice_tune.hpp"
#include "vkunroll/host/model/weights.hpp"

using namespace vkunroll;

namespace {

constexpr const char* kBench = "vkunroll-bench-tune";

double ms_arg(const std::string& flag, const std::string& v) {
  return static_cast<double>(bench_int_arg(kBench, flag, v, 0, 3600000));
}

// -1: parsed; else the exit status (usage said on stderr).
int parse_args(int argc, char** argv, std::string& model, TuneOptions& o) {
  std::vector<std::pair<int, int>> frames{{346, 260}, {640, 480}};
  int tile = 32, halo = 32;
  for (int i = 1; i < argc; ++i) {
    const std::string f = argv[i];
    const bool has = i + 1 < argc;
    if (f == "--model" && has) model = argv[++i];
    else if (f == "--size" && has) {
      frames.clear();
      std::stringstream ss(argv[++i]);
      for (std::string item; std::getline(ss, item, ',');) {
        const BenchSize z = bench_size_arg(kBench, f, item, 2, 16384);
        frames.emplace_back(static_cast<int>(z.w), static_cast<int>(z.h));
      }
    } else if (f == "--modes" && has) {
      const std::string m = argv[++i];
      o.s = m.find('s') != std::string::npos, o.m = m.find('m') != std::string::npos;
    } else if (f == "--tile" && has) tile = static_cast<int>(bench_int_arg(kBench, f, argv[++i], 0, 4096));
    else if (f == "--halo" && has) halo = static_cast<int>(bench_int_arg(kBench, f, argv[++i], 0, 4096));
    else if (f == "--precision" && has) {
      const std::string p = argv[++i];
      o.precisions = p == "all" ? std::vector<Precision>{Precision::fp32, Precision::fp16}
                                : std::vector<Precision>{parse_precision(p, "--precision")};
    } else if (f == "--reps" && has) o.reps = static_cast<int>(bench_int_arg(kBench, f, argv[++i], 1, 1000));
    else if (f == "--candidate-ms" && has) o.candidate_ms = ms_arg(f, argv[++i]);
    else if (f == "--warm-ms" && has) o.warm_ms = ms_arg(f, argv[++i]);
    else if (f == "--budget-s" && has) o.budget_s = static_cast<double>(bench_int_arg(kBench, f, argv[++i], 0, 86400));
    else if (f == "--plan") o.plan = true;
    else if (f == "--no-compare") o.compare = false;
    else {
      std::fprintf(stderr, "usage: %s --model W.safetensors [--size WxH[,WxH]] [--modes s|m|s,m] [--tile N] [--halo N]\n"
                           "       [--precision fp32|fp16|all] [--reps N] [--candidate-ms MS] [--warm-ms MS] [--budget-s S]\n"
                           "       [--plan] [--no-compare]   (as `vkunroll tune`)\n", kBench);
      return 2;
    }
  }
  if (model.empty() || frames.empty()) {
    std::fprintf(stderr, "%s: --model and at least one --size are needed\n", kBench);
    return 2;
  }
  o.sizes = tune_sizes(frames, tile, halo);
  return -1;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    std::string model;
    TuneOptions o;
    if (const int status = parse_args(argc, argv, model, o); status >= 0) return status;
    o.report = [](const std::string& line) {
      std::printf("%s\n", line.c_str());
      std::fflush(stdout);
    };
    tune_conv_choices(tune_model_weights(model), o);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: %s\n", kBench, e.what());
    return 1;
  }
}
