#include "vkunroll/host/model/conv_choice_tune.hpp"

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <cstdarg>
#include <memory>
#include <random>
#include <sstream>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/log.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/model/conv_choice.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll {

namespace {

// One line of the tune report (a printf format), to TuneOptions::report or the log sink.
__attribute__((format(printf, 2, 3))) void say(const TuneOptions& a, const char* format, ...) {
  std::va_list args, again;
  va_start(args, format);
  va_copy(again, args);
  const int n = std::vsnprintf(nullptr, 0, format, args);
  va_end(args);
  std::string line(static_cast<size_t>(std::max(n, 0)), '\0');
  std::vsnprintf(line.data(), line.size() + 1, format, again);
  va_end(again);
  if (!line.empty() && line.back() == '\n') line.pop_back();
  if (a.report) a.report(line);
  else log_info(line);
}

// Untimed submits before each candidate's timing: after the start's warm-up only the check run and
// the host's compare left the GPU idle, briefly. --warm-ms 0 turns both off.
double candidate_warm_ms(const TuneOptions& a) { return std::min(a.warm_ms, 2.0); }

// What one precision's pass timed (or, with --plan, counted).
struct TuneCount {
  uint64_t shapes = 0, candidates = 0, past_deadline = 0;
  double seconds = 0;
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
    const auto t0 = Clock::now();
    model.run(in, ro);
    const double wall = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    best = std::min(best, ctx.info().timestamps ? ctx.traffic().gpu_ms - g0 : wall);
  }
  return best;
}

// Prints each shape as it is timed, with the FMA ceiling read right after it (a dropped clock shows).
void print_timed_shape(const TuneOptions& a, Context& ctx, bool half, const std::string& key, const ConvChoiceEntry& e, double s,
                       TuneCount& count) {
  ++count.shapes;
  std::istringstream ts(e.timings);
  int listed = 0;
  for (std::string item; ts >> item;) listed += item.find("rejected") == std::string::npos;
  count.candidates += static_cast<uint64_t>(a.plan ? listed : e.timed);
  if (a.plan) {
    say(a, "  %-52s %d candidates: %s\n", key.c_str(), listed, e.timings.c_str());
    return;
  }
  const double ceiling = fma_ceiling_gflops(ctx, false, 1, 0.5);
  const double ceiling16 = half ? fma_ceiling_gflops(ctx, true, 1, 0.5) : 0;
  const double gf = e.ms > 0 ? e.flop / (e.ms * 1e6) : 0, best_ceiling = std::max(ceiling, ceiling16);
  say(a, "  %-52s %-9s %9.4f ms %9.1f GFLOP/s %5.1f%% of the ceiling %9.1f  %.2f s  heuristic %-9s [%s]\n",
              key.c_str(), e.algo.c_str(), e.ms, gf, best_ceiling > 0 ? 100 * gf / best_ceiling : 0.0, best_ceiling, s,
              e.heuristic.c_str(), e.timings.c_str());
}

// Meets every conv shape of the model at each size and mode, timing (retune) or counting (--plan) it.
TuneCount time_shapes(const TuneOptions& a, Context& ctx, VulkanBackend& backend, Model& model, const Weights& weights,
                      const std::vector<TuneSize>& sizes, Precision precision, std::mt19937& rng) {
  TuneCount count;
  const bool half = precision == Precision::fp16;
  backend.on_conv_timed([&](const std::string& key, const ConvChoiceEntry& e, double s) {
    print_timed_shape(a, ctx, half, key, e, s, count);
  });
  const auto t0 = Clock::now();
  for (const TuneSize& s : sizes) {
    if (a.s) {
      say(a, " S %dx%d batch %d\n", s.w, s.h, s.batch_s);
      model_ms(ctx, model, random_inputs(weights.config, s.batch_s, s.h, s.w, rng), Mode::s, 1);
    }
    if (a.m && weights.config.moa && s.batch_s == 1) {
      say(a, " M %dx%d batch 2\n", s.w, s.h);
      model_ms(ctx, model, random_inputs(weights.config, 2, s.h, s.w, rng), Mode::m, 1);
    }
  }
  count.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  count.past_deadline = backend.convs_past_deadline();
  backend.on_conv_timed({});
  return count;
}

