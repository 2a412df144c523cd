// Precision as a setting: the host's fp16 conversions, the fp16 refusal on a device without 16-bit
// storage, and the overflow guards: fp16 never returns Inf or NaN where fp32 does not.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "kernel_test_util.hpp"
#include "vkunroll/kernels/backward_warp.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/conv_transpose2d.hpp"
#include "vkunroll/kernels/elementwise.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/base/half.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::ktest;

TEST(Precision, HalfConversionRoundsToNearestEven) {
  // Every half survives half -> float -> half.
  for (uint32_t h = 0; h < 65536; ++h) {
    const float f = half_to_float(static_cast<uint16_t>(h));
    if (std::isnan(f)) {
      ASSERT_TRUE(std::isnan(half_to_float(float_to_half(f))));
      continue;
    }
    ASSERT_EQ(float_to_half(f), h) << h;
  }
  EXPECT_EQ(round_to_half(1.f + 1.f / 2048), 1.f);                 // tie: to even
  EXPECT_EQ(round_to_half(1.f + 3.f / 2048), 1.f + 2.f / 1024);    // tie: to even (up)
  EXPECT_EQ(round_to_half(65519.f), 65504.f);
  EXPECT_TRUE(std::isinf(round_to_half(65520.f)));
  EXPECT_EQ(round_to_half(5.9604645e-8f), 5.9604645e-8f);          // smallest subnormal
  EXPECT_EQ(round_to_half(2.9802322e-8f), 0.f);                    // half of it: to even (0)
  EXPECT_EQ(parse_precision("fp16"), Precision::fp16);
  EXPECT_THROW(parse_precision("bf16"), Error);
}

TEST(Precision, Fp16TensorsRefuseValuesBeyondTheRange) {
  Context& ctx = vktest::context();
  HostTensor t({1, 1, 2, 2}, std::vector<float>{1.f, -65504.f, 7e4f, 0.f});
  try {
    to_device(ctx, t, DType::f16);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("index 2"), std::string::npos) << e.what();
  }
  HostTensor w({2, 1, 1, 1}, std::vector<float>{1.f, 1e5f});
  ConvOptions o;
  o.precision = Precision::fp16;
  try {
    Conv2d conv(ctx, w, HostTensor(), {1, 1, 0, {}}, "big_weights", nullptr, o);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("big_weights"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("fp16"), std::string::npos) << e.what();
  }
}

