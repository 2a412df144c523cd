// vkunroll tune: times every candidate algorithm of every conv shape a model meets at the given
// sizes on this device, keeps the fastest in the device's table (the cache directory, beside the
// pipeline cache) that `unroll` then uses, and reports the model's device time with the kernels'
// heuristic and with the measured choice, side by side in one run.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <random>
#include <sstream>

#include "vkunroll/host/cli/cli.hpp"
#include "vkunroll/host/cli/exit_codes.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/model/conv_choice.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll::cli {

namespace {

struct TuneArgs {
  std::string model, sizes = "346x260", precision = "fp32";
  int tile = 32, halo = 32, reps = 3;
  bool no_compare = false;
  DeviceArgs device;
};

struct Size {
  int w = 0, h = 0;
  int batch_s = 1;  // S batch items (tiles run several at once)
};

HostTensor random_tensor(Shape s, std::mt19937& rng, bool counts) {
  HostTensor t(s);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::uniform_int_distribution<int> c(0, 3);
  for (auto& x : t.data) x = counts ? static_cast<float>(c(rng)) : u(rng);
  return t;
}

ModelInputs random_inputs(const ModelConfig& cfg, int64_t b, int h, int w, std::mt19937& rng) {
  const int64_t e = cfg.ev_channels();
  ModelInputs in{random_tensor({b, 3, h, w}, rng, false), random_tensor({b, e, h, w}, rng, true),
                 random_tensor({b, e, h, w}, rng, true), random_tensor({b, e, h, w}, rng, true), {}};
  if (cfg.physics_input) in.phys = random_tensor({b, 3, h, w}, rng, false);
  return in;
}

// Device milliseconds of one model run (best of `reps`; wall time without timestamps).
double model_ms(Context& ctx, Model& model, const ModelInputs& in, Mode mode, int reps) {
  RunOptions ro;
  ro.mode = mode;
  ro.outputs = {mode == Mode::m ? ModelOutput::out : ModelOutput::fused};
  double best = 1e300;
  for (int r = 0; r < reps; ++r) {
    const double g0 = ctx.traffic().gpu_ms;
    const auto t0 = std::chrono::steady_clock::now();
    model.run(in, ro);
    const double wall = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    best = std::min(best, ctx.info().timestamps ? ctx.traffic().gpu_ms - g0 : wall);
  }
  return best;
}

std::vector<Size> tune_sizes(const TuneArgs& a) {
  std::vector<Size> out;
  std::stringstream ss(a.sizes);
  for (std::string item; std::getline(ss, item, ',');) {
    Size s;
    parse_size(item, "--size", s.w, s.h);
    out.push_back(s);
  }
  if (out.empty()) throw UsageError("--size '" + a.sizes + "': expected one or more WIDTHxHEIGHT, e.g. 346x260");
  if (a.tile > 0) {
    if (a.tile % 32 || a.halo < 0 || a.halo % 32)
      throw UsageError("--tile " + std::to_string(a.tile) + " --halo " + std::to_string(a.halo) +
                       ": expected multiples of 32 (the sparse tiles of `unroll`), --tile 0 for none");
    const int side = a.tile + 2 * a.halo;
    out.push_back({side, side, 1});
    out.push_back({side, side, 4});
  }
  return out;
}

int run_tune_precision(const TuneArgs& a, const Weights& weights, Precision precision, const std::vector<Size>& sizes) {
  ContextOptions co;
  co.device = a.device.device;
  Context ctx(co);
  const std::string path = conv_choice_path(ctx);
  if (path.empty()) throw UsageError("no cache directory: set VKUNROLL_CACHE_DIR, XDG_CACHE_HOME or HOME");
  std::vector<std::string> warnings;
  auto table = std::make_shared<ConvChoiceTable>(ConvChoiceTable::load(path, &warnings));
  for (const auto& w : warnings) std::cerr << "vkunroll: warning: " << w << "\n";
  VulkanBackend backend(ctx, nullptr, kPoolFlushBytes, precision);
  backend.set_conv_choice(table, ConvChoice::retune, a.reps);
  Model model(backend, weights);
  std::mt19937 rng(1);
  std::printf("tune %s on %s (%s): timing every conv shape's candidates, best of %d\n", precision_name(precision),
              ctx.info().name.c_str(), ctx.info().driver_version_string().c_str(), a.reps);
  for (const Size& s : sizes) {
    const auto in_s = random_inputs(weights.config, s.batch_s, s.h, s.w, rng);
    model_ms(ctx, model, in_s, Mode::s, 1);
    if (weights.config.moa && s.batch_s == 1) model_ms(ctx, model, random_inputs(weights.config, 2, s.h, s.w, rng), Mode::m, 1);
  }
  table->save(path, conv_choice_header(ctx));
  size_t differs = 0;
  for (const auto& [key, e] : table->entries()) {
    if (key.find(precision_name(precision)) == std::string::npos) continue;
    differs += e.algo != e.heuristic;
    std::printf("  %-48s %-9s %9.3f ms  heuristic %-9s  [%s]\n", key.c_str(), e.algo.c_str(), e.ms, e.heuristic.c_str(),
                e.timings.c_str());
  }
  std::printf("%llu conv shapes timed; %zu of this precision's entries differ from the heuristic; table: %s\n",
              static_cast<unsigned long long>(backend.convs_timed()), differs, path.c_str());
  if (a.no_compare) return kExitOk;
  // The model's device time with each choice, measured side by side in this run.
  for (const Size& s : sizes) {
    const auto in = random_inputs(weights.config, s.batch_s, s.h, s.w, rng);
    backend.set_conv_choice(table, ConvChoice::heuristic);
    const double h_ms = model_ms(ctx, model, in, Mode::s, a.reps);
    backend.set_conv_choice(table, ConvChoice::cached);
    const double m_ms = model_ms(ctx, model, in, Mode::s, a.reps);
    std::printf("  S %dx%d batch %d %s: heuristic %.2f ms, measured %.2f ms per run (heuristic / measured %.2f)\n", s.w,
                s.h, s.batch_s, precision_name(precision), h_ms, m_ms, m_ms > 0 ? h_ms / m_ms : 0.0);
  }
  return kExitOk;
}

int run_tune(const TuneArgs& a) {
  std::error_code ec;
  if (!std::filesystem::exists(a.model, ec)) throw InputMissingError("--model " + a.model + ": no such file");
  std::vector<Precision> precisions;
  if (a.precision == "all")
    precisions = {Precision::fp32, Precision::fp16};
  else
    precisions = {parse_precision(a.precision, "--precision")};
  const std::vector<Size> sizes = tune_sizes(a);
  const Weights weights = load_weights(a.model);
  apply_threads(a.device.threads);
  for (Precision p : precisions) run_tune_precision(a, weights, p, sizes);
  return kExitOk;
}

}  // namespace