// The arithmetic behind the time a table takes: candidates x the per-candidate budget.
void print_estimate(const TuneOptions& a, const TuneCount& c, Precision precision) {
  const double per = a.candidate_ms + candidate_warm_ms(a);
  if (a.plan)
    say(a, "%s: %llu conv shapes, %llu candidates counted (the model's runs took %.1f s)\n", precision_name(precision),
                static_cast<unsigned long long>(c.shapes), static_cast<unsigned long long>(c.candidates), c.seconds);
  else
    say(a, "%s: %llu conv shapes, %llu candidates timed in %.1f s (%.1f ms per candidate, all overhead included)\n",
                precision_name(precision), static_cast<unsigned long long>(c.shapes),
                static_cast<unsigned long long>(c.candidates), c.seconds,
                c.candidates ? 1000 * c.seconds / static_cast<double>(c.candidates) : 0.0);
  say(a, "  budget arithmetic: %llu candidates x (%.0f ms timed + %.0f ms warm) = %.1f s of timing, plus one checked "
              "run and the pipeline builds per candidate and one FMA ceiling read per shape\n",
              static_cast<unsigned long long>(c.candidates), a.candidate_ms, candidate_warm_ms(a),
              static_cast<double>(c.candidates) * per / 1000);
  if (c.past_deadline)
    say(a, "  %llu shapes were not timed: the %.0f s budget ran out; they keep the heuristic\n",
                static_cast<unsigned long long>(c.past_deadline), a.budget_s);
}

// The model's device time with each choice, measured side by side in this run.
void compare_choices(const TuneOptions& a, Context& ctx, VulkanBackend& backend, Model& model, const Weights& weights,
                     const std::vector<TuneSize>& sizes, const std::shared_ptr<ConvChoiceTable>& table, Precision precision,
                     std::mt19937& rng) {
  const int reps = std::min(a.reps, 3);
  for (const TuneSize& s : sizes) {
    const auto in = random_inputs(weights.config, s.batch_s, s.h, s.w, rng);
    backend.set_conv_choice(table, ConvChoice::heuristic);
    const double h_ms = model_ms(ctx, model, in, Mode::s, reps);
    backend.set_conv_choice(table, ConvChoice::cached);
    const double m_ms = model_ms(ctx, model, in, Mode::s, reps);
    say(a, "  S %dx%d batch %d %s: heuristic %.2f ms, measured %.2f ms per run (heuristic / measured %.2f)\n", s.w,
                s.h, s.batch_s, precision_name(precision), h_ms, m_ms, m_ms > 0 ? h_ms / m_ms : 0.0);
  }
}

