// conv2d parity: every algorithm against the CPU reference on odd shapes, slices and activations.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <optional>

#include "conv_test_cases.hpp"
#include "kernel_test_util.hpp"
#include "op_test_harness.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/conv_transpose2d.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::ktest;

namespace {
using namespace vkunroll::convtest;
// One Winograd form (ConvOptions::winograd_tile) on `list`: whole in fp32 and fp16, in input-channel
// chunks and through storage buffers in fp32.
void run_winograd_form(const std::vector<Case>& list, int tile) {
  Limits whole, chunks{6 * 64 * 4 * 64}, storage{~0ull, 0, false};
  for (Limits* l : {&whole, &chunks, &storage}) l->options.winograd_tile = tile;
  run_cases(vktest::context(), ConvAlgo::winograd, list, whole, {kFp32, kFp16});
  run_cases(vktest::context(), ConvAlgo::winograd, list, chunks, {kFp32});
  run_cases(vktest::context(), ConvAlgo::winograd, list, storage, {kFp32});
}
}  // namespace

// Every algorithm in both precisions; fp16 against the same fp32 reference.
TEST(Conv2d, NaiveMatchesReference) { run_cases(ConvAlgo::naive); }
TEST(Conv2d, BlockedMatchesReference) { run_cases(ConvAlgo::blocked); }
TEST(Conv2d, WinogradMatchesReference) { run_cases(ConvAlgo::winograd); }
TEST(Conv2d, GemmMatchesReference) { run_cases(ConvAlgo::gemm); }
TEST(Conv2d, DirectMatchesReference) { run_cases(ConvAlgo::direct); }
TEST(Conv2d, PointwiseMatchesReference) { run_cases(ConvAlgo::pointwise); }
TEST(Conv2d, AutomaticMatchesReference) { run_cases(ConvAlgo::automatic); }
// The chunked variants: fp32 on every case, fp16 on the shorter list.
// Scratch for 3 input channels' tiles only: several chunks accumulated by the GEMM.
TEST(Conv2d, WinogradInChunksMatchesReference) {
  run_cases(ConvAlgo::winograd, {3 * 36 * 4 * 64}, {kFp32});
  run_cases(vktest::context(), ConvAlgo::winograd, canary_cases(), {3 * 36 * 4 * 64}, {kFp16});
}
TEST(Conv2d, GemmInChunksMatchesReference) {
  run_cases(ConvAlgo::gemm, {2 * 4 * 80}, {kFp32});
  run_cases(vktest::context(), ConvAlgo::gemm, canary_cases(), {2 * 4 * 80}, {kFp16});
}
// 2 input channels per dispatch: chunks accumulate in the output, the last applies act + residual.
TEST(Conv2d, DirectInChunksMatchesReference) { run_cases(ConvAlgo::direct, {~0ull, 2}, {kFp32}); }
// Each chunk's weights are a uniform binding: on a device with a 256-byte offset alignment the
// chunks start at aligned channels (found on NVIDIA, whose 64 bytes refused 2-channel chunks); fp16:
// direct's slabs of 8 halves per uniform entry.
TEST(Conv2d, DirectInChunksOnAStrictUniformAlignment) {
  run_cases(vktest::strict_uniform_context(), ConvAlgo::direct, cases(), {~0ull, 2}, {kFp32});
  run_cases(vktest::strict_uniform_context(), ConvAlgo::direct, canary_cases(), {~0ull, 2}, {kFp16});
}
// The input through a storage buffer instead of a texel buffer (the fallback for huge inputs).
TEST(Conv2d, DirectStorageInputMatchesReference) {
  run_cases(ConvAlgo::direct, {~0ull, 0, false}, {kFp32});
  run_cases(vktest::context(), ConvAlgo::direct, canary_cases(), {~0ull, 0, false}, {kFp16});
}
// Winograd's input, V, U and M through storage buffers instead of texel buffers (the fallback for
// ranges beyond maxTexelBufferElements), whole and in chunks.
TEST(Conv2d, WinogradStorageFormsMatchReference) {
  run_cases(ConvAlgo::winograd, {~0ull, 0, false}, {kFp32});
  run_cases(vktest::context(), ConvAlgo::winograd, canary_cases(), {3 * 36 * 4 * 64, 0, false}, {kFp32, kFp16});
}
// 5x5 stride 1 in both Winograd forms: F(4x4, 5x5) on 8x8 tiles (the default) and the kernel split
// into four F(4x4, 3x3) convs (winograd_tile 6), with a long reduction (SFENet1-like 120 -> 24),
// texel and storage forms, whole and in chunks.
TEST(Conv2d, Winograd5x5BothFormsMatchReference) {
  const Act lrelu01 = leaky_relu(0.1f);
  const std::vector<Case> k5 = {{5, 1, 3, 9, 1, 13, Act{Activation::tanh}, false},
                                {5, 1, 11, 6, 12, 9, Act{}, false, 0, 0, 3, 1, 2},
                                {5, 1, 120, 24, 21, 30, lrelu01, true, 0, 0, 0, 0, 2},
                                {5, 1, 7, 16, 33, 18, lrelu01, false, 2, 1}};
  for (int tile : {8, 6}) run_winograd_form(k5, tile);
}
// 3x3 stride 1 as F(6x6, 3x3) on 8x8 tiles (winograd_tile 8): every 3x3 stride-1 case, in both
// precisions, in chunks and through storage buffers; stride 2 keeps F(4x4, 3x3) (its phases).
TEST(Conv2d, Winograd6x6MatchesReference) {
  std::vector<Case> k3;
  for (const Case& c : cases())
    if (c.k == 3) k3.push_back(c);
  k3.push_back({3, 1, 144, 48, 26, 37, leaky_relu(0.1f), true, 0, 0, 0, 0, 2});  // an RDB conv's reduction
  run_winograd_form(k3, 8);
}
// The 1x1 GEMM's input, V and U through storage buffers (its plain pack and GEMM) instead of texel
// buffers.
TEST(Conv2d, GemmStorageFormsMatchReference) {
  run_cases(ConvAlgo::gemm, {~0ull, 0, false}, {kFp32});
  run_cases(vktest::context(), ConvAlgo::gemm, canary_cases(), {2 * 4 * 80, 0, false}, {kFp32, kFp16});
}
// pointwise: the 130- and 129-channel cases run in two unrolled chunks (at most 128 each) that
// accumulate in the output; here they start at 256-byte aligned slabs, and the input comes through
// a storage buffer.
TEST(Conv2d, PointwiseOnAStrictUniformAlignment) {
  run_cases(vktest::strict_uniform_context(), ConvAlgo::pointwise, cases(), {}, {kFp32});
  run_cases(vktest::strict_uniform_context(), ConvAlgo::pointwise, canary_cases(), {}, {kFp16});
}
// 4 input channels per dispatch (1-33 chunks; 13 -> 9 and 13 -> 32 end on a 1-channel chunk): the
// raw sums accumulate in the output, the last chunk applies activation and residual.
TEST(Conv2d, PointwiseInChunksMatchesReference) {
  run_cases(ConvAlgo::pointwise, pointwise_chunks_of(4), {kFp32, kFp16});
  Limits strict = pointwise_chunks_of(20);  // 16-channel chunks on 256-byte aligned slabs
  run_cases(vktest::strict_uniform_context(), ConvAlgo::pointwise, cases(), strict, {kFp32, kFp16});
}
TEST(Conv2d, PointwiseStorageInputMatchesReference) {
  run_cases(ConvAlgo::pointwise, {~0ull, 0, false}, {kFp32});
  run_cases(vktest::context(), ConvAlgo::pointwise, canary_cases(), {~0ull, 0, false}, {kFp16});
}