Command add_tune(CLI::App& parent) {
  auto a = std::make_shared<TuneArgs>();
  CLI::App* c = parent.add_subcommand("tune", "time every conv algorithm per shape on this device, keep the fastest");
  c->description(
      "Runs the model at each --size (S, and M where the model has it) and on the sparse tiles (--tile plus\n"
      "--halo on each side, batch 1 and 4), timing every algorithm that applies to each conv shape; the\n"
      "fastest goes into this device's table in the cache directory (conv-choices-<uuid>-<driver>.tsv, beside\n"
      "the pipeline cache), which `unroll --conv-choice auto` reads. Then it times the model with the\n"
      "kernels' heuristic and with the measured choice, side by side.");
  c->add_option("--model", a->model, "SelfUnroll weights (safetensors)")->required()->type_name("FILE");
  c->add_option("--size", a->sizes, "frame sizes, comma-separated")->capture_default_str()->type_name("WxH[,WxH]");
  c->add_option("--tile", a->tile, "sparse tile interior to tune for (0: none)")->check(int_range(0, 4096))->capture_default_str()->type_name("N");
  c->add_option("--halo", a->halo, "the tiles' halo")->check(int_range(0, 4096))->capture_default_str()->type_name("N");
  c->add_option("--precision", a->precision, "fp32 | fp16 | all")
      ->check(CLI::IsMember({"fp32", "fp16", "all"}))->capture_default_str()->type_name("P");
  c->add_option("--reps", a->reps, "timed runs per candidate (the least counts)")->check(int_range(1, 100))->capture_default_str()->type_name("N");
  c->add_flag("--no-compare", a->no_compare, "skip the model timing with the heuristic against the measured choice");
  add_device_options(c, a->device);
  return {c, [a] { return run_tune(*a); }};
}

}  // namespace vkunroll::cli
