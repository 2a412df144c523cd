// Event tensors: events per second of the GPU builder and of the exact CPU reference against the
// NumPy binning (float64 + np.add.at, tools/data/event_tensors_numpy.py), on the same 300,000 random
// events at 346x260, N = 16, three tensors (ev1, ev2, ev3) of one (frame, target) pair, in one run.
//
//   vkunroll-bench-event-tensor [--events 300000] [--repeat 5] [--batch 8]
//
// Times are the best of `repeat` runs (the machine is shared; best-of filters other load).
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <string>

#include "bench_args.hpp"
#include "bench_process.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/model/safetensors.hpp"
#include "vkunroll/kernels/event_tensor.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/profiler.hpp"

using namespace vkunroll;

namespace {

template <class F>
double best_of(int repeat, F&& f) {
  double best = 1e30;
  for (int i = 0; i < repeat; ++i) {
    const Stopwatch t;
    f();
    best = std::min(best, t.seconds());
  }
  return best;
}

// The same position-weighted checksum as the NumPy tool.
double check(const std::vector<float>& v) {
  double s = 0;
  for (size_t i = 0; i < v.size(); ++i) s += static_cast<double>(v[i]) * static_cast<double>(i % 9973);
  return s;
}

constexpr const char* kBench = "vkunroll-bench-event-tensor";

struct Args {
  size_t n_events = 300000;
  int repeat = 5, batch = 8;
};

// The command line; nullopt (said on stderr) when it is refused.
std::optional<Args> parse_args(int argc, char** argv) {
  Args a;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i];
    if (k == "--events") a.n_events = static_cast<size_t>(bench_int_arg(kBench, k, argv[i + 1], 1, 1LL << 34));
    else if (k == "--repeat") a.repeat = static_cast<int>(bench_int_arg(kBench, k, argv[i + 1], 1, 100000));
    else if (k == "--batch") a.batch = static_cast<int>(bench_int_arg(kBench, k, argv[i + 1], 1, 4096));
    else {
      std::fprintf(stderr, "%s: unknown option %s (--events N, --repeat N, --batch N)\n", kBench, k.c_str());
      return std::nullopt;
    }
  }
  if (argc % 2 == 0) {
    std::fprintf(stderr, "%s: %s needs a value\n", kBench, argv[argc - 1]);
    return std::nullopt;
  }
  return a;
}

// The events and the pair every side bins: a DAVIS346-like frame (line delay 70 us as DRE,
// exposure 10 ms), t* at tau = 0.5, N = 16.
struct Workload {
  static constexpr int W = 346, H = 260, N = 16;
  RowTiming tm{Rational(0), Rational(70), Rational(10000), H, Readout::top_down};
  Rational t_star = tm.target_time(Rational(1, 2));
  // A second stream of the same statistics: the sparse path's timings alternate the two, so each
  // build undoes cells other than the ones it counts (as with a new frame's events).
  EventStream ev, ev_b;
  EventTensorSpec spec{N, {}};
  std::vector<EventTensorPair> pairs = {{tm, t_star, std::nullopt}};
  size_t n_events = 0;
};

Workload make_workload(size_t n_events) {
  Workload w;
  w.n_events = n_events;
  std::mt19937_64 rng(42);
  auto random_events = [&](EventStream& e) {
    e.width = Workload::W;
    e.height = Workload::H;
    std::vector<int64_t> ts(n_events);
    for (auto& t : ts) t = -5000 + static_cast<int64_t>(rng() % 40000);  // frame spans 0 .. 28130 us
    std::sort(ts.begin(), ts.end());
    for (size_t i = 0; i < n_events; ++i)
      e.push(ts[i], static_cast<uint16_t>(rng() % Workload::W), static_cast<uint16_t>(rng() % Workload::H), (rng() & 1) ? 1 : -1);
  };
  random_events(w.ev);
  random_events(w.ev_b);
  return w;
}

struct NumpyBaseline {
  double seconds = 0;
  std::vector<double> checks;
};

