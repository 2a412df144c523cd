// Elementwise ops on slices: add, scale*act, blend across batch items, clamp, copy.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "kernel_test_util.hpp"
#include "vkunroll/kernels/elementwise.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::ktest;

namespace {
constexpr double kTol = 1e-6;  // one or two fp32 roundings of values of order 1 (tanh/exp: 1e-6)
// fp16 (inputs and outputs stored as half, fp32 arithmetic) against the fp32 reference, relative
// to the output's range: docs/kernels.md, "Precision".
constexpr double kRelTolFp16 = 2e-3;
}

namespace {
// Every op into a slice among canaries that must survive.
void run_cases(Context& ctx, Precision prec = Precision::fp32) {
  std::mt19937 rng(17);
  const DType dt = precision_dtype(prec);
  double worst = 0;
  for (Shape s : {Shape{2, 5, 7, 9}, Shape{2, 3, 1, 1}, Shape{2, 6, 1, 13}}) {
    // One tensor holding two batch items and extra channels; ops read channel slices of it.
    HostTensor t = random_tensor({s.n, s.c * 2 + 1, s.h, s.w}, rng, -4.f, 4.f);
    HostTensor m = random_tensor({s.n, 1, s.h, s.w}, rng, 0.f, 1.f);
    Tensor td = to_device(ctx, t, dt), md = to_device(ctx, m, dt);
    const HostSlice a(t, 0, s.c), b(t, s.c, s.c);
    const Slice ad(td, 0, s.c), bd(td, s.c, s.c);
    const Shape half{1, s.c, s.h, s.w};
    struct Out {
      CanarySlice cs;
      HostTensor ref;
      Tensor dev;
    };
    std::vector<Out> outs;
    CommandStream cs(ctx);
    auto next = [&](Shape os) -> Out& {
      CanarySlice c = canary_slice(os, rng);
      HostTensor ref = c.host;
      Tensor dev = to_device(ctx, c.host, dt);
      outs.push_back({std::move(c), std::move(ref), std::move(dev)});
      return outs.back();
    };
    outs.reserve(16);
    { Out& o = next(s); add_ref(a, b, o.cs.of(o.ref)); add(cs, ad, bd, o.cs.of(o.dev)); }
    { Out& o = next(s); copy_ref(b, o.cs.of(o.ref)); copy(cs, bd, o.cs.of(o.dev)); }
    { Out& o = next(s); clamp01_ref(a, o.cs.of(o.ref)); clamp01(cs, ad, o.cs.of(o.dev)); }
    for (Activation k : {Activation::none, Activation::leaky_relu, Activation::tanh, Activation::sigmoid,
                         Activation::hardsigmoid}) {
      Out& o = next(s);
      scale_act_ref(a, o.cs.of(o.ref), {k, 0.2f}, 100.f);
      scale_act(cs, ad, o.cs.of(o.dev), {k, 0.2f}, 100.f);
    }
    {  // MOA: m * (item 0) + (1 - m) * (item 1), the mask from item 0 of m.
      Out& o = next(half);
      blend_ref(HostSlice(m, 0, 1, 0, 1), HostSlice(t, 0, s.c, 0, 1), HostSlice(t, 0, s.c, 1, 1), o.cs.of(o.ref));
      blend(cs, Slice(md, 0, 1, 0, 1), Slice(td, 0, s.c, 0, 1), Slice(td, 0, s.c, 1, 1), o.cs.of(o.dev));
    }
    cs.submit_and_wait();
    for (size_t i = 0; i < outs.size(); ++i) {
      // scale_act multiplies by 100: its tolerance scales with it.
      const double tol = (i >= 3 && i < 8) ? 100 * kTol : kTol;
      const HostTensor got = to_host(outs[i].dev);
      if (prec == Precision::fp16) {
        const double err = max_range_rel_diff(got, outs[i].ref, outs[i].cs);
        worst = std::max(worst, err);
        EXPECT_LE(err, kRelTolFp16) << "fp16 op " << i << " " << s.str();
      } else {
        EXPECT_LE(max_abs_diff(got, outs[i].ref, outs[i].cs), tol) << "op " << i << " " << s.str();
      }
      EXPECT_EQ(canary_damage(got, outs[i].cs), "") << "op " << i << " " << s.str();
    }
  }
  if (prec == Precision::fp16) std::printf("[ measured ] elementwise fp16: max relative error %.3g\n", worst);
}
}  // namespace