// Every algorithm (and the chunked variants) on a context that binds whole tensors: a write
// outside the output slice lands on a canary inside the binding. The blocked path's dispatch sized
// by 8 output channels while its shader used 16 (fixed) wrote batch items past the slice here.
// Direct in chunks in fp16 too: its slab geometry is the one dispatch layout that differs between
// the precisions.
TEST(Conv2d, WritesNothingOutsideItsSlice) {
  Context& ctx = vktest::whole_binding_context();
  for (ConvAlgo a : {ConvAlgo::naive, ConvAlgo::blocked, ConvAlgo::winograd, ConvAlgo::gemm, ConvAlgo::direct,
                     ConvAlgo::pointwise, ConvAlgo::automatic})
    run_cases(ctx, a, canary_cases(), {}, {kFp32});
  run_cases(ctx, ConvAlgo::pointwise, canary_cases(), {}, {kFp16});
  run_cases(ctx, ConvAlgo::pointwise, canary_cases(), pointwise_chunks_of(5), {kFp32, kFp16});
  run_cases(ctx, ConvAlgo::winograd, canary_cases(), {3 * 36 * 4 * 64}, {kFp32});
  run_cases(ctx, ConvAlgo::winograd, canary_cases(), {~0ull, 0, false}, {kFp32});
  run_cases(ctx, ConvAlgo::gemm, canary_cases(), {2 * 4 * 80}, {kFp32});
  run_cases(ctx, ConvAlgo::gemm, canary_cases(), {~0ull, 0, false}, {kFp32});
  run_cases(ctx, ConvAlgo::direct, canary_cases(), {~0ull, 2});
  run_cases(ctx, ConvAlgo::direct, canary_cases(), {~0ull, 0, false}, {kFp32});
}