// The NumPy baseline, on the same events (tools/data/event_tensors_numpy.py); nullopt (said on stderr)
// when it fails.
std::optional<NumpyBaseline> numpy_baseline(const Workload& w, int repeat) {
  const size_t n = w.n_events;
  const std::string in = (std::filesystem::temp_directory_path() / "vkunroll_bench_event_tensor.safetensors").string();
  std::vector<int8_t> p(w.ev.p.begin(), w.ev.p.end());
  write_safetensors(in,
                    std::vector<SafetensorsTensorRef>{{"t", StDType::I64, {int64_t(n)}, w.ev.t.data(), n * 8},
                                                      {"x", StDType::U16, {int64_t(n)}, w.ev.x.data(), n * 2},
                                                      {"y", StDType::U16, {int64_t(n)}, w.ev.y.data(), n * 2},
                                                      {"p", StDType::I8, {int64_t(n)}, p.data(), n}},
                    {{"width", std::to_string(Workload::W)}, {"height", std::to_string(Workload::H)}, {"bins", std::to_string(Workload::N)},
                     {"t0", "0"}, {"delay", "70"}, {"exposure", "10000"}, {"target", w.t_star.str()}});
  const std::string py = "/usr/bin/python3 " + std::string(VKUNROLL_SOURCE_DIR) +
                         "/tools/data/event_tensors_numpy.py --bench " + in + " --repeat " + std::to_string(repeat);
  const CommandOutput np_run = run_command(py, /*with_stderr=*/false);
  NumpyBaseline b;
  try {
    if (np_run.status != 0) throw Error("exit status " + std::to_string(np_run.status));
    const auto j = nlohmann::json::parse(np_run.text);
    b.seconds = j["seconds"].get<double>();
    b.checks = j["checks"].get<std::vector<double>>();
  } catch (const std::exception& e) {
    std::cerr << "NumPy baseline failed (" << py << "): " << e.what() << "\n" << np_run.text << "\n";
    return std::nullopt;
  }
  std::filesystem::remove(in);
  return b;
}

// The GPU builder's measurements, each the best of its rounds.
struct GpuTimes {
  double end_to_end = 1e30, reused = 1e30, dense = 1e30;  // seconds
  double resident = 1e30, sparse_resident = 1e30;          // seconds
  double device_ms = 1e30, fill_ms = 0, sparse_device_ms = 1e30, undo_ms = 0;  // timestamps
  EventBinAlgorithm default_algo = EventBinAlgorithm::automatic, device_algo = EventBinAlgorithm::automatic;
  std::vector<uint32_t> caps = {0, 8, 64};                 // per-row kernels' workgroups (0: one per row)
  std::vector<double> cap_dense, cap_sparse;               // device ms per cap
  double batch = 0, batch_reused = 0, cpu_batch = 0;       // seconds, the batch of targets
  double counted_batch = 0;                                // (event, tensor) pairs of the batch
  bool same = true;                                        // every GPU result equals the CPU reference
  EventTensors first;                                      // the end-to-end result (checked by the caller)
};

// Runs the GPU builder against the CPU reference `cpu` (of w.ev) and `cpu_b` (of w.ev_b).
class GpuBench {
 public:
  GpuBench(Context& ctx, const Workload& w, int repeat, const EventTensors& cpu, const EventTensors& cpu_b)
      : w_(w), repeat_(repeat), cpu_(cpu), cpu_b_(cpu_b), builder_(ctx, &prof_) {}

  // The load on the shared machine drifts, so every comparison interleaves its two sides: one call
  // of each per round, best of `repeat` rounds each. The sparse side alternates the two streams.
  void end_to_end(GpuTimes& t) {
    EventTensors dense, reused;
    t.first = builder_.build(w_.ev, w_.pairs, w_.spec);  // warm-up: pipelines, the sparse path's persistent outputs
    builder_.build(w_.ev, w_.pairs, w_.spec, reused);
    t.default_algo = builder_.last_algorithm();
    for (int r = 0; r < repeat_; ++r) {
      t.end_to_end = std::min(t.end_to_end, best_of(1, [&] { t.first = builder_.build(w_.ev, w_.pairs, w_.spec); }));
      t.reused = std::min(t.reused, best_of(1, [&] { builder_.build(stream(), w_.pairs, w_.spec, reused); }));
      t.same = t.same && same_as_cpu(reused, flip_);
      flip_ ^= 1;
      // The previous default (dense: zero fill + per-row binning into a fresh tensor).
      builder_.set_algorithm(EventBinAlgorithm::per_row);
      t.dense = std::min(t.dense, best_of(1, [&] { dense = builder_.build(w_.ev, w_.pairs, w_.spec); }));
      builder_.set_algorithm(EventBinAlgorithm::automatic);
    }
    t.same = t.same && same_as_cpu(t.first, false) && same_as_cpu(dense, false);
  }