// A device without 16-bit storage: every fp16 kernel refuses by name; fp32 still runs.
TEST(Precision, Fp16IsRefusedOnADeviceWithoutSixteenBitStorage) {
  ContextOptions co;
  co.validation = true;
  co.validation_fatal = true;
  co.announce = false;
  co.without_fp16 = true;
  Context ctx(co);
  ASSERT_FALSE(ctx.info().storage_buffer_16bit);
  ConvOptions o;
  o.precision = Precision::fp16;
  auto message = [](auto f) -> std::string {
    try {
      f();
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  };
  const std::string m = message([&] { Conv2d(ctx, HostTensor({4, 3, 3, 3}), HostTensor(), {}, "head", nullptr, o); });
  EXPECT_NE(m.find("head"), std::string::npos) << m;
  EXPECT_NE(m.find("storageBuffer16BitAccess"), std::string::npos) << m;
  EXPECT_NE(message([&] { ConvTranspose2d(ctx, HostTensor({4, 3, 4, 4}), HostTensor(), {}, "up", o); }).find("up"),
            std::string::npos);
  Tensor a(ctx, {1, 2, 3, 3}, DType::f16), b(ctx, {1, 2, 3, 3}, DType::f16), f(ctx, {1, 2, 3, 3});
  CommandStream cs(ctx);
  EXPECT_NE(message([&] { add(cs, Slice(a), Slice(a), Slice(b)); }).find("storageBuffer16BitAccess"), std::string::npos);
  EXPECT_NE(message([&] { copy(cs, Slice(f), Slice(a)); }).find("storageBuffer16BitAccess"), std::string::npos);
  EXPECT_NO_THROW(Conv2d(ctx, HostTensor({4, 3, 3, 3}), HostTensor(), {}, "fp32_head"));
}

namespace {
// Counts of elements inside the slice where fp16 is not finite while fp32 is.
int64_t fp16_nonfinite_where_fp32_finite(const HostTensor& f32, const HostTensor& f16, const CanarySlice& cs) {
  int64_t bad = 0;
  for (int64_t n = cs.n0; n < cs.n0 + cs.n; ++n)
    for (int64_t c = cs.c0; c < cs.c0 + cs.c; ++c)
      for (int64_t y = 0; y < f32.shape.h; ++y)
        for (int64_t x = 0; x < f32.shape.w; ++x)
          bad += std::isfinite(f32.at(n, c, y, x)) && !std::isfinite(f16.at(n, c, y, x));
  return bad;
}

}  // namespace

// Inputs near fp16's limit into every conv algorithm: outputs beyond 65504 saturate (finite, right
// sign), never Inf or NaN. Inputs up to 5000 stay accurate, Winograd included (its transformed
// tiles stay fp32).
TEST(Precision, Fp16ConvsSaturateInsteadOfOverflowing) {
  Context& ctx = vktest::context();
  std::mt19937 rng(31);
  const int64_t cin = 16, cout = 8;
  for (int k : {1, 3}) {
    const Conv2dParams p{k, 1, k / 2, leaky_relu(0.1f)};
    const float ws = 1.f / std::sqrt(static_cast<float>(cin * k * k));
    HostTensor w = random_tensor({cout, cin, k, k}, rng, -ws, ws), b = random_tensor({1, 1, 1, cout}, rng);
    ConvOptions o16;
    o16.precision = Precision::fp16;
    Conv2d c32(ctx, w, b, p), c16(ctx, w, b, p, "fp16", nullptr, o16);
    for (float scale : {5000.f, 60000.f}) {
      HostTensor x = random_tensor({2, cin, 13, 17}, rng, -scale, scale);
      for (ConvAlgo a : {ConvAlgo::naive, ConvAlgo::blocked, ConvAlgo::winograd, ConvAlgo::gemm, ConvAlgo::direct}) {
        if (!c16.supports(a)) continue;
        const CanarySlice ys = canary_slice({2, cout, 13, 17}, rng);
        Tensor x32 = to_device(ctx, x), x16 = to_device(ctx, x, DType::f16);
        Tensor y32 = to_device(ctx, ys.host), y16 = to_device(ctx, ys.host, DType::f16);
        CommandStream cs(ctx);
        c32.record(cs, Slice(x32), ys.of(y32), std::nullopt, a);
        c16.record(cs, Slice(x16), ys.of(y16), std::nullopt, a);
        cs.submit_and_wait();
        const HostTensor r32 = to_host(y32), r16 = to_host(y16);
        const std::string what = std::string(conv_algo_name(a)) + " k" + std::to_string(k) + " inputs +-" +
                                 std::to_string(static_cast<int>(scale));
        EXPECT_EQ(fp16_nonfinite_where_fp32_finite(r32, r16, ys), 0) << what;
        EXPECT_EQ(canary_damage(r16, ys), "") << what;
        int64_t wrong_sign = 0;
        for (int64_t i = 0; i < static_cast<int64_t>(r32.data.size()); ++i)
          wrong_sign += std::fabs(r32.data[i]) > 2 * kHalfMax && std::fabs(r16.data[i]) != kHalfMax;
        EXPECT_EQ(wrong_sign, 0) << what << ": beyond the range, fp16 saturates at 65504";
        if (scale <= 5000.f) {
          const double rel = max_range_rel_diff(r16, r32, ys, kHalfMax);
          std::printf("[ measured ] %s: fp16 error / output range %.3g\n", what.c_str(), rel);
          EXPECT_LE(rel, 1e-2) << what;
        }
      }
    }
  }
}

// The flow head's 100 * tanh, sigmoid and the elementwise ops on values at fp16's limit, and the
// warp with huge flows: finite wherever fp32 is.
TEST(Precision, Fp16ScaleTanhElementwiseAndWarpStayFinite) {
  Context& ctx = vktest::context();
  std::mt19937 rng(37);
  HostTensor a = random_tensor({1, 4, 9, 11}, rng, -65504.f, 65504.f), b = random_tensor({1, 4, 9, 11}, rng, -65504.f, 65504.f);
  a.at(0, 0, 0, 0) = 65504.f, b.at(0, 0, 0, 0) = 65504.f;  // their sum: 131008 in fp32
  struct Run {
    CanarySlice cs;
    Tensor d32, d16;
  };
  std::vector<Run> runs;
  runs.reserve(8);
  CommandStream cs(ctx);
  Tensor a32 = to_device(ctx, a), b32 = to_device(ctx, b), a16 = to_device(ctx, a, DType::f16),
         b16 = to_device(ctx, b, DType::f16);
  auto out = [&]() -> Run& {
    CanarySlice c = canary_slice(a.shape, rng);
    Tensor t32 = to_device(ctx, c.host), t16 = to_device(ctx, c.host, DType::f16);
    runs.push_back({std::move(c), std::move(t32), std::move(t16)});
    return runs.back();
  };
  {
    Run& r = out();
    tanh_scale(cs, Slice(a32), r.cs.of(r.d32), 100.f);
    tanh_scale(cs, Slice(a16), r.cs.of(r.d16), 100.f);
  }
  {
    Run& r = out();
    scale_act(cs, Slice(a32), r.cs.of(r.d32), {Activation::sigmoid, 0.f}, 1.f);
    scale_act(cs, Slice(a16), r.cs.of(r.d16), {Activation::sigmoid, 0.f}, 1.f);
  }
  {
    Run& r = out();
    add(cs, Slice(a32), Slice(b32), r.cs.of(r.d32));
    add(cs, Slice(a16), Slice(b16), r.cs.of(r.d16));
  }
  {
    Run& r = out();
    scale_act(cs, Slice(a32), r.cs.of(r.d32), leaky_relu(0.1f), 100.f);  // 100 x 65504: beyond fp16
    scale_act(cs, Slice(a16), r.cs.of(r.d16), leaky_relu(0.1f), 100.f);
  }
  {  // backward_warp with flows of +-60000 px (clamped to the border) on an image at the limit
    Run& r = out();
    backward_warp(cs, Slice(a32), Slice(b32, 0, 2), r.cs.of(r.d32));
    backward_warp(cs, Slice(a16), Slice(b16, 0, 2), r.cs.of(r.d16));
  }
  cs.submit_and_wait();
  for (size_t i = 0; i < runs.size(); ++i) {
    const HostTensor r32 = to_host(runs[i].d32), r16 = to_host(runs[i].d16);
    EXPECT_EQ(fp16_nonfinite_where_fp32_finite(r32, r16, runs[i].cs), 0) << "op " << i;
    EXPECT_EQ(canary_damage(r16, runs[i].cs), "") << "op " << i;
    EXPECT_LE(max_range_rel_diff(r16, r32, runs[i].cs, kHalfMax), 2e-3) << "op " << i;
  }
  // The flow scale: |100 tanh| <= 100 in both.
  const HostTensor flow16 = to_host(runs[0].d16);
  for (int64_t c = 0; c < 4; ++c)
    for (int64_t y = 0; y < 9; ++y)
      for (int64_t x = 0; x < 11; ++x) EXPECT_LE(std::fabs(flow16.at(runs[0].cs.n0, runs[0].cs.c0 + c, y, x)), 100.f);
}

// conv_transpose2d with inputs near the limit: saturates, never Inf.
TEST(Precision, Fp16TransposedConvSaturatesInsteadOfOverflowing) {
  Context& ctx = vktest::context();
  std::mt19937 rng(41);
  HostTensor w = random_tensor({8, 8, 4, 4}, rng, -1.f, 1.f), b = random_tensor({1, 1, 1, 8}, rng);
  ConvOptions o16;
  o16.precision = Precision::fp16;
  ConvTranspose2d d32(ctx, w, b, {}), d16(ctx, w, b, {}, "fp16", o16);
  HostTensor x = random_tensor({1, 8, 6, 7}, rng, -60000.f, 60000.f);
  Tensor x32 = to_device(ctx, x), x16 = to_device(ctx, x, DType::f16);
  for (ConvTransposeAlgo a : {ConvTransposeAlgo::naive, ConvTransposeAlgo::blocked, ConvTransposeAlgo::direct}) {
    const CanarySlice ys = canary_slice({1, 8, 12, 14}, rng);
    Tensor y32 = to_device(ctx, ys.host), y16 = to_device(ctx, ys.host, DType::f16);
    CommandStream cs(ctx);
    d32.record(cs, Slice(x32), ys.of(y32), a);
    d16.record(cs, Slice(x16), ys.of(y16), a);
    cs.submit_and_wait();
    const HostTensor r32 = to_host(y32), r16 = to_host(y16);
    EXPECT_EQ(fp16_nonfinite_where_fp32_finite(r32, r16, ys), 0) << conv_transpose_algo_name(a);
    EXPECT_EQ(canary_damage(r16, ys), "") << conv_transpose_algo_name(a);
  }
}
