// conv_transpose2d parity: every algorithm against the CPU reference (PyTorch weight layout).
#include <gtest/gtest.h>

#include <cmath>
#include <memory>

#include "kernel_test_util.hpp"
#include "op_test_harness.hpp"
#include "vkunroll/kernels/conv_transpose2d.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::ktest;

namespace {
constexpr double kTol = 1e-4;      // fp32, values of order 1
constexpr double kTolFp16 = 1e-2;  // fp16 storage against the fp32 reference (docs/kernels.md, "Precision")

struct Case {
  int64_t cin, cout, h, w;
  Act act;
  int64_t in_extra_c = 0, in_c0 = 0, out_extra_c = 0, out_c0 = 0, batch = 1;
  int k = 4, s = 2, pad = 1;  // the UNets' deconvs unless a case says otherwise
};

struct Variant {
  ConvTransposeAlgo algo = ConvTransposeAlgo::automatic;
  int64_t direct_chunk_limit = 0;
  bool texel_fetch = true;
  std::vector<Precision> precisions{Precision::fp32, Precision::fp16};
  int igemm_splits = 0;  // > 0: igemm's reduction in that many splits
};

// One case of the op: weights drawn here, the op built per precision when the case is recorded.
optest::OpCase deconv_case(const Case& c, const Variant& v, std::mt19937& rng) {
  const ConvTranspose2dParams p{c.k, c.s, c.pad, c.act};
  const float ws = 1.f / std::sqrt(static_cast<float>(c.cin * c.k * c.k / (c.s * c.s)));
  const HostTensor w = random_tensor({c.cin, c.cout, c.k, c.k}, rng, -ws, ws);
  const int64_t oh = conv_transpose_output_size(c.h, c.k, c.s, c.pad), ow = conv_transpose_output_size(c.w, c.k, c.s, c.pad);
  const HostTensor b = random_tensor({1, 1, 1, c.cout}, rng, -0.5f, 0.5f);
  optest::OpCase k;
  k.what = std::to_string(c.cin) + "->" + std::to_string(c.cout) + " " + std::to_string(c.h) + "x" +
           std::to_string(c.w) + " batch " + std::to_string(c.batch) + " k" + std::to_string(c.k) + " s" +
           std::to_string(c.s) + " p" + std::to_string(c.pad);
  k.inputs = {random_tensor({c.batch, c.cin + c.in_extra_c, c.h, c.w}, rng)};
  k.outputs = {{{c.batch, c.cout, oh, ow}, c.out_c0 + 1, c.out_extra_c - c.out_c0 + 1}};
  k.reference = [c, w, b, p](optest::HostRun& r) {
    conv_transpose2d_ref(HostSlice(r.inputs[0], c.in_c0, c.cin), r.out(0), w, b, p);
  };
  k.record = [c, w, b, p, v](optest::DeviceRun& d) {
    ConvOptions opt;
    opt.precision = d.precision;
    auto deconv = std::make_shared<ConvTranspose2d>(d.ctx, w, b, p, "conv_transpose2d", opt);
    deconv->set_direct_chunk_limit(v.direct_chunk_limit);
    deconv->set_texel_fetch(v.texel_fetch);
    deconv->set_igemm_splits(v.igemm_splits);
    if (!deconv->supports(v.algo)) return false;
    deconv->record(d.stream, Slice(d.inputs[0], c.in_c0, c.cin), d.out(0), v.algo);
    d.keep_alive = deconv;
    return true;
  };
  return k;
}

void run_cases(Context& ctx, const Variant& v) {
  std::mt19937 rng(99);
  const std::vector<Case> cases{
      {5, 7, 9, 11, leaky_relu(0.1f), 3, 2, 4, 4, 2},
      {16, 8, 1, 1, Act{}},
      {3, 9, 1, 13, Act{Activation::tanh}},
      {12, 6, 7, 1, Act{Activation::sigmoid}, 0, 0, 6, 0},
      {9, 13, 6, 5, Act{Activation::hardsigmoid}},
      {32, 16, 11, 9, leaky_relu(0.01f), 0, 0, 16, 16, 2},
      {33, 64, 5, 3, leaky_relu(0.2f), 2, 1, 0, 0, 1},  // direct's 32-channel blocks
      // other kernels and strides (the igemm sub-pixel form's general case; the others skip them)
      {6, 5, 7, 6, Act{}, 0, 0, 0, 0, 2, 2, 2, 0},
      {7, 4, 5, 4, leaky_relu(0.1f), 0, 0, 0, 0, 1, 6, 3, 2},
      {4, 20, 6, 9, Act{Activation::tanh}, 0, 0, 0, 0, 1, 4, 2, 2},
  };
  optest::OpTest test{std::string("conv_transpose2d ") + conv_transpose_algo_name(v.algo) +
                          (v.direct_chunk_limit ? " in chunks" : "") + (v.texel_fetch ? "" : " storage input") +
                          (v.igemm_splits > 1 ? " split-K" : ""),
                      {}, {kTol, kTolFp16}, v.precisions};
  for (const Case& c : cases) test.cases.push_back(deconv_case(c, v, rng));
  optest::run_op_test(ctx, test);
}
void run_cases(const Variant& v) { run_cases(vktest::context(), v); }
constexpr auto kFp32 = Precision::fp32;
}  // namespace