// Non-default tuning knobs change the blocking, never the result.
TEST(Conv2d, OptionsChangeSpeedNotResults) {
  Context& ctx = vktest::context();
  const std::vector<Case> all = canary_cases(), few{all[0], all[2], all[3], all[5]};
  Limits lim;
  lim.options.blocked_cob = 4;
  lim.options.blocked_px = 5;
  run_cases(ctx, ConvAlgo::blocked, few, lim, {kFp32});
  lim.options = {};
  lim.options.direct_cob = 8;
  lim.options.direct_px = 3;
  lim.options.direct_py = 2;
  run_cases(ctx, ConvAlgo::direct, few, lim, {kFp32});
  lim.options = {};
  lim.options.gemm_cob = 4;
  lim.options.gemm_tv = 1;
  run_cases(ctx, ConvAlgo::winograd, few, lim, {kFp32});
  run_cases(ctx, ConvAlgo::gemm, few, lim, {kFp32});
  lim.options = {};
  lim.options.pointwise_cob = 5;  // partial last blocks (cout 16, 32, 96); 3 pixels per invocation
  lim.options.pointwise_px = 3;
  run_cases(ctx, ConvAlgo::pointwise, all, lim, {kFp32, kFp16});
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
  o = {};
  o.winograd_tile = 7;
  expect_error(o, "winograd_tile");
  o = {};
  o.pointwise_cob = 33;
  expect_error(o, "pointwise_cob");
  o = {};
  o.pointwise_px = 9;
  expect_error(o, "pointwise_px");
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

// A dense block's convs with Winograd's transformed input shared (WinogradInputCache): conv c reads
// the first 8 + 8c channels of X and writes the next 8 into X, so each transforms only its new
// channels (a conv re-reading the same prefix transforms nothing: 2 dispatches, not 3); begin()
// after the input changed starts over. Both precisions, batch 2, odd sizes.
TEST(Conv2d, WinogradSharesTheInputTransformAcrossADenseBlock) {
  Context& ctx = vktest::context();
  for (Precision prec : {kFp32, kFp16}) {
    std::mt19937 rng(91);
    const Conv2dParams p{3, 1, 1, leaky_relu(0.01f)};
    const int64_t cins[4] = {8, 16, 24, 24}, couts[4] = {8, 8, 5, 7};
    auto ws = std::make_shared<ConvWorkspace>();
    ConvOptions opt;
    opt.precision = prec;
    std::vector<std::unique_ptr<Conv2d>> convs;
    std::vector<HostTensor> wts, bs;
    for (int c = 0; c < 4; ++c) {
      const float sc = 1.f / std::sqrt(static_cast<float>(9 * cins[c]));
      wts.push_back(random_tensor({couts[c], cins[c], 3, 3}, rng, -sc, sc));
      bs.push_back(random_tensor({1, 1, 1, couts[c]}, rng, -0.5f, 0.5f));
      convs.push_back(std::make_unique<Conv2d>(ctx, wts[c], bs[c], p, "dense" + std::to_string(c), ws, opt));
    }
    const DType dt = prec == kFp16 ? DType::f16 : DType::f32;
    const double tol = prec == kFp16 ? kTolFp16 : kTol;
    Tensor xd(ctx, {2, 24, 13, 19}, dt);  // both rounds: new values in the same buffer
    for (int round = 0; round < 2; ++round) {
      HostTensor x = random_tensor({2, 24, 13, 19}, rng), x_ref = x;
      std::vector<HostTensor> y_ref{HostTensor({2, 5, 13, 19}), HostTensor({2, 7, 13, 19})};
      for (int c = 0; c < 4; ++c) {
        HostSliceOut o = c < 2 ? HostSliceOut(x_ref, 8 + 8 * c, 8) : HostSliceOut(y_ref[size_t(c - 2)]);
        conv2d_ref(HostSlice(x_ref, 0, cins[c]), o, wts[size_t(c)], bs[size_t(c)], p, std::nullopt);
      }
      upload(x, xd);
      Tensor y2(ctx, {2, 5, 13, 19}, dt), y3(ctx, {2, 7, 13, 19}, dt);
      WinogradInputCache cache;
      CommandStream cs(ctx);
      cache.begin(24);
      const size_t want[4] = {3, 3, 3, 2};
      for (int c = 0; c < 4; ++c) {
        const size_t before = cs.recorded();
        const Slice out = c == 0 ? Slice(xd, 8, 8) : c == 1 ? Slice(xd, 16, 8) : c == 2 ? Slice(y2) : Slice(y3);
        convs[size_t(c)]->record(cs, Slice(xd, 0, cins[c]), out, std::nullopt, ConvAlgo::winograd, &cache);
        EXPECT_EQ(cs.recorded() - before, want[c]) << "conv " << c << " " << precision_name(prec);
      }
      // Another input inside the block (misuse): its key differs, so all of it is transformed again.
      HostTensor z = random_tensor({2, 16, 13, 19}, rng), z_out({2, 8, 13, 19});
      conv2d_ref(HostSlice(z), HostSliceOut(z_out), wts[1], bs[1], p, std::nullopt);
      Tensor zd = to_device(ctx, z, dt), zo(ctx, {2, 8, 13, 19}, dt);
      convs[1]->record(cs, Slice(zd), Slice(zo), std::nullopt, ConvAlgo::winograd, &cache);
      cache.end();
      cs.submit_and_wait();
      EXPECT_LE(max_abs_diff(to_host(zo), z_out), tol) << precision_name(prec) << " round " << round;
      EXPECT_LE(max_abs_diff(to_host(xd), x_ref), tol) << precision_name(prec) << " round " << round;
      EXPECT_LE(max_abs_diff(to_host(y2), y_ref[0]), tol) << precision_name(prec) << " round " << round;
      EXPECT_LE(max_abs_diff(to_host(y3), y_ref[1]), tol) << precision_name(prec) << " round " << round;
    }
  }
}

// A batch whose transformed input needs channel chunks while one item's does not runs item group
// by item group, each with all its channels in one GEMM (3 dispatches per group): batch items at an
// offset inside a larger batch, input and output channel slices and a residual; both 8x8-tile and
// 6x6-tile forms, fp32 and fp16. Against the reference, and against the chunked run's dispatch count.
TEST(Conv2d, WinogradRunsABatchByItemGroupsWhenOneGroupFitsTheScratch) {
  Context& ctx = vktest::context();
  for (Precision prec : {kFp32, kFp16})
    for (int k : {3, 5}) {
      std::mt19937 rng(7 + k);
      const int64_t cin = 17, cout = 19, h = 16, w = 12, nb = 3, n_total = 5, n0 = 1;
      const Conv2dParams p{k, 1, k / 2, leaky_relu(0.1f)};
      const float sc = 1.f / std::sqrt(static_cast<float>(cin * k * k));
      const HostTensor wt = random_tensor({cout, cin, k, k}, rng, -sc, sc), b = random_tensor({1, 1, 1, cout}, rng, -0.5f, 0.5f);
      const HostTensor x = random_tensor({n_total, cin + 3, h, w}, rng), res = random_tensor({n_total, cout, h, w}, rng);
      HostTensor y_ref({nb, cout + 2, h, w});
      conv2d_ref(HostSlice(x, 2, cin, n0, nb), HostSliceOut(y_ref, 1, cout), wt, b, p, HostSlice(res, 0, -1, n0, nb));
      const DType dt = prec == kFp16 ? DType::f16 : DType::f32;
      const Tensor xd = to_device(ctx, x, dt), rd = to_device(ctx, res, dt);
      // One item's 4x4 tiles: 16 per item (tiles_pad), 3 items: 48. The scratch holds every channel
      // of one item's V (and of a group of two), not of three.
      const int64_t npos = k == 5 ? 64 : 36;
      ConvOptions o;
      o.precision = prec;
      Conv2d conv(ctx, wt, b, p, "batch", nullptr, o);
      conv.set_winograd_scratch_limit(static_cast<uint64_t>(npos * 32 * 4 * cin));
      size_t dispatches[2] = {0, 0};
      for (int run = 0; run < 2; ++run) {
        if (run == 1) conv.set_winograd_scratch_limit(static_cast<uint64_t>(npos * 16 * 4 * 6));  // chunks even for one item
        Tensor yd = to_device(ctx, HostTensor({nb, cout + 2, h, w}, 0.f), dt);
        CommandStream cs(ctx);
        conv.record(cs, Slice(xd, 2, cin, n0, nb), Slice(yd, 1, cout), Slice(rd, 0, -1, n0, nb), ConvAlgo::winograd);
        dispatches[run] = cs.recorded();
        cs.submit_and_wait();
        HostTensor y = to_host(yd);
        for (int64_t i = 0; i < nb; ++i)
          for (int64_t c : {int64_t(0), cout + 1})  // the channels around the slice stay 0
            for (int64_t q = 0; q < h * w; ++q) ASSERT_EQ(y.data[size_t(((i * (cout + 2)) + c) * h * w + q)], 0.f);
        EXPECT_LE(max_abs_diff(y, y_ref), prec == kFp16 ? kTolFp16 : kTol) << "k " << k << " run " << run << " " << precision_name(prec);
      }
      EXPECT_EQ(dispatches[0], 2u * 3u) << "k " << k << ": groups of two items, then one, each in one GEMM";
      EXPECT_GT(dispatches[1], dispatches[0]) << "k " << k << ": channel chunks";
    }
}

// A batch whose Winograd M (all items, all output channels) exceeds one binding still runs Winograd,
// item group by item group: the published SFENet1's 96 output channels at 240x320 take 118 MB of M
// per item as F(4x4, 5x5), so M mode's two items exceed lavapipe's 128 MiB (before, Winograd was
// refused and the conv fell back to blocked).
TEST(Conv2d, WinogradSplitsABatchWhoseMDoesNotFitOneBinding) {
  Context& ctx = vktest::context();
  std::mt19937 rng(5);
  const int64_t cin = 2, cout = 96, h = 240, w = 320, n = 2;
  const Conv2dParams p{5, 1, 2, leaky_relu(0.1f)};
  const HostTensor wt = random_tensor({cout, cin, 5, 5}, rng, -0.2f, 0.2f), b = random_tensor({1, 1, 1, cout}, rng, -0.5f, 0.5f);
  const HostTensor x = random_tensor({n, cin, h, w}, rng);
  HostTensor y_ref({n, cout, h, w});
  conv2d_ref(HostSlice(x), HostSliceOut(y_ref), wt, b, p, std::nullopt);
  Conv2d conv(ctx, wt, b, p, "sfenet1", nullptr, ConvOptions{});
  ASSERT_TRUE(conv.supports(ConvAlgo::winograd, x.shape));
  const uint64_t m_item = 64ull * 96 * 4800 * 4;  // positions x cout x tiles (80 x 60) x fp32
  const bool split = n * m_item > ctx.info().max_storage_buffer_range;
  const Tensor xd = to_device(ctx, x);
  Tensor yd(ctx, {n, cout, h, w});
  CommandStream cs(ctx);
  conv.record(cs, Slice(xd), Slice(yd), std::nullopt, ConvAlgo::winograd);
  EXPECT_EQ(cs.recorded(), split ? 6u : 3u) << "one group per item where M of both does not fit";
  cs.submit_and_wait();
  EXPECT_LE(max_abs_diff(to_host(yd), y_ref), kTol);
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
