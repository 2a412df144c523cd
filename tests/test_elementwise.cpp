// Elementwise ops on slices: add, scale*act, blend across batch items, clamp, copy.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iterator>

#include "kernel_test_util.hpp"
#include "op_test_harness.hpp"
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
constexpr Activation kActivations[] = {Activation::none, Activation::leaky_relu, Activation::tanh,
                                       Activation::sigmoid, Activation::hardsigmoid};

// Every op into its own slice among canaries, one case a shape: add, copy, clamp01, scale_act with
// each activation (x100: its fp32 tolerance scales with it) and blend across batch items. texel: the
// inputs through texel buffers (elementwise_texel.comp), else as storage buffers.
optest::OpTest elementwise_test(bool texel) {
  std::mt19937 rng(17);
  optest::OpTest test{texel ? "elementwise (texel)" : "elementwise (storage)", {}, {kTol, kRelTolFp16, true}};
  for (Shape s : {Shape{2, 5, 7, 9}, Shape{2, 3, 1, 1}, Shape{2, 6, 1, 13}, Shape{2, 3, 37, 29}}) {
    optest::OpCase k;
    k.what = s.str();
    // One tensor holding two batch items and extra channels; ops read channel slices of it.
    k.inputs = {random_tensor({s.n, s.c * 2 + 1, s.h, s.w}, rng, -4.f, 4.f), random_tensor({s.n, 1, s.h, s.w}, rng, 0.f, 1.f)};
    k.outputs.assign(3, {s});
    for (size_t i = 0; i < std::size(kActivations); ++i) k.outputs.push_back({s, 1, 2, 100});
    k.outputs.push_back({{1, s.c, s.h, s.w}});
    k.reference = [s](optest::HostRun& r) {
      const HostSlice a(r.inputs[0], 0, s.c), b(r.inputs[0], s.c, s.c);
      add_ref(a, b, r.out(0));
      copy_ref(b, r.out(1));
      clamp01_ref(a, r.out(2));
      for (size_t i = 0; i < std::size(kActivations); ++i) scale_act_ref(a, r.out(3 + i), {kActivations[i], 0.2f}, 100.f);
      // MOA: m * (item 0) + (1 - m) * (item 1), the mask from item 0 of m.
      blend_ref(HostSlice(r.inputs[1], 0, 1, 0, 1), HostSlice(r.inputs[0], 0, s.c, 0, 1),
                HostSlice(r.inputs[0], 0, s.c, 1, 1), r.out(8));
    };
    k.record = [s, texel](optest::DeviceRun& d) {
      const Slice a(d.inputs[0], 0, s.c), b(d.inputs[0], s.c, s.c);
      const TexelReadOptions o{texel};
      add(d.stream, a, b, d.out(0), o);
      copy(d.stream, b, d.out(1), o);
      clamp01(d.stream, a, d.out(2), o);
      for (size_t i = 0; i < std::size(kActivations); ++i)
        scale_act(d.stream, a, d.out(3 + i), {kActivations[i], 0.2f}, 100.f, o);
      blend(d.stream, Slice(d.inputs[1], 0, 1, 0, 1), Slice(d.inputs[0], 0, s.c, 0, 1), Slice(d.inputs[0], 0, s.c, 1, 1),
            d.out(8), o);
      return true;
    };
    test.cases.push_back(std::move(k));
  }
  return test;
}
}  // namespace

TEST(Elementwise, EveryOpMatchesReferenceInBothPrecisions) {
  for (bool texel : {true, false}) optest::run_op_test(vktest::context(), elementwise_test(texel));
}

// copy converts between an f32 and an f16 slice (the model's fp32 inputs and outputs), rounding to
// nearest even and saturating at +-65504.
TEST(Elementwise, CopyConvertsBetweenFp32AndFp16Slices) {
  Context& ctx = vktest::context();
  std::mt19937 rng(23);
  HostTensor a = random_tensor({2, 3, 11, 13}, rng, -3.f, 3.f);  // 143-pixel planes: three workgroups
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
      for (int64_t y = 0; y < 11; ++y)
        for (int64_t x = 0; x < 13; ++x) {
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
  for (bool texel : {true, false}) optest::run_op_test(vktest::whole_binding_context(), elementwise_test(texel));
}

// In place, both input forms: a texel read of the buffer the same dispatch writes is safe because
// each element is read only by the invocation that writes it, before it writes it. 37x29: several
// elements an invocation.
TEST(Elementwise, InPlaceAddAndCopyIntoAConcatenation) {
  Context& ctx = vktest::context();
  std::mt19937 rng(2);
  const int64_t h = 37, w = 29;
  HostTensor a = random_tensor({1, 3, h, w}, rng), b = random_tensor({1, 2, h, w}, rng);
  Tensor ad = to_device(ctx, a), bd = to_device(ctx, b), cat(ctx, {1, 5, h, w});
  CommandStream cs(ctx);
  for (bool texel : {true, false}) {
    const TexelReadOptions o{texel};
    copy(cs, Slice(ad), Slice(cat, 0, 3), o);
    copy(cs, Slice(bd), Slice(cat, 3, 2), o);
    add(cs, Slice(cat, 0, 2), Slice(bd), Slice(cat, 0, 2), o);  // in place on a slice
    cs.submit_and_wait();
    HostTensor c = to_host(cat);
    for (int64_t y = 0; y < h; ++y)
      for (int64_t x = 0; x < w; ++x) {
        ASSERT_EQ(c.at(0, 0, y, x), a.at(0, 0, y, x) + b.at(0, 0, y, x)) << texel;
        ASSERT_EQ(c.at(0, 1, y, x), a.at(0, 1, y, x) + b.at(0, 1, y, x)) << texel;
        ASSERT_EQ(c.at(0, 2, y, x), a.at(0, 2, y, x)) << texel;
        ASSERT_EQ(c.at(0, 4, y, x), b.at(0, 1, y, x)) << texel;
      }
  }
  EXPECT_THROW(add(cs, Slice(ad), Slice(bd), Slice(ad)), Error);  // 3 vs 2 channels
}