void tune_precision(const TuneOptions& a, const Weights& weights, Precision precision, Clock::time_point deadline) {
  const std::vector<TuneSize>& sizes = a.sizes;
  ContextOptions co;
  co.device = a.device;
  Context ctx(co);
  if (!a.plan && conv_choice_path(ctx).empty()) throw UsageError("no cache directory: set VKUNROLL_CACHE_DIR, XDG_CACHE_HOME or HOME");
  if (!a.plan && a.check_table) a.check_table(conv_choice_path(ctx));  // before any timing, and before a foreign file is read
  std::vector<std::string> warnings;
  DeviceConvTable d = load_device_conv_table(ctx, {}, &warnings);  // this device's own table; tune never merges a committed one
  for (const auto& w : warnings) log_warning("vkunroll: warning: " + w);
  auto table = a.plan ? std::make_shared<ConvChoiceTable>() : d.table;
  VulkanBackend backend(ctx, nullptr, kPoolFlushBytes, precision);
  backend.set_conv_choice(table, ConvChoice::retune, ConvTimingBudget{a.reps, a.candidate_ms, candidate_warm_ms(a), a.plan});
  if (!a.plan) backend.set_conv_timing_deadline(deadline);  // a census times nothing: it counts every shape
  Model model(backend, weights);
  std::mt19937 rng(1);
  say(a, "tune %s on %s (driver %s, uuid %s)%s\n", precision_name(precision), ctx.info().name.c_str(),
              ctx.info().driver_version_string().c_str(), ctx.info().uuid_string().c_str(),
              a.plan ? ": counting every conv shape's candidates (a plan: nothing timed)" : "");
  if (!a.plan) {
    const auto w0 = Clock::now();
    warm_device(ctx, a.warm_ms);
    const double warmed = std::chrono::duration<double, std::milli>(Clock::now() - w0).count();
    const double c32 = fma_ceiling_gflops(ctx), c16 = precision == Precision::fp16 ? fma_ceiling_gflops(ctx, true) : 0;
    say(a, "FMA ceiling after %.0f ms of warm-up: %.1f GFLOP/s fp32, %.1f fp16 (0: not read); candidates timed for at "
                "most %.0f ms or %d submits each (the least device time counts), the ceiling read again after each shape\n",
                warmed, c32, c16, a.candidate_ms, a.reps);
  }
  const TuneCount count = time_shapes(a, ctx, backend, model, weights, sizes, precision, rng);
  print_estimate(a, count, precision);
  if (a.plan) return;
  table->save(d.path, conv_choice_header(ctx), conv_device_identity(ctx));
  size_t differs = 0, entries = 0;
  for (const auto& [key, e] : table->entries())
    if (key.find(precision_name(precision)) != std::string::npos) ++entries, differs += e.algo != e.heuristic;
  say(a, "table: %s (%zu entries of %s, %zu differ from the heuristic)\n", d.path.c_str(), entries,
              precision_name(precision), differs);
  if (a.compare) compare_choices(a, ctx, backend, model, weights, sizes, table, precision, rng);
}

}  // namespace

std::vector<TuneSize> tune_sizes(const std::vector<std::pair<int, int>>& frames, int tile, int halo) {
  std::vector<TuneSize> out;
  for (const auto& [w, h] : frames) out.push_back({w, h, 1});
  if (tile > 0) {
    if (tile % 32 || halo < 0 || halo % 32)
      throw OptionError("tile", std::to_string(tile),
                        "expected the tile and the halo (" + std::to_string(halo) + ") in multiples of 32 (the sparse tiles of `unroll`), 0 for none",
                        opt("tile") + " " + std::to_string(tile) + " " + opt("halo") + " " + std::to_string(halo) +
                            ": expected multiples of 32 (the sparse tiles of `unroll`), " + opt("tile") + " 0 for none");
    const int side = tile + 2 * halo;
    out.push_back({side, side, 1});
    out.push_back({side, side, 4});
  }
  return out;
}

Weights tune_model_weights(const std::string& model) {
  if (model == "published") return random_weights(ModelConfig::published(), 2024);
  std::error_code ec;
  if (!std::filesystem::exists(model, ec)) throw OptionError("model", model, "no such file (or 'published')", {}, ErrorKind::input_missing);
  return load_weights(model);
}

void tune_conv_choices(const Weights& weights, const TuneOptions& o) {
  const auto t0 = Clock::now();
  // One budget for every precision, so that the table of a short GPU window ends on time; precision
  // i of n stops timing at (i + 1) / n of it, so that the last one is not the one left untimed.
  for (size_t i = 0; i < o.precisions.size(); ++i) {
    const double share = o.budget_s * static_cast<double>(i + 1) / static_cast<double>(o.precisions.size());
    const auto deadline = o.budget_s > 0 ? t0 + std::chrono::milliseconds(static_cast<int64_t>(share * 1000))
                                         : Clock::time_point::max();
    tune_precision(o, weights, o.precisions[i], deadline);
  }
  say(o, "tune took %.1f s in all\n", std::chrono::duration<double>(Clock::now() - t0).count());
}

}  // namespace vkunroll