TEST(Elementwise, EveryOpMatchesReference) { run_cases(vktest::context()); }
TEST(Elementwise, Fp16EveryOpMatchesReference) { run_cases(vktest::context(), Precision::fp16); }

// copy converts between an f32 and an f16 slice (the model's fp32 inputs and outputs), rounding to
// nearest even and saturating at +-65504.
TEST(Elementwise, CopyConvertsBetweenFp32AndFp16Slices) {
  Context& ctx = vktest::context();
  std::mt19937 rng(23);
  HostTensor a = random_tensor({2, 3, 5, 7}, rng, -3.f, 3.f);
  a.at(0, 0, 0, 0) = 1e6f;    // beyond fp16: saturates, never Inf
  a.at(1, 2, 4, 6) = -7e4f;
  a.at(0, 1, 2, 3) = NAN;      // stays NaN
  const CanarySlice hs = canary_slice(a.shape, rng), fs = canary_slice(a.shape, rng);
  Tensor ad = to_device(ctx, a), h = to_device(ctx, hs.host, DType::f16), f = to_device(ctx, fs.host);
  CommandStream cs(ctx);
  copy(cs, Slice(ad), hs.of(h));
  copy(cs, hs.of(h), fs.of(f));
  cs.submit_and_wait();
  const HostTensor hh = to_host(h), ff = to_host(f);
  EXPECT_EQ(canary_damage(hh, hs), "");
  EXPECT_EQ(canary_damage(ff, fs), "");
  for (int64_t n = 0; n < 2; ++n)
    for (int64_t c = 0; c < 3; ++c)
      for (int64_t y = 0; y < 5; ++y)
        for (int64_t x = 0; x < 7; ++x) {
          const float v = a.at(n, c, y, x), got = ff.at(fs.n0 + n, fs.c0 + c, y, x);
          if (std::isnan(v)) {
            EXPECT_TRUE(std::isnan(got));
            continue;
          }
          const float expect = round_to_half(std::clamp(v, -kHalfMax, kHalfMax));
          ASSERT_EQ(got, expect) << v;
          ASSERT_EQ(hh.at(hs.n0 + n, hs.c0 + c, y, x), expect);
        }
  Tensor u(ctx, {1, 1, 5, 7}, DType::u32), g(ctx, {1, 1, 5, 7});
  EXPECT_THROW(copy(cs, Slice(u), Slice(g)), Error);                  // not a float tensor
  EXPECT_THROW(add(cs, Slice(g), Slice(h, 0, 1, 0, 1), Slice(g)), Error);  // mixed precisions
}
// On a context that binds whole tensors a write outside an output slice lands on a canary.
TEST(Elementwise, WritesNothingOutsideItsSlice) {
  run_cases(vktest::whole_binding_context());
  run_cases(vktest::whole_binding_context(), Precision::fp16);
}

TEST(Elementwise, InPlaceAddAndCopyIntoAConcatenation) {
  Context& ctx = vktest::context();
  std::mt19937 rng(2);
  HostTensor a = random_tensor({1, 3, 4, 5}, rng), b = random_tensor({1, 2, 4, 5}, rng);
  Tensor ad = to_device(ctx, a), bd = to_device(ctx, b), cat(ctx, {1, 5, 4, 5});
  CommandStream cs(ctx);
  copy(cs, Slice(ad), Slice(cat, 0, 3));
  copy(cs, Slice(bd), Slice(cat, 3, 2));
  add(cs, Slice(cat, 0, 2), Slice(bd), Slice(cat, 0, 2));  // in place on a slice
  cs.submit_and_wait();
  HostTensor c = to_host(cat);
  for (int64_t y = 0; y < 4; ++y)
    for (int64_t x = 0; x < 5; ++x) {
      EXPECT_EQ(c.at(0, 0, y, x), a.at(0, 0, y, x) + b.at(0, 0, y, x));
      EXPECT_EQ(c.at(0, 2, y, x), a.at(0, 2, y, x));
      EXPECT_EQ(c.at(0, 4, y, x), b.at(0, 1, y, x));
    }
  EXPECT_THROW(add(cs, Slice(ad), Slice(bd), Slice(ad)), Error);  // 3 vs 2 channels
}