  // Device-resident: dense (build_on_device: fresh tensor, zero fill + per-row binning) against
  // sparse (build_resident: undo + binning into the persistent output).
  void device_resident(GpuTimes& t) {
    (void)builder_.build_on_device(w_.ev, w_.pairs, w_.spec);
    (void)builder_.build_resident(w_.ev, w_.pairs, w_.spec);
    for (int r = 0; r < repeat_; ++r) {
      prof_.clear();
      t.resident = std::min(t.resident, best_of(1, [&] { (void)builder_.build_on_device(w_.ev, w_.pairs, w_.spec); }));
      t.device_algo = builder_.last_algorithm();
      if (const auto [total, fill] = device_ms("fill"); total < t.device_ms) t.device_ms = total, t.fill_ms = fill;
      prof_.clear();
      t.sparse_resident = std::min(t.sparse_resident, best_of(1, [&] { (void)builder_.build_resident(stream(), w_.pairs, w_.spec); }));
      flip_ ^= 1;
      if (const auto [total, undo] = device_ms("event_tensor_undo"); total < t.sparse_device_ms) t.sparse_device_ms = total, t.undo_ms = undo;
    }
  }

  // Device time by the per-row kernels' workgroup count (interleaved): dense, sparse.
  void row_workgroups(GpuTimes& t) {
    t.cap_dense.assign(t.caps.size(), 1e30);
    t.cap_sparse.assign(t.caps.size(), 1e30);
    for (int r = 0; r < repeat_; ++r)
      for (size_t c = 0; c < t.caps.size(); ++c) {
        builder_.set_row_workgroups(t.caps[c]);
        prof_.clear();
        (void)builder_.build_on_device(w_.ev, w_.pairs, w_.spec);
        t.cap_dense[c] = std::min(t.cap_dense[c], device_ms("fill").first);
        prof_.clear();
        (void)builder_.build_resident(stream(), w_.pairs, w_.spec);
        flip_ ^= 1;
        t.cap_sparse[c] = std::min(t.cap_sparse[c], device_ms("fill").first);
      }
    builder_.set_row_workgroups(64);
    const std::vector<float> all = builder_.build_resident(w_.ev, w_.pairs, w_.spec).download<float>();
    const size_t sl = cpu_.ev1.size();
    t.same = t.same && std::equal(cpu_.ev1.begin(), cpu_.ev1.end(), all.begin()) &&
             std::equal(cpu_.ev2.begin(), cpu_.ev2.end(), all.begin() + sl) &&
             std::equal(cpu_.ev3.begin(), cpu_.ev3.end(), all.begin() + 2 * sl);
  }

  // A batch of `targets` targets in one pass over the events (intra- and inter-frame taus).
  void batch(GpuTimes& t, int targets) {
    std::vector<EventTensorPair> many;
    for (int i = 0; i < targets; ++i)
      many.push_back({w_.tm, w_.tm.target_time(Rational(-1, 4) + Rational(3, 2) * Rational(i) / Rational(std::max(1, targets - 1))),
                      std::nullopt});
    t.batch = best_of(std::max(1, repeat_ / 2), [&] { (void)builder_.build(w_.ev, many, w_.spec); });
    EventTensors cpu_many;
    t.cpu_batch = best_of(1, [&] { cpu_many = build_event_tensors_ref(w_.ev, many, w_.spec); });
    EventTensors many_reused;
    builder_.build(w_.ev, many, w_.spec, many_reused);
    t.batch_reused = best_of(std::max(1, repeat_ / 2), [&] { builder_.build(w_.ev, many, w_.spec, many_reused); });
    t.same = t.same && cpu_many.ev1 == many_reused.ev1 && cpu_many.ev2 == many_reused.ev2 && cpu_many.ev3 == many_reused.ev3;
    t.counted_batch = counted(cpu_many);
  }

