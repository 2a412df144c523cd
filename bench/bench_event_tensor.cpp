// Event tensors: events per second of the GPU builder and of the exact CPU reference against the
// NumPy binning (float64 + np.add.at, tools/data/event_tensors_numpy.py), on the same 300,000 random
// events at 346x260, N = 16, three tensors (ev1, ev2, ev3) of one (frame, target) pair, in one run.
//
//   vkunroll-bench-event-tensor [--events 300000] [--repeat 5] [--batch 8]
//
// Times are the best of `repeat` runs (the machine is shared; best-of filters other load).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>
#include <random>
#include <string>

#include "bench_args.hpp"
#include "bench_process.hpp"
#include "vkunroll/host/model/safetensors.hpp"
#include "vkunroll/kernels/event_tensor.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/profiler.hpp"

using namespace vkunroll;
using Clock = std::chrono::steady_clock;

namespace {

template <class F>
double best_of(int repeat, F&& f) {
  double best = 1e30;
  for (int i = 0; i < repeat; ++i) {
    const auto t0 = Clock::now();
    f();
    best = std::min(best, std::chrono::duration<double>(Clock::now() - t0).count());
  }
  return best;
}

// The same position-weighted checksum as the NumPy tool.
double check(const std::vector<float>& v) {
  double s = 0;
  for (size_t i = 0; i < v.size(); ++i) s += static_cast<double>(v[i]) * static_cast<double>(i % 9973);
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  size_t n_events = 300000;
  int repeat = 5, batch = 8;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i];
    if (k == "--events") n_events = static_cast<size_t>(bench_int_arg("vkunroll-bench-event-tensor", k, argv[i + 1], 1, 1LL << 34));
    else if (k == "--repeat") repeat = static_cast<int>(bench_int_arg("vkunroll-bench-event-tensor", k, argv[i + 1], 1, 100000));
    else if (k == "--batch") batch = static_cast<int>(bench_int_arg("vkunroll-bench-event-tensor", k, argv[i + 1], 1, 4096));
    else {
      std::fprintf(stderr, "vkunroll-bench-event-tensor: unknown option %s (--events N, --repeat N, --batch N)\n", k.c_str());
      return 2;
    }
  }
  if (argc % 2 == 0) {
    std::fprintf(stderr, "vkunroll-bench-event-tensor: %s needs a value\n", argv[argc - 1]);
    return 2;
  }
  const int W = 346, H = 260, N = 16;
  // DAVIS346-like frame: line delay 70 us (DRE), exposure 10 ms; t* at tau = 0.5.
  RowTiming tm{Rational(0), Rational(70), Rational(10000), H, Readout::top_down};
  const Rational t_star = tm.target_time(Rational(1, 2));
  EventStream ev;
  ev.width = W;
  ev.height = H;
  std::mt19937_64 rng(42);
  auto random_events = [&](EventStream& e) {
    std::vector<int64_t> ts(n_events);
    for (auto& t : ts) t = -5000 + static_cast<int64_t>(rng() % 40000);  // frame spans 0 .. 28130 us
    std::sort(ts.begin(), ts.end());
    for (size_t i = 0; i < n_events; ++i)
      e.push(ts[i], static_cast<uint16_t>(rng() % W), static_cast<uint16_t>(rng() % H), (rng() & 1) ? 1 : -1);
  };
  random_events(ev);
  // A second stream of the same statistics: the sparse path's timings alternate the two, so each
  // build undoes cells other than the ones it counts (as with a new frame's events).
  EventStream ev_b;
  ev_b.width = W;
  ev_b.height = H;
  random_events(ev_b);

  // The NumPy baseline, on the same events.
  const std::string in = (std::filesystem::temp_directory_path() / "vkunroll_bench_event_tensor.safetensors").string();
  std::vector<int8_t> p(ev.p.begin(), ev.p.end());
  write_safetensors(in,
                    std::vector<SafetensorsTensorRef>{{"t", StDType::I64, {int64_t(n_events)}, ev.t.data(), n_events * 8},
                                              {"x", StDType::U16, {int64_t(n_events)}, ev.x.data(), n_events * 2},
                                              {"y", StDType::U16, {int64_t(n_events)}, ev.y.data(), n_events * 2},
                                              {"p", StDType::I8, {int64_t(n_events)}, p.data(), n_events}},
                    {{"width", std::to_string(W)}, {"height", std::to_string(H)}, {"bins", std::to_string(N)},
                     {"t0", "0"}, {"delay", "70"}, {"exposure", "10000"}, {"target", t_star.str()}});
  const std::string py = "/usr/bin/python3 " + std::string(VKUNROLL_SOURCE_DIR) +
                         "/tools/data/event_tensors_numpy.py --bench " + in + " --repeat " + std::to_string(repeat);
  const CommandOutput np_run = run_command(py, /*with_stderr=*/false);
  const std::string& py_out = np_run.text;
  double np_s = 0;
  std::vector<double> np_checks;
  try {
    if (np_run.status != 0) throw Error("exit status " + std::to_string(np_run.status));
    const auto j = nlohmann::json::parse(py_out);
    np_s = j["seconds"].get<double>();
    np_checks = j["checks"].get<std::vector<double>>();
  } catch (const std::exception& e) {
    std::cerr << "NumPy baseline failed (" << py << "): " << e.what() << "\n" << py_out << "\n";
    return 1;
  }
  std::filesystem::remove(in);

  const EventTensorSpec spec{N, {}};
  const std::vector<EventTensorPair> pairs = {{tm, t_star, std::nullopt}};
  EventTensors cpu;
  const double cpu_s = best_of(repeat, [&] { cpu = build_event_tensors_ref(ev, pairs, spec); });

  ContextOptions co;
  co.announce = true;
  Context ctx(co);
  Profiler prof;
  EventTensorBuilder builder(ctx, &prof);
  // Device time of one call from the profiler's timestamps: total and the part of one op.
  auto device_ms = [&](const char* part) {
    double total = 0, of_part = 0;
    for (const auto& [name, st] : prof.ops()) {
      total += st.total_ms;
      if (name == part) of_part = st.total_ms;
    }
    return std::pair<double, double>{total, of_part};
  };
  // Alternates the two streams; checks every result against the CPU reference of its stream.
  const EventTensors cpu_b = build_event_tensors_ref(ev_b, pairs, spec);
  bool sparse_same = true;
  auto same_as_cpu = [&](const EventTensors& t, bool second) {
    const EventTensors& c = second ? cpu_b : cpu;
    return c.ev1 == t.ev1 && c.ev2 == t.ev2 && c.ev3 == t.ev3;
  };

  // The load on the shared machine drifts, so every comparison interleaves its two sides: one call
  // of each per round, best of `repeat` rounds each. The sparse side alternates the two streams.
  EventTensors gpu, dense, reused;
  gpu = builder.build(ev, pairs, spec);  // warm-up: pipelines, the sparse path's persistent outputs
  builder.build(ev, pairs, spec, reused);
  const EventBinAlgorithm default_algo = builder.last_algorithm();
  int flip = 1;
  double gpu_s = 1e30, gpu_reuse_s = 1e30, dense_s = 1e30;
  for (int r = 0; r < repeat; ++r) {
    gpu_s = std::min(gpu_s, best_of(1, [&] { gpu = builder.build(ev, pairs, spec); }));
    gpu_reuse_s = std::min(gpu_reuse_s, best_of(1, [&] { builder.build(flip ? ev_b : ev, pairs, spec, reused); }));
    sparse_same = sparse_same && same_as_cpu(reused, flip);
    flip ^= 1;
    // The previous default (dense: zero fill + per-row binning into a fresh tensor).
    builder.set_algorithm(EventBinAlgorithm::per_row);
    dense_s = std::min(dense_s, best_of(1, [&] { dense = builder.build(ev, pairs, spec); }));
    builder.set_algorithm(EventBinAlgorithm::automatic);
  }
  // Device-resident: dense (build_on_device: fresh tensor, zero fill + per-row binning) against
  // sparse (build_resident: undo + binning into the persistent output).
  (void)builder.build_on_device(ev, pairs, spec);
  (void)builder.build_resident(ev, pairs, spec);
  double dev_s = 1e30, disp_ms = 1e30, fill_ms = 0, res_s = 1e30, res_disp_ms = 1e30, res_undo_ms = 0;
  EventBinAlgorithm device_algo = EventBinAlgorithm::automatic;
  for (int r = 0; r < repeat; ++r) {
    prof.clear();
    dev_s = std::min(dev_s, best_of(1, [&] { (void)builder.build_on_device(ev, pairs, spec); }));
    device_algo = builder.last_algorithm();
    const auto [total, fill] = device_ms("fill");
    if (total < disp_ms) {
      disp_ms = total;
      fill_ms = fill;
    }
    prof.clear();
    res_s = std::min(res_s, best_of(1, [&] { (void)builder.build_resident(flip ? ev_b : ev, pairs, spec); }));
    flip ^= 1;
    const auto [rtotal, undo] = device_ms("event_tensor_undo");
    if (rtotal < res_disp_ms) {
      res_disp_ms = rtotal;
      res_undo_ms = undo;
    }
  }
  // Device time by the per-row kernels' workgroup count (interleaved): dense, sparse.
  const std::vector<uint32_t> caps = {0, 8, 64};
  std::vector<double> cap_dense(caps.size(), 1e30), cap_sparse(caps.size(), 1e30);
  for (int r = 0; r < repeat; ++r)
    for (size_t c = 0; c < caps.size(); ++c) {
      builder.set_row_workgroups(caps[c]);
      prof.clear();
      (void)builder.build_on_device(ev, pairs, spec);
      cap_dense[c] = std::min(cap_dense[c], device_ms("fill").first);
      prof.clear();
      (void)builder.build_resident(flip ? ev_b : ev, pairs, spec);
      flip ^= 1;
      cap_sparse[c] = std::min(cap_sparse[c], device_ms("fill").first);
    }
  builder.set_row_workgroups(64);
  {
    std::vector<float> all = builder.build_resident(ev, pairs, spec).download<float>();
    const size_t sl = cpu.ev1.size();
    sparse_same = sparse_same && std::equal(cpu.ev1.begin(), cpu.ev1.end(), all.begin()) &&
                  std::equal(cpu.ev2.begin(), cpu.ev2.end(), all.begin() + sl) &&
                  std::equal(cpu.ev3.begin(), cpu.ev3.end(), all.begin() + 2 * sl);
  }

  // The host's share of every GPU call: exact planning (rational thresholds) and row grouping.
  std::vector<uint32_t> scratch_packed, scratch_ranges;
  const double plan_s = best_of(repeat, [&] {
    const BinningPlan plan = plan_binning(ev, event_tensor_jobs(pairs), spec);
    (void)pack_events_by_row(ev, plan, scratch_packed, scratch_ranges);
  });
  // Floor of any dense design: one f32 write of every output cell, at this machine's fill rate.
  const size_t out_bytes = 3 * cpu.ev1.size() * 4;
  // A batch of targets in one pass over the events (intra- and inter-frame taus).
  std::vector<EventTensorPair> many;
  for (int i = 0; i < batch; ++i)
    many.push_back({tm, tm.target_time(Rational(-1, 4) + Rational(3, 2) * Rational(i) / Rational(std::max(1, batch - 1))),
                    std::nullopt});
  const double gpu_batch_s = best_of(std::max(1, repeat / 2), [&] { (void)builder.build(ev, many, spec); });
  EventTensors cpu_many;
  const double cpu_batch_s = best_of(1, [&] { cpu_many = build_event_tensors_ref(ev, many, spec); });
  EventTensors many_reused;
  builder.build(ev, many, spec, many_reused);
  const double gpu_batch_reuse_s = best_of(std::max(1, repeat / 2), [&] { builder.build(ev, many, spec, many_reused); });
  sparse_same = sparse_same && cpu_many.ev1 == many_reused.ev1 && cpu_many.ev2 == many_reused.ev2 &&
                cpu_many.ev3 == many_reused.ev3;
  // (event, tensor) counts: the work per pair, which the batch's inter-frame targets raise.
  auto counted = [](const EventTensors& t) {
    double s = 0;
    for (const auto* v : {&t.ev1, &t.ev2, &t.ev3})
      for (float x : *v) s += x;
    return s;
  };

  const bool same = cpu.ev1 == gpu.ev1 && cpu.ev2 == gpu.ev2 && cpu.ev3 == gpu.ev3 && cpu.ev1 == dense.ev1 &&
                    cpu.ev2 == dense.ev2 && cpu.ev3 == dense.ev3 && sparse_same;
  const bool numpy_same = np_checks.size() == 3 && np_checks[0] == check(cpu.ev1) && np_checks[1] == check(cpu.ev2) &&
                          np_checks[2] == check(cpu.ev3);
  const double n = static_cast<double>(n_events);
  auto line = [&](const char* name, double s, double events) {
    std::printf("  %-44s %9.2f ms  %8.2f M events/s  %6.1fx NumPy\n", name, s * 1e3, events / s / 1e6, np_s / s * (events / n));
  };
  std::printf("event tensors: %zu random events, %dx%d, N=%d, ev1+ev2+ev3 of one pair (%zu events in its window)\n",
              n_events, W, H, N, gpu.events_considered);
  std::printf("device: %s; best of %d runs (shared machine: expect noise of 10-30%%)\n", ctx.info().name.c_str(), repeat);
  line("NumPy float64 + np.add.at", np_s, n);
  line("CPU reference (exact int128, 1 thread)", cpu_s, n);
  line("GPU builder, end to end (upload+bin+readback)", gpu_s, n);
  line("GPU builder, device-resident (upload+bin)", dev_s, n);
  line("GPU on the device (fill + binning)", disp_ms / 1e3, n);
  std::printf("  %-44s %9.2f ms (zero fill %.2f ms + %s binning %.2f ms)\n", "GPU time on the device (timestamps)",
              disp_ms, fill_ms, event_bin_algorithm_name(device_algo), disp_ms - fill_ms);
  std::printf("  (end to end above: %s; device-resident above: build_on_device, a fresh dense tensor)\n",
              event_bin_algorithm_name(default_algo));
  line("GPU end to end, dense per-row (old default)", dense_s, n);
  line("GPU end to end into reused host tensors", gpu_reuse_s, n);
  line("GPU sparse, device-resident (build_resident)", res_s, n);
  line("GPU sparse on the device (undo + binning)", res_disp_ms / 1e3, n);
  std::printf("  %-44s %9.2f ms (undo %.2f ms + sparse binning %.2f ms; streams alternate)\n",
              "GPU sparse time on the device (timestamps)", res_disp_ms, res_undo_ms, res_disp_ms - res_undo_ms);
  for (size_t c = 0; c < caps.size(); ++c)
    std::printf("  device time with %-3s row workgroups: dense %.2f ms, sparse %.2f ms\n",
                caps[c] ? std::to_string(caps[c]).c_str() : "780", cap_dense[c], cap_sparse[c]);
  std::printf("  dense floor: %.1f MB of f32 output written once at the zero fill's %.1f GB/s = %.2f ms = %.1fx NumPy at most\n",
              out_bytes / 1e6, out_bytes / (fill_ms * 1e6), fill_ms, np_s / (fill_ms / 1e3));
  std::printf("  %-44s %9.2f ms\n", "host part: plan (exact thresholds) + row grouping", plan_s * 1e3);
  std::printf("  counted (event, tensor) pairs: %.0f for the pair\n", counted(cpu));
  std::printf("batch of %d targets, one pass over the events:\n", batch);
  std::printf("  counted (event, tensor) pairs: %.0f per pair (%.1fx the single pair's: inter-frame targets)\n",
              counted(cpu_many) / batch, counted(cpu_many) / batch / counted(cpu));
  line("GPU builder, end to end", gpu_batch_s, n * batch);
  line("GPU builder, end to end into reused host tensors", gpu_batch_reuse_s, n * batch);
  line("CPU reference", cpu_batch_s, n * batch);
  std::printf("ratio GPU (end to end) / NumPy: %.1fx   (target >= 20x)\n", np_s / gpu_s);
  std::printf("ratio GPU (device-resident) / NumPy: %.1fx\n", np_s / dev_s);
  std::printf("ratio GPU (device time) / NumPy: %.1fx\n", np_s / (disp_ms / 1e3));
  std::printf("ratio GPU (end to end, reused host tensors) / NumPy: %.1fx\n", np_s / gpu_reuse_s);
  std::printf("ratio GPU (sparse device-resident) / NumPy: %.1fx\n", np_s / res_s);
  std::printf("ratio GPU (sparse device time) / NumPy: %.1fx\n", np_s / (res_disp_ms / 1e3));
  std::printf("ratio CPU reference / NumPy: %.1fx\n", np_s / cpu_s);
  std::printf("GPU == CPU: %s; CPU == NumPy (checksums): %s\n", same ? "yes" : "NO", numpy_same ? "yes" : "NO");
  return same && numpy_same ? 0 : 1;
}