// Every algorithm in both precisions; fp16 against the same fp32 reference.
TEST(ConvTranspose2d, NaiveMatchesReference) { run_cases({ConvTransposeAlgo::naive}); }
TEST(ConvTranspose2d, BlockedMatchesReference) { run_cases({ConvTransposeAlgo::blocked}); }
TEST(ConvTranspose2d, DirectMatchesReference) { run_cases({ConvTransposeAlgo::direct}); }
// 3 input channels per dispatch: chunks accumulate in the output, the last applies the activation.
TEST(ConvTranspose2d, DirectInChunksMatchesReference) { run_cases({ConvTransposeAlgo::direct, 3, true, {kFp32}}); }
// Chunk starts on a 256-byte uniform offset alignment (see Conv2d.DirectInChunksOnAStrictUniformAlignment).
TEST(ConvTranspose2d, DirectInChunksOnAStrictUniformAlignment) {
  run_cases(vktest::strict_uniform_context(), {ConvTransposeAlgo::direct, 3});
}
// The input through a storage buffer instead of a texel buffer (the fallback for huge inputs).
TEST(ConvTranspose2d, DirectStorageInputMatchesReference) { run_cases({ConvTransposeAlgo::direct, 0, false}); }
// The GPU family: the phases as stride-1 convs in one dispatch, whole and split-K (with its reduce).
TEST(ConvTranspose2d, IgemmMatchesReference) {
  run_cases({ConvTransposeAlgo::igemm});
  Variant split{ConvTransposeAlgo::igemm};
  split.igemm_splits = 2;
  run_cases(split);
}
TEST(ConvTranspose2d, AutomaticMatchesReference) { run_cases({ConvTransposeAlgo::automatic, 0, true, {kFp32}}); }

// Every algorithm on a context that binds whole tensors: a write outside the output slice lands on
// a canary inside the binding (lavapipe drops writes past a binding).
TEST(ConvTranspose2d, WritesNothingOutsideItsSlice) {
  Context& ctx = vktest::whole_binding_context();
  for (ConvTransposeAlgo a : {ConvTransposeAlgo::naive, ConvTransposeAlgo::blocked, ConvTransposeAlgo::direct})
    run_cases(ctx, {a, 0, true, {kFp32}});
  run_cases(ctx, {ConvTransposeAlgo::direct, 3, true, {kFp32}});
  run_cases(ctx, {ConvTransposeAlgo::direct, 0, false, {kFp32}});
  run_cases(ctx, {ConvTransposeAlgo::igemm, 0, true, {kFp32, Precision::fp16}});
  run_cases(ctx, {ConvTransposeAlgo::igemm, 0, true, {kFp32}, 3});
}

TEST(ConvTranspose2d, ReferenceKnownValues) {
  // One input pixel of value 1: output (oy, ox) of the 2x2 result is weight (oy+1, ox+1) + bias.
  HostTensor w({1, 1, 4, 4});
  for (int i = 0; i < 16; ++i) w.data[static_cast<size_t>(i)] = static_cast<float>(i);
  HostTensor x({1, 1, 1, 1}, 1.f), b({1, 1, 1, 1}, 100.f), y({1, 1, 2, 2});
  conv_transpose2d_ref(HostSlice(x), HostSliceOut(y), w, b, {});
  EXPECT_EQ(y.at(0, 0, 0, 0), 105.f);
  EXPECT_EQ(y.at(0, 0, 0, 1), 106.f);
  EXPECT_EQ(y.at(0, 0, 1, 0), 109.f);
  EXPECT_EQ(y.at(0, 0, 1, 1), 110.f);
  EXPECT_EQ(conv_transpose_output_size(130, 4, 2, 1), 260);
}