  // (event, tensor) counts: the work per pair, which the batch's inter-frame targets raise.
  static double counted(const EventTensors& t) {
    double s = 0;
    for (const auto* v : {&t.ev1, &t.ev2, &t.ev3})
      for (float x : *v) s += x;
    return s;
  }

 private:
  const EventStream& stream() const { return flip_ ? w_.ev_b : w_.ev; }
  bool same_as_cpu(const EventTensors& t, bool second) const {
    const EventTensors& c = second ? cpu_b_ : cpu_;
    return c.ev1 == t.ev1 && c.ev2 == t.ev2 && c.ev3 == t.ev3;
  }
  // Device time of one call from the profiler's timestamps: total and the part of one op.
  std::pair<double, double> device_ms(const char* part) const {
    double total = 0, of_part = 0;
    for (const auto& [name, st] : prof_.ops()) {
      total += st.total_ms;
      if (name == part) of_part = st.total_ms;
    }
    return {total, of_part};
  }

  const Workload& w_;
  int repeat_;
  const EventTensors& cpu_;
  const EventTensors& cpu_b_;
  Profiler prof_;
  EventTensorBuilder builder_;
  int flip_ = 1;
};

// The host's share of every GPU call: exact planning (rational thresholds) and row grouping.
double host_plan_seconds(const Workload& w, int repeat) {
  std::vector<uint32_t> scratch_packed, scratch_ranges;
  return best_of(repeat, [&] {
    const BinningPlan plan = plan_binning(w.ev, event_tensor_jobs(w.pairs), w.spec);
    (void)pack_events_by_row(w.ev, plan, scratch_packed, scratch_ranges);
  });
}

struct Report {
  const Workload& w;
  const Args& args;
  double np_s, cpu_s, plan_s;
  const EventTensors& cpu;
  const GpuTimes& t;
  std::string device;
};

void print_single_pair(const Report& r) {
  const GpuTimes& t = r.t;
  const double n = static_cast<double>(r.w.n_events), np_s = r.np_s;
  auto line = [&](const char* name, double s) {
    std::printf("  %-44s %9.2f ms  %8.2f M events/s  %6.1fx NumPy\n", name, s * 1e3, n / s / 1e6, np_s / s);
  };
  std::printf("event tensors: %zu random events, %dx%d, N=%d, ev1+ev2+ev3 of one pair (%zu events in its window)\n",
              r.w.n_events, Workload::W, Workload::H, Workload::N, t.first.events_considered);
  std::printf("device: %s; best of %d runs (shared machine: expect noise of 10-30%%)\n", r.device.c_str(), r.args.repeat);
  line("NumPy float64 + np.add.at", np_s);
  line("CPU reference (exact int128, 1 thread)", r.cpu_s);
  line("GPU builder, end to end (upload+bin+readback)", t.end_to_end);
  line("GPU builder, device-resident (upload+bin)", t.resident);
  line("GPU on the device (fill + binning)", t.device_ms / 1e3);
  std::printf("  %-44s %9.2f ms (zero fill %.2f ms + %s binning %.2f ms)\n", "GPU time on the device (timestamps)",
              t.device_ms, t.fill_ms, event_bin_algorithm_name(t.device_algo), t.device_ms - t.fill_ms);
  std::printf("  (end to end above: %s; device-resident above: build_on_device, a fresh dense tensor)\n",
              event_bin_algorithm_name(t.default_algo));
  line("GPU end to end, dense per-row (old default)", t.dense);
  line("GPU end to end into reused host tensors", t.reused);
  line("GPU sparse, device-resident (build_resident)", t.sparse_resident);
  line("GPU sparse on the device (undo + binning)", t.sparse_device_ms / 1e3);
  std::printf("  %-44s %9.2f ms (undo %.2f ms + sparse binning %.2f ms; streams alternate)\n",
              "GPU sparse time on the device (timestamps)", t.sparse_device_ms, t.undo_ms, t.sparse_device_ms - t.undo_ms);
  for (size_t c = 0; c < t.caps.size(); ++c)
    std::printf("  device time with %-3s row workgroups: dense %.2f ms, sparse %.2f ms\n",
                t.caps[c] ? std::to_string(t.caps[c]).c_str() : "780", t.cap_dense[c], t.cap_sparse[c]);
  // Floor of any dense design: one f32 write of every output cell, at this machine's fill rate.
  const size_t out_bytes = 3 * r.cpu.ev1.size() * 4;
  std::printf("  dense floor: %.1f MB of f32 output written once at the zero fill's %.1f GB/s = %.2f ms = %.1fx NumPy at most\n",
              out_bytes / 1e6, out_bytes / (t.fill_ms * 1e6), t.fill_ms, np_s / (t.fill_ms / 1e3));
  std::printf("  %-44s %9.2f ms\n", "host part: plan (exact thresholds) + row grouping", r.plan_s * 1e3);
  std::printf("  counted (event, tensor) pairs: %.0f for the pair\n", GpuBench::counted(r.cpu));
}

