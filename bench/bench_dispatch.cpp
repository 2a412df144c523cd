// vkunroll-bench-dispatch: the host cost of recording a dispatch, push descriptors
// (VK_KHR_push_descriptor) against descriptor sets from pools, side by side in one run. A chain of
// small elementwise dispatches (the model's shape: many small ops) is recorded and submitted; the
// host time to record one dispatch and the whole submit's wall time are reported per path, with the
// ratio, alternating the paths `--reps` times.
//
// usage: vkunroll-bench-dispatch [--dispatches 2000] [--elements 4096] [--reps 5]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>

#include "bench_args.hpp"
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
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < dispatches; ++i) add(cs, Slice(i % 2 ? c : a), Slice(b), Slice(i % 2 ? a : c));
  const auto t1 = std::chrono::steady_clock::now();
  cs.submit_and_wait();
  const auto t2 = std::chrono::steady_clock::now();
  best.record_us_per_dispatch =
      std::min(best.record_us_per_dispatch, std::chrono::duration<double, std::micro>(t1 - t0).count() / dispatches);
  best.submit_ms = std::min(best.submit_ms, std::chrono::duration<double, std::milli>(t2 - t0).count());
}
}  // namespace

constexpr const char* kBench = "vkunroll-bench-dispatch";

int main(int argc, char** argv) {
  int dispatches = 2000, reps = 5;
  int64_t elements = 4096;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--dispatches" && i + 1 < argc) dispatches = static_cast<int>(bench_int_arg(kBench, a, argv[++i], 1, 1000000));
    else if (a == "--elements" && i + 1 < argc) elements = bench_int_arg(kBench, a, argv[++i], 1, 1LL << 30);
    else if (a == "--reps" && i + 1 < argc) reps = static_cast<int>(bench_int_arg(kBench, a, argv[++i], 1, 1000));
    else {
      std::fprintf(stderr, "usage: vkunroll-bench-dispatch [--dispatches N] [--elements N] [--reps N]\n");
      return 2;
    }
  }
  ContextOptions po, so;
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
  std::printf("vkunroll-bench-dispatch: %d dependent add dispatches of %lld floats, one submit, best of %d, device %s\n",
              dispatches, static_cast<long long>(elements), reps, pushed.info().name.c_str());
  std::printf("  push descriptors : %.2f us host time to record a dispatch, %.1f ms record + submit + wait\n",
              tp.record_us_per_dispatch, tp.submit_ms);
  std::printf("  descriptor sets  : %.2f us host time to record a dispatch, %.1f ms record + submit + wait\n",
              ts.record_us_per_dispatch, ts.submit_ms);
  std::printf("  ratio (push / sets): record %.2f, whole submit %.2f\n", tp.record_us_per_dispatch / ts.record_us_per_dispatch,
              tp.submit_ms / ts.submit_ms);
  return 0;
}
