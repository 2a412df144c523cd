// conv2d parity: every algorithm against the CPU reference on odd shapes, slices and activations.
#include <gtest/gtest.h>

#include <cstdio>

#include "kernel_test_util.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/conv_transpose2d.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::ktest;

namespace {
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

std::vector<Case> cases() {
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
std::vector<Case> canary_cases() {
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
  bool direct_texel_input = true;
  ConvOptions options;
};

// Every case against the reference; the output slice sits among canaries (kernel_test_util.hpp),
// which must survive: values outside the slice are never written.
void run_cases(Context& ctx, ConvAlgo algo, const std::vector<Case>& list, const Limits& lim = {}) {
  std::mt19937 rng(1234);
  int ran = 0;
  double worst = 0;
  const bool fp16 = lim.options.precision == Precision::fp16;
  for (const Case& c : list) {
    const Conv2dParams p{c.k, c.s, c.k / 2, c.act};
    const float wscale = 1.f / std::sqrt(static_cast<float>(c.cin * c.k * c.k));
    HostTensor w = random_tensor({c.cout, c.cin, c.k, c.k}, rng, -wscale, wscale);
    HostTensor b = random_tensor({1, 1, 1, c.cout}, rng, -0.5f, 0.5f);
    Conv2d conv(ctx, w, b, p, "conv2d", nullptr, lim.options);
    conv.set_winograd_scratch_limit(lim.winograd_scratch);
    conv.set_direct_chunk_limit(lim.direct_chunk);
    conv.set_direct_texel_input(lim.direct_texel_input);
    if (!conv.supports(algo)) continue;
    const int64_t oh = conv_output_size(c.h, c.k, c.s, c.k / 2), ow = conv_output_size(c.w, c.k, c.s, c.k / 2);
    const int64_t nb = std::max(c.batch, c.in_batch_total);
    HostTensor x = random_tensor({nb, c.cin + c.in_extra_c, c.h, c.w}, rng);
    const CanarySlice ys = canary_slice({c.batch, c.cout, oh, ow}, rng, c.out_c0 + 1, c.out_extra_c - c.out_c0 + 1);
    HostTensor r = random_tensor({nb, c.cout, oh, ow}, rng);
    HostTensor y_ref = ys.host;
    conv2d_ref(HostSlice(x, c.in_c0, c.cin, c.in_n0, c.batch), ys.of(y_ref), w, b, p,
               c.residual ? std::optional<HostSlice>(HostSlice(r, 0, -1, c.in_n0, c.batch)) : std::nullopt);
    const DType dt = precision_dtype(lim.options.precision);
    Tensor xd = to_device(ctx, x, dt), yd = to_device(ctx, ys.host, dt), rd = to_device(ctx, r, dt);
    CommandStream cs(ctx);
    conv.record(cs, Slice(xd, c.in_c0, c.cin, c.in_n0, c.batch), ys.of(yd),
                c.residual ? std::optional<Slice>(Slice(rd, 0, -1, c.in_n0, c.batch)) : std::nullopt, algo);
    cs.submit_and_wait();
    const HostTensor y = to_host(yd);
    const std::string what = std::string(conv_algo_name(algo)) + " k" + std::to_string(c.k) + " s" +
                             std::to_string(c.s) + " " + std::to_string(c.cin) + "->" + std::to_string(c.cout) + " " +
                             std::to_string(c.h) + "x" + std::to_string(c.w) + " batch " + std::to_string(c.batch) +
                             " act " + activation_name(c.act.kind);
    const double err = max_abs_diff(y, y_ref, ys);
    worst = std::max(worst, err);
    EXPECT_LE(err, fp16 ? kTolFp16 : kTol) << what << " " << precision_name(lim.options.precision);
    EXPECT_EQ(canary_damage(y, ys), "") << what;
    ++ran;
  }
  EXPECT_GT(ran, 0) << "no case applies to " << conv_algo_name(algo);
  std::printf("[ measured ] conv2d %s %s: max abs error %.3g over %d cases\n", conv_algo_name(algo),
              precision_name(lim.options.precision), worst, ran);
}
void run_cases(ConvAlgo algo, const Limits& lim = {}) { run_cases(vktest::context(), algo, cases(), lim); }
Limits fp16(Limits lim = {}) {
  lim.options.precision = Precision::fp16;
  return lim;
}
}  // namespace

TEST(Conv2d, NaiveMatchesReference) { run_cases(ConvAlgo::naive); }
TEST(Conv2d, BlockedMatchesReference) { run_cases(ConvAlgo::blocked); }
TEST(Conv2d, WinogradMatchesReference) { run_cases(ConvAlgo::winograd); }
// Scratch for 3 input channels' tiles only: several chunks accumulated by the GEMM.
TEST(Conv2d, WinogradInChunksMatchesReference) { run_cases(ConvAlgo::winograd, {3 * 36 * 4 * 64}); }
TEST(Conv2d, GemmMatchesReference) { run_cases(ConvAlgo::gemm); }
TEST(Conv2d, GemmInChunksMatchesReference) { run_cases(ConvAlgo::gemm, {2 * 4 * 80}); }
TEST(Conv2d, DirectMatchesReference) { run_cases(ConvAlgo::direct); }
// 2 input channels per dispatch: chunks accumulate in the output, the last applies act + residual.
TEST(Conv2d, DirectInChunksMatchesReference) { run_cases(ConvAlgo::direct, {~0ull, 2}); }
// Each chunk's weights are a uniform binding: on a device with a 256-byte offset alignment the
// chunks start at aligned channels (found on NVIDIA, whose 64 bytes refused 2-channel chunks).
TEST(Conv2d, DirectInChunksOnAStrictUniformAlignment) {
  run_cases(vktest::strict_uniform_context(), ConvAlgo::direct, cases(), {~0ull, 2});
}
// The input through a storage buffer instead of a texel buffer (the fallback for huge inputs).
TEST(Conv2d, DirectStorageInputMatchesReference) { run_cases(ConvAlgo::direct, {~0ull, 0, false}); }
TEST(Conv2d, AutomaticMatchesReference) { run_cases(ConvAlgo::automatic); }

// fp16: the same cases for every algorithm, against the same fp32 reference.
TEST(Conv2d, Fp16NaiveMatchesReference) { run_cases(ConvAlgo::naive, fp16()); }
TEST(Conv2d, Fp16BlockedMatchesReference) { run_cases(ConvAlgo::blocked, fp16()); }
TEST(Conv2d, Fp16WinogradMatchesReference) { run_cases(ConvAlgo::winograd, fp16()); }
TEST(Conv2d, Fp16GemmMatchesReference) { run_cases(ConvAlgo::gemm, fp16()); }
TEST(Conv2d, Fp16DirectMatchesReference) { run_cases(ConvAlgo::direct, fp16()); }
TEST(Conv2d, Fp16AutomaticMatchesReference) { run_cases(ConvAlgo::automatic, fp16()); }
// The chunked variants on the shorter list: Winograd and GEMM scratch for a few channels, direct's
// fp16 slabs (8 halves per uniform entry) in 2-channel chunks on a 256-byte uniform alignment, the
// storage-buffer input, and direct on the whole-binding context (its slab geometry is the one
// dispatch layout that differs between the precisions).
TEST(Conv2d, Fp16ChunkedVariantsMatchReference) {
  run_cases(vktest::context(), ConvAlgo::winograd, canary_cases(), fp16({3 * 36 * 4 * 64}));
  run_cases(vktest::context(), ConvAlgo::gemm, canary_cases(), fp16({2 * 4 * 80}));
  run_cases(vktest::strict_uniform_context(), ConvAlgo::direct, canary_cases(), fp16({~0ull, 2}));
  run_cases(vktest::context(), ConvAlgo::direct, canary_cases(), fp16({~0ull, 0, false}));
  run_cases(vktest::whole_binding_context(), ConvAlgo::direct, canary_cases(), fp16({~0ull, 2}));
}

// Every algorithm (and the chunked variants) on a context that binds whole tensors: a write
// outside the output slice lands on a canary inside the binding. The blocked path's dispatch sized
// by 8 output channels while its shader used 16 (fixed) wrote batch items past the slice here.
TEST(Conv2d, WritesNothingOutsideItsSlice) {
  Context& ctx = vktest::whole_binding_context();
  for (ConvAlgo a : {ConvAlgo::naive, ConvAlgo::blocked, ConvAlgo::winograd, ConvAlgo::gemm, ConvAlgo::direct,
                     ConvAlgo::automatic})
    run_cases(ctx, a, canary_cases());
  run_cases(ctx, ConvAlgo::winograd, canary_cases(), {3 * 36 * 4 * 64});
  run_cases(ctx, ConvAlgo::gemm, canary_cases(), {2 * 4 * 80});
  run_cases(ctx, ConvAlgo::direct, canary_cases(), {~0ull, 2});
  run_cases(ctx, ConvAlgo::direct, canary_cases(), {~0ull, 0, false});
}

// Non-default tuning knobs change the blocking, never the result.
TEST(Conv2d, OptionsChangeSpeedNotResults) {
  Context& ctx = vktest::context();
  const std::vector<Case> all = canary_cases(), few{all[0], all[2], all[3], all[5]};
  Limits lim;
  lim.options.blocked_cob = 4;
  lim.options.blocked_px = 5;
  run_cases(ctx, ConvAlgo::blocked, few, lim);
  lim.options = {};
  lim.options.direct_cob = 8;
  lim.options.direct_px = 3;
  lim.options.direct_py = 2;
  run_cases(ctx, ConvAlgo::direct, few, lim);
  lim.options = {};
  lim.options.gemm_cob = 4;
  lim.options.gemm_tv = 1;
  run_cases(ctx, ConvAlgo::winograd, few, lim);
  run_cases(ctx, ConvAlgo::gemm, few, lim);
}

TEST(Conv2d, OptionsAreValidatedByName) {
  Context& ctx = vktest::context();
  const HostTensor w({8, 4, 3, 3}), b;
  auto expect_error = [&](ConvOptions o, const std::string& field) {
    try {
      Conv2d conv(ctx, w, b, {3, 1, 1, {}}, "my_conv", nullptr, o);
      ADD_FAILURE() << field << ": no error";
    } catch (const Error& e) {
      const std::string m = e.what();
      EXPECT_NE(m.find("my_conv"), std::string::npos) << m;
      EXPECT_NE(m.find("ConvOptions::" + field), std::string::npos) << m;
    }
  };
  ConvOptions o;
  o.blocked_cob = 3;  // was VKUNROLL_BLOCKED_COB (0 there divided by zero)
  expect_error(o, "blocked_cob");
  o = {};
  o.blocked_px = 17;
  expect_error(o, "blocked_px");
  o = {};
  o.direct_cob = 6;
  expect_error(o, "direct_cob");
  o = {};
  o.direct_px = -1;
  expect_error(o, "direct_px");
  o = {};
  o.direct_py = 9;
  expect_error(o, "direct_py");
  o = {};
  o.gemm_cob = 12;
  expect_error(o, "gemm_cob");
  o = {};
  o.gemm_tv = 3;
  expect_error(o, "gemm_tv");
  EXPECT_NO_THROW(Conv2d(ctx, w, b, {3, 1, 1, {}}, "ok", nullptr, ConvOptions{}));  // 0 everywhere: defaults
  ConvOptions t;
  t.direct_cob = 5;
  EXPECT_THROW(ConvTranspose2d(ctx, HostTensor({4, 8, 4, 4}), b, {}, "deconv", t), Error);
}

TEST(Conv2d, AutomaticAvoidsChunkedDirectOnAnOverlappingResidual) {
  // A wide 1x1 conv picks `direct` even in several input-channel chunks, which accumulate in the
  // output; with the residual being the output itself (y = conv(x) + y) it must take another path.
  Context& ctx = vktest::context();
  std::mt19937 rng(77);
  const int64_t cin = 130, cout = 96;
  const Conv2dParams p{1, 1, 0, leaky_relu(0.1f)};
  const float wscale = 1.f / std::sqrt(static_cast<float>(cin));
  HostTensor w = random_tensor({cout, cin, 1, 1}, rng, -wscale, wscale), b = random_tensor({1, 1, 1, cout}, rng);
  Conv2d conv(ctx, w, b, p);
  conv.set_direct_chunk_limit(50);
  HostTensor x = random_tensor({1, cin, 4, 9}, rng), y = random_tensor({1, cout, 4, 9}, rng), y_ref = y;
  const HostTensor r = y;
  conv2d_ref(HostSlice(x), HostSliceOut(y_ref), w, b, p, HostSlice(r));
  Tensor xd = to_device(ctx, x), yd = to_device(ctx, y);
  CommandStream cs(ctx);
  EXPECT_THROW(conv.record(cs, Slice(xd), Slice(yd), Slice(yd), ConvAlgo::direct), Error);
  const size_t before = cs.recorded();
  conv.record(cs, Slice(xd), Slice(yd), Slice(yd));
  EXPECT_EQ(cs.recorded() - before, 3u);  // gemm: pack, GEMM, epilogue
  cs.submit_and_wait();
  EXPECT_LE(max_abs_diff(to_host(yd), y_ref), kTol);
  // Without the overlap the same conv runs `direct` in 3 chunks.
  Tensor y2(ctx, {1, cout, 4, 9}), rd = to_device(ctx, r);
  conv.record(cs, Slice(xd), Slice(y2), Slice(rd));
  EXPECT_EQ(cs.recorded(), 6u);  // direct: 2 blocks of 48 channels x 3 chunks of <= 50 inputs
  cs.submit_and_wait();
  EXPECT_LE(max_abs_diff(to_host(y2), y_ref), kTol);
}

TEST(Conv2d, ReferenceKnownValues) {
  // 1 input channel 3x3 of ones, 3x3 kernel of ones, pad 1: corner 4, edge 6, centre 9, + bias.
  HostTensor x({1, 1, 3, 3}, 1.f), w({1, 1, 3, 3}, 1.f), b({1, 1, 1, 1}, 0.5f), y({1, 1, 3, 3});
  conv2d_ref(HostSlice(x), HostSliceOut(y), w, b, {3, 1, 1, {}});
  EXPECT_EQ(y.at(0, 0, 0, 0), 4.5f);
  EXPECT_EQ(y.at(0, 0, 0, 1), 6.5f);
  EXPECT_EQ(y.at(0, 0, 1, 1), 9.5f);
  EXPECT_EQ(conv_output_size(260, 3, 2, 1), 130);
  EXPECT_EQ(conv_output_size(13, 3, 2, 1), 7);
}

TEST(Conv2d, ShapeErrorsNameTheProblem) {
  Context& ctx = vktest::context();
  Conv2d conv(ctx, HostTensor({4, 3, 3, 3}), HostTensor(), {3, 1, 1, {}}, "my_conv");
  Tensor x(ctx, {1, 5, 8, 8}), y(ctx, {1, 4, 8, 8}), y2(ctx, {1, 4, 7, 8});
  CommandStream cs(ctx);
  try {
    conv.record(cs, Slice(x), Slice(y));
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("my_conv"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("5 channels"), std::string::npos) << e.what();
  }
  EXPECT_NO_THROW(conv.record(cs, Slice(x, 1, 3), Slice(y)));
  EXPECT_THROW(conv.record(cs, Slice(x, 1, 3), Slice(y2)), Error);
  EXPECT_THROW(conv.record(cs, Slice(x, 3, 3), Slice(y)), Error);  // slice outside the tensor
  EXPECT_THROW(Conv2d(ctx, HostTensor({4, 3, 3, 3}), HostTensor({1, 1, 1, 3}), {3, 1, 1, {}}), Error);
  cs.submit_and_wait();
}
