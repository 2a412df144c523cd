// conv_transpose2d parity: every algorithm against the CPU reference (PyTorch weight layout).
#include <gtest/gtest.h>

#include <cstdio>

#include "kernel_test_util.hpp"
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
};

void run_cases(Context& ctx, ConvTransposeAlgo algo, int64_t direct_chunk_limit = 0, bool direct_texel_input = true,
               Precision prec = Precision::fp32) {
  std::mt19937 rng(99);
  double worst = 0;
  ConvOptions opt;
  opt.precision = prec;
  const std::vector<Case> cases{
      {5, 7, 9, 11, leaky_relu(0.1f), 3, 2, 4, 4, 2},
      {16, 8, 1, 1, Act{}},
      {3, 9, 1, 13, Act{Activation::tanh}},
      {12, 6, 7, 1, Act{Activation::sigmoid}, 0, 0, 6, 0},
      {9, 13, 6, 5, Act{Activation::hardsigmoid}},
      {32, 16, 11, 9, leaky_relu(0.01f), 0, 0, 16, 16, 2},
      {33, 64, 5, 3, leaky_relu(0.2f), 2, 1, 0, 0, 1},  // direct's 32-channel blocks
  };
  int ran = 0;
  for (const Case& c : cases) {
    const ConvTranspose2dParams p{4, 2, 1, c.act};
    const float ws = 1.f / std::sqrt(static_cast<float>(c.cin * 4));
    HostTensor w = random_tensor({c.cin, c.cout, 4, 4}, rng, -ws, ws);
    HostTensor b = random_tensor({1, 1, 1, c.cout}, rng, -0.5f, 0.5f);
    ConvTranspose2d deconv(ctx, w, b, p, "conv_transpose2d", opt);
    deconv.set_direct_chunk_limit(direct_chunk_limit);
    deconv.set_direct_texel_input(direct_texel_input);
    if (!deconv.supports(algo)) continue;
    HostTensor x = random_tensor({c.batch, c.cin + c.in_extra_c, c.h, c.w}, rng);
    // The output slice among canaries that must survive (kernel_test_util.hpp).
    const CanarySlice ys =
        canary_slice({c.batch, c.cout, 2 * c.h, 2 * c.w}, rng, c.out_c0 + 1, c.out_extra_c - c.out_c0 + 1);
    HostTensor y_ref = ys.host;
    conv_transpose2d_ref(HostSlice(x, c.in_c0, c.cin), ys.of(y_ref), w, b, p);
    Tensor xd = to_device(ctx, x, precision_dtype(prec)), yd = to_device(ctx, ys.host, precision_dtype(prec));
    CommandStream cs(ctx);
    deconv.record(cs, Slice(xd, c.in_c0, c.cin), ys.of(yd), algo);
    cs.submit_and_wait();
    const HostTensor y = to_host(yd);
    const std::string what = std::string(conv_transpose_algo_name(algo)) + " " + std::to_string(c.cin) + "->" +
                             std::to_string(c.cout) + " " + std::to_string(c.h) + "x" + std::to_string(c.w);
    const double err = max_abs_diff(y, y_ref, ys);
    worst = std::max(worst, err);
    EXPECT_LE(err, prec == Precision::fp16 ? kTolFp16 : kTol) << what << " " << precision_name(prec);
    EXPECT_EQ(canary_damage(y, ys), "") << what;
    ++ran;
  }
  EXPECT_GT(ran, 0);
  std::printf("[ measured ] conv_transpose2d %s %s: max abs error %.3g over %d cases\n",
              conv_transpose_algo_name(algo), precision_name(prec), worst, ran);
}
void run_cases(ConvTransposeAlgo algo, int64_t direct_chunk_limit = 0, bool direct_texel_input = true) {
  run_cases(vktest::context(), algo, direct_chunk_limit, direct_texel_input);
}
}  // namespace

TEST(ConvTranspose2d, NaiveMatchesReference) { run_cases(ConvTransposeAlgo::naive); }
TEST(ConvTranspose2d, BlockedMatchesReference) { run_cases(ConvTransposeAlgo::blocked); }
TEST(ConvTranspose2d, DirectMatchesReference) { run_cases(ConvTransposeAlgo::direct); }
// 3 input channels per dispatch: chunks accumulate in the output, the last applies the activation.
TEST(ConvTranspose2d, DirectInChunksMatchesReference) { run_cases(ConvTransposeAlgo::direct, 3); }
// Chunk starts on a 256-byte uniform offset alignment (see Conv2d.DirectInChunksOnAStrictUniformAlignment).
TEST(ConvTranspose2d, DirectInChunksOnAStrictUniformAlignment) {
  run_cases(vktest::strict_uniform_context(), ConvTransposeAlgo::direct, 3);
}
// The input through a storage buffer instead of a texel buffer (the fallback for huge inputs).
TEST(ConvTranspose2d, DirectStorageInputMatchesReference) { run_cases(ConvTransposeAlgo::direct, 0, false); }
TEST(ConvTranspose2d, AutomaticMatchesReference) { run_cases(ConvTransposeAlgo::automatic); }

// fp16: the same cases for every algorithm (direct also in chunks on a 256-byte uniform alignment,
// and with the storage-buffer input), against the same fp32 reference.
TEST(ConvTranspose2d, Fp16MatchesReference) {
  Context& ctx = vktest::context();
  for (ConvTransposeAlgo a : {ConvTransposeAlgo::naive, ConvTransposeAlgo::blocked, ConvTransposeAlgo::direct})
    run_cases(ctx, a, 0, true, Precision::fp16);
  run_cases(vktest::strict_uniform_context(), ConvTransposeAlgo::direct, 3, true, Precision::fp16);
  run_cases(ctx, ConvTransposeAlgo::direct, 0, false, Precision::fp16);
}

// Every algorithm on a context that binds whole tensors: a write outside the output slice lands on
// a canary inside the binding (lavapipe drops writes past a binding).
TEST(ConvTranspose2d, WritesNothingOutsideItsSlice) {
  Context& ctx = vktest::whole_binding_context();
  for (ConvTransposeAlgo a : {ConvTransposeAlgo::naive, ConvTransposeAlgo::blocked, ConvTransposeAlgo::direct})
    run_cases(ctx, a);
  run_cases(ctx, ConvTransposeAlgo::direct, 3);
  run_cases(ctx, ConvTransposeAlgo::direct, 0, false);
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
