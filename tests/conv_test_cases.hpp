// The conv2d parity cases shared by test_conv2d.cpp and test_conv2d_igemm.cpp (and their data and
// reference by test_conv2d_coopmat.cpp): odd shapes, slices
// inside larger tensors, batches, activations and residuals, run against the CPU reference through
// the op harness (canaries around every output binding), in fp32 and fp16.
#pragma once
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <optional>

#include "kernel_test_util.hpp"
#include "op_test_harness.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vk_test_env.hpp"

namespace vkunroll::convtest {
using namespace vkunroll::ktest;

// fp32 with values of order 1 (weights scaled by 1/sqrt(fan-in)): max abs error 1e-4.
constexpr double kTol = 1e-4;
// fp16 storage (inputs, weights, residual and output rounded to half; fp32 arithmetic) against the
// same fp32 reference: see docs/kernels.md, "Precision" for the measured errors.
constexpr double kTolFp16 = 1e-2;

struct Case {
  int k, s;
  int64_t cin, cout, h, w;
  Act act;
  bool residual;
  int64_t in_extra_c = 0, in_c0 = 0, out_extra_c = 0, out_c0 = 0;  // slices inside larger tensors
  int64_t batch = 1, in_n0 = 0, in_batch_total = 1;
};

inline std::vector<Case> cases() {
  const Act lrelu01 = leaky_relu(0.1f), lrelu001 = leaky_relu(0.01f);
  return {
      // k  s cin cout  h   w  act                                res   in slice  out slice  batch
      {3, 1, 5, 7, 9, 11, lrelu001, true, 4, 2, 5, 3, 2, 0, 2},
      {3, 1, 17, 19, 16, 12, lrelu01, false},
      {3, 1, 8, 16, 13, 35, Act{}, true, 0, 0, 8, 8},
      {1, 1, 6, 3, 1, 1, Act{Activation::sigmoid}, false, 2, 1, 0, 0},
      {1, 1, 13, 9, 7, 10, lrelu01, true},
      {5, 1, 3, 9, 1, 13, Act{Activation::tanh}, false},
      {5, 1, 11, 6, 12, 9, Act{}, false, 0, 0, 3, 1},
      {3, 2, 4, 10, 13, 7, Act{Activation::hardsigmoid}, false},
      {3, 2, 6, 5, 1, 1, Act{}, false},
      {3, 2, 9, 12, 16, 18, lrelu01, false, 3, 3, 0, 0, 1, 1, 3},
      {3, 1, 7, 5, 21, 1, lrelu01, false},
      {5, 2, 5, 4, 11, 14, Act{Activation::sigmoid}, true},
      {1, 2, 3, 5, 9, 8, Act{}, false},
      // heads with 1, 2 and 3 output channels (direct computes only the real ones, 8 rows per invocation)
      {3, 1, 9, 1, 19, 13, Act{Activation::hardsigmoid}, false, 2, 1, 3, 2},
      {3, 1, 6, 2, 10, 23, Act{}, true},
      {3, 1, 5, 3, 17, 9, lrelu01, false, 0, 0, 0, 0, 2},
      // wide 1x1 convs: direct's 4 px x 48 and 8 px x 32 channel blocks
      {1, 1, 130, 96, 5, 7, lrelu01, true, 3, 1, 2, 1},
      {1, 1, 129, 64, 3, 11, Act{Activation::tanh}, false, 0, 0, 0, 0, 2, 0, 2},
  };
}

// A few cases for the canary runs on the whole-binding context: batch 2 slices, cout % 16 == 0 (the
// blocked path's 16-channel blocks), heads, strides, 5x5, the wide 1x1 blocks.
inline std::vector<Case> canary_cases() {
  const Act lrelu01 = leaky_relu(0.1f);
  return {
      {3, 1, 5, 16, 9, 11, lrelu01, true, 4, 2, 5, 3, 2, 0, 2},
      {3, 1, 6, 7, 6, 5, Act{}, false, 0, 0, 0, 0, 2},
      {1, 1, 13, 32, 7, 10, lrelu01, true, 0, 0, 0, 0, 2},
      {3, 2, 9, 12, 16, 18, lrelu01, false, 3, 3, 0, 0, 2, 1, 3},
      {5, 1, 11, 6, 12, 9, Act{}, false, 0, 0, 3, 1, 2},
      {3, 1, 9, 1, 19, 13, Act{Activation::hardsigmoid}, false, 2, 1, 3, 2, 2},
      {1, 1, 130, 96, 5, 7, lrelu01, true, 3, 1, 2, 1, 2},
  };
}

struct Limits {
  uint64_t winograd_scratch = ~0ull;
  int64_t direct_chunk = 0;
  bool texel_fetch = true;
  ConvOptions options;  // its precision is the run's
  int64_t pointwise_chunk = 0;
  int igemm_splits = 0;     // > 0: the igemm reduction in that many splits (split-K and its reduce)
  bool gpu_family = false;  // automatic takes the GPU family's choice (Conv2d::set_gpu_family)
};
// Input channels per pointwise dispatch at most (several chunks accumulate in the output).
inline Limits pointwise_chunks_of(int64_t channels) {
  Limits lim;
  lim.pointwise_chunk = channels;
  return lim;
}
constexpr auto kFp32 = Precision::fp32;
constexpr auto kFp16 = Precision::fp16;
using Precisions = std::vector<Precision>;

inline std::string case_name(const Case& c) {
  return "k" + std::to_string(c.k) + " s" + std::to_string(c.s) + " " + std::to_string(c.cin) + "->" +
         std::to_string(c.cout) + " " + std::to_string(c.h) + "x" + std::to_string(c.w) + " batch " +
         std::to_string(c.batch) + " act " + activation_name(c.act.kind) + (c.residual ? " residual" : "");
}

// What every conv parity case shares (this file's and test_conv2d_coopmat.cpp's): the weights and
// bias drawn, the inputs (the input, and a residual of the output's shape), the output slice among
// canaries, and the CPU reference. The caller adds `op.record`.
struct ConvCaseData {
  optest::OpCase op;
  HostTensor w, b;
  Conv2dParams p;
};
inline ConvCaseData conv_case_data(const Case& c, std::mt19937& rng) {
  ConvCaseData d;
  d.p = Conv2dParams{c.k, c.s, c.k / 2, c.act};
  const float wscale = 1.f / std::sqrt(static_cast<float>(c.cin * c.k * c.k));
  d.w = random_tensor({c.cout, c.cin, c.k, c.k}, rng, -wscale, wscale);
  d.b = random_tensor({1, 1, 1, c.cout}, rng, -0.5f, 0.5f);
  const int64_t oh = conv_output_size(c.h, c.k, c.s, c.k / 2), ow = conv_output_size(c.w, c.k, c.s, c.k / 2);
  const int64_t nb = std::max(c.batch, c.in_batch_total);
  d.op.what = case_name(c);
  d.op.inputs = {random_tensor({nb, c.cin + c.in_extra_c, c.h, c.w}, rng), random_tensor({nb, c.cout, oh, ow}, rng)};
  d.op.outputs = {{{c.batch, c.cout, oh, ow}, c.out_c0 + 1, c.out_extra_c - c.out_c0 + 1}};
  d.op.reference = [c, w = d.w, b = d.b, p = d.p](optest::HostRun& r) {
    const HostSlice residual(r.inputs[1], 0, -1, c.in_n0, c.batch);
    conv2d_ref(HostSlice(r.inputs[0], c.in_c0, c.cin, c.in_n0, c.batch), r.out(0), w, b, p,
               c.residual ? std::optional<HostSlice>(residual) : std::nullopt);
  };
  return d;
}

// One case of the op: weights drawn here, the conv built per precision when the case is recorded.
inline optest::OpCase conv_case(const Case& c, ConvAlgo algo, const Limits& lim, std::mt19937& rng) {
  ConvCaseData data = conv_case_data(c, rng);
  optest::OpCase k = std::move(data.op);
  k.record = [c, w = data.w, b = data.b, p = data.p, algo, lim](optest::DeviceRun& d) {
    ConvOptions options = lim.options;
    options.precision = d.precision;
    auto conv = std::make_shared<Conv2d>(d.ctx, w, b, p, "conv2d", nullptr, options);
    conv->set_winograd_scratch_limit(lim.winograd_scratch);
    conv->set_direct_chunk_limit(lim.direct_chunk);
    conv->set_pointwise_chunk_limit(lim.pointwise_chunk);
    conv->set_texel_fetch(lim.texel_fetch);
    conv->set_igemm_splits(lim.igemm_splits);
    conv->set_gpu_family(lim.gpu_family);
    if (!conv->supports(algo)) return false;
    const Slice residual(d.inputs[1], 0, -1, c.in_n0, c.batch);
    conv->record(d.stream, Slice(d.inputs[0], c.in_c0, c.cin, c.in_n0, c.batch), d.out(0),
                 c.residual ? std::optional<Slice>(residual) : std::nullopt, algo);
    d.keep_alive = conv;
    return true;
  };
  return k;
}

// Every case against the reference in each precision; the output slice sits among canaries
// (op_test_harness.hpp), which must survive: values outside the slice are never written.
inline void run_cases(Context& ctx, ConvAlgo algo, const std::vector<Case>& list, const Limits& lim = {},
               const Precisions& precisions = {kFp32, kFp16}) {
  std::mt19937 rng(1234);
  const bool chunked =
      lim.winograd_scratch != ~0ull || lim.direct_chunk > 0 || lim.pointwise_chunk > 0 || lim.igemm_splits > 1;
  optest::OpTest test{std::string("conv2d ") + conv_algo_name(algo) + (chunked ? " in chunks" : "") +
                          (lim.texel_fetch ? "" : " storage forms"),
                      {}, {kTol, kTolFp16}, precisions};
  for (const Case& c : list) test.cases.push_back(conv_case(c, algo, lim, rng));
  optest::run_op_test(ctx, test);
}
inline void run_cases(ConvAlgo algo, const Limits& lim = {}, const Precisions& precisions = {kFp32, kFp16}) {
  run_cases(vktest::context(), algo, cases(), lim, precisions);
}
}  // namespace vkunroll::convtest
