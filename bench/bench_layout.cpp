// vkunroll-bench-layout: the model's data-movement ops (reflection pad, crop, space_to_depth,
// depth_to_space) at the published model's sizes, each against a plain `copy` of as many output
// values in the same run: the copy is this device's ceiling for moving those bytes, so the ratio
// says how much an op's index math costs beyond its traffic. Each op and its copy alternate
// `--reps` times; a chain of `--dispatches` dependent dispatches per timing, best taken.
//
// usage: vkunroll-bench-layout [--size 346x260] [--channels 16] [--batch 4] [--dispatches 10] [--reps 3]
//                              [--precision fp32|fp16|both]
#include <algorithm>
#include <cstdio>
#include <functional>
#include <string>
#include <vector>

#include "bench_args.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/kernels/elementwise.hpp"
#include "vkunroll/kernels/reflection_pad.hpp"
#include "vkunroll/kernels/space_to_depth.hpp"
#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/context.hpp"

using namespace vkunroll;

namespace {
struct Args {
  int64_t w = 346, h = 260, c = 16, n = 4;
  int dispatches = 10, reps = 3;
  std::string precision = "both";
};

// Wall time of `dispatches` recordings of `op` in one submit, after one untimed (pipeline build).
double time_chain(Context& ctx, int dispatches, const std::function<void(CommandStream&)>& op) {
  CommandStream cs(ctx);
  op(cs);
  cs.submit_and_wait();
  const Stopwatch clock;
  for (int i = 0; i < dispatches; ++i) op(cs);
  cs.submit_and_wait();
  return clock.ms() / dispatches;
}

struct Case {
  std::string name;
  Shape in, out;
  std::function<void(CommandStream&, Slice, Slice)> op;
};

void run_precision(Context& ctx, const Args& a, Precision prec) {
  const DType dt = precision_dtype(prec);
  const Pads pads = size_adapter_pads(a.h, a.w);
  const Shape img{a.n, a.c, a.h, a.w};
  const Shape padded{a.n, a.c, a.h + pads.top + pads.bottom, a.w + pads.left + pads.right};
  const Shape even{a.n, a.c, (a.h + 1) / 2 * 2, (a.w + 1) / 2 * 2};
  const std::vector<Case> cases = {
      {"reflection_pad", img, padded, [&](CommandStream& cs, Slice i, Slice o) { reflection_pad(cs, i, o, pads); }},
      {"reflection_pad (storage buffer)", img, padded,
       [&](CommandStream& cs, Slice i, Slice o) { reflection_pad(cs, i, o, pads, TexelReadOptions{false}); }},
      {"crop", padded, img, [&](CommandStream& cs, Slice i, Slice o) { crop(cs, i, o, pads.top, pads.left); }},
      {"space_to_depth", img, space_to_depth_shape(img), [](CommandStream& cs, Slice i, Slice o) { space_to_depth(cs, i, o); }},
      {"space_to_depth (storage buffer)", img, space_to_depth_shape(img),
       [](CommandStream& cs, Slice i, Slice o) { space_to_depth(cs, i, o, TexelReadOptions{false}); }},
      {"depth_to_space", space_to_depth_shape(even), even,
       [](CommandStream& cs, Slice i, Slice o) { depth_to_space(cs, i, o); }},
      {"depth_to_space (storage buffer)", space_to_depth_shape(even), even,
       [](CommandStream& cs, Slice i, Slice o) { depth_to_space(cs, i, o, TexelReadOptions{false}); }},
  };
  std::printf("%s, %s, %d dispatches a timing, best of %d (ms per dispatch; ratio = op / copy of its output's size)\n",
              precision_name(prec), ctx.info().name.c_str(), a.dispatches, a.reps);
  for (const Case& k : cases) {
    Tensor in(ctx, k.in, dt), out(ctx, k.out, dt), src(ctx, k.out, dt), dst(ctx, k.out, dt);
    double op_ms = 1e30, copy_ms = 1e30;
    for (int r = 0; r < a.reps; ++r) {
      op_ms = std::min(op_ms, time_chain(ctx, a.dispatches, [&](CommandStream& cs) { k.op(cs, Slice(in), Slice(out)); }));
      copy_ms = std::min(copy_ms, time_chain(ctx, a.dispatches, [&](CommandStream& cs) { copy(cs, Slice(src), Slice(dst)); }));
    }
    const double mb = static_cast<double>(k.out.count() * static_cast<int64_t>(dtype_size(dt))) / 1e6;
    std::printf("  %-32s %-18s -> %-18s %8.2f ms  copy %8.2f ms  ratio %5.2f  (%.1f MB written, copy %.2f GB/s)\n",
                k.name.c_str(), k.in.str().c_str(), k.out.str().c_str(), op_ms, copy_ms, op_ms / copy_ms, mb,
                mb / copy_ms);
  }
}
}  // namespace

int main(int argc, char** argv) {
  Args a;
  constexpr const char* kBench = "vkunroll-bench-layout";
  for (int i = 1; i < argc; ++i) {
    const std::string s = argv[i];
    const bool has_value = i + 1 < argc;
    if (s == "--size" && has_value) {
      const BenchSize z = bench_size_arg(kBench, s, argv[++i], 2, 16384);
      a.w = z.w;
      a.h = z.h;
    } else if (s == "--channels" && has_value) a.c = bench_int_arg(kBench, s, argv[++i], 1, 4096);
    else if (s == "--batch" && has_value) a.n = bench_int_arg(kBench, s, argv[++i], 1, 4096);
    else if (s == "--dispatches" && has_value) a.dispatches = static_cast<int>(bench_int_arg(kBench, s, argv[++i], 1, 100000));
    else if (s == "--reps" && has_value) a.reps = static_cast<int>(bench_int_arg(kBench, s, argv[++i], 1, 1000));
    else if (s == "--precision" && has_value) a.precision = argv[++i];
    else {
      std::fprintf(stderr, "%s: bad argument '%s'\nusage: %s [--size WxH] [--channels C] [--batch N] [--dispatches N] "
                   "[--reps N] [--precision fp32|fp16|both]\n", kBench, s.c_str(), kBench);
      return 2;
    }
  }
  if (a.precision != "fp32" && a.precision != "fp16" && a.precision != "both") {
    std::fprintf(stderr, "vkunroll-bench-layout: --precision '%s': expected fp32, fp16 or both\n", a.precision.c_str());
    return 2;
  }
  try {
    Context ctx;
    if (a.precision != "fp16") run_precision(ctx, a, Precision::fp32);
    if (a.precision != "fp32") run_precision(ctx, a, Precision::fp16);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "vkunroll-bench-layout: %s\n", e.what());
    return 1;
  }
  return 0;
}