void print_batch_and_ratios(const Report& r) {
  const GpuTimes& t = r.t;
  const double n = static_cast<double>(r.w.n_events) * r.args.batch, np_s = r.np_s;
  auto line = [&](const char* name, double s) {
    std::printf("  %-44s %9.2f ms  %8.2f M events/s  %6.1fx NumPy\n", name, s * 1e3, n / s / 1e6, np_s / s * r.args.batch);
  };
  const double single = GpuBench::counted(r.cpu);
  std::printf("batch of %d targets, one pass over the events:\n", r.args.batch);
  std::printf("  counted (event, tensor) pairs: %.0f per pair (%.1fx the single pair's: inter-frame targets)\n",
              t.counted_batch / r.args.batch, t.counted_batch / r.args.batch / single);
  line("GPU builder, end to end", t.batch);
  line("GPU builder, end to end into reused host tensors", t.batch_reused);
  line("CPU reference", t.cpu_batch);
  std::printf("ratio GPU (end to end) / NumPy: %.1fx   (target >= 20x)\n", np_s / t.end_to_end);
  std::printf("ratio GPU (device-resident) / NumPy: %.1fx\n", np_s / t.resident);
  std::printf("ratio GPU (device time) / NumPy: %.1fx\n", np_s / (t.device_ms / 1e3));
  std::printf("ratio GPU (end to end, reused host tensors) / NumPy: %.1fx\n", np_s / t.reused);
  std::printf("ratio GPU (sparse device-resident) / NumPy: %.1fx\n", np_s / t.sparse_resident);
  std::printf("ratio GPU (sparse device time) / NumPy: %.1fx\n", np_s / (t.sparse_device_ms / 1e3));
  std::printf("ratio CPU reference / NumPy: %.1fx\n", np_s / r.cpu_s);
}

}  // namespace

int main(int argc, char** argv) {
  const std::optional<Args> args = parse_args(argc, argv);
  if (!args) return 2;
  const Workload w = make_workload(args->n_events);
  const std::optional<NumpyBaseline> np = numpy_baseline(w, args->repeat);
  if (!np) return 1;
  EventTensors cpu;
  const double cpu_s = best_of(args->repeat, [&] { cpu = build_event_tensors_ref(w.ev, w.pairs, w.spec); });
  const EventTensors cpu_b = build_event_tensors_ref(w.ev_b, w.pairs, w.spec);
  ContextOptions co;
  co.announce = true;
  Context ctx(co);
  GpuTimes t;
  {
    GpuBench bench(ctx, w, args->repeat, cpu, cpu_b);
    bench.end_to_end(t);
    bench.device_resident(t);
    bench.row_workgroups(t);
    const double plan_s = host_plan_seconds(w, args->repeat);
    bench.batch(t, args->batch);
    const Report report{w, *args, np->seconds, cpu_s, plan_s, cpu, t, ctx.info().name};
    print_single_pair(report);
    print_batch_and_ratios(report);
  }
  const bool numpy_same = np->checks.size() == 3 && np->checks[0] == check(cpu.ev1) && np->checks[1] == check(cpu.ev2) &&
                          np->checks[2] == check(cpu.ev3);
  std::printf("GPU == CPU: %s; CPU == NumPy (checksums): %s\n", t.same ? "yes" : "NO", numpy_same ? "yes" : "NO");
  return t.same && numpy_same ? 0 : 1;
}
