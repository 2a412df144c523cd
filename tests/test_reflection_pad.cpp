// Reflection pad and crop: the size adapter's pads, PyTorch's reflection, big pads, round trip.
#include <gtest/gtest.h>

#include "kernel_test_util.hpp"
#include "vkunroll/kernels/reflection_pad.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::ktest;

TEST(ReflectionPad, SizeAdapterPads) {
  EXPECT_EQ(size_adapter_pads(260, 346), (Pads{14, 14, 3, 3}));   // 288 x 352
  EXPECT_EQ(size_adapter_pads(64, 32), (Pads{0, 0, 0, 0}));
  EXPECT_EQ(size_adapter_pads(33, 1), (Pads{15, 16, 15, 16}));    // odd remainder bottom/right
  EXPECT_EQ(size_adapter_pads(1, 31), (Pads{15, 16, 0, 1}));
  EXPECT_THROW(size_adapter_pads(0, 5), Error);
}

TEST(ReflectionPad, ReflectIndexMatchesPyTorchWherePyTorchWorks) {
  // ReflectionPad2d on [0 1 2 3] with pad 3: 3 2 1 | 0 1 2 3 | 2 1 0
  const int64_t expect[] = {3, 2, 1, 0, 1, 2, 3, 2, 1, 0};
  for (int64_t i = -3; i < 7; ++i) EXPECT_EQ(reflect_index(i, 4), expect[i + 3]) << i;
  // Beyond PyTorch: pads larger than the size keep folding; size 1 repeats.
  EXPECT_EQ(reflect_index(-4, 3), 0);
  EXPECT_EQ(reflect_index(5, 3), 1);
  EXPECT_EQ(reflect_index(-17, 1), 0);
}

namespace {
// Pure data movement: bit-exact, in fp16 too (against the reference on the inputs as fp16 stores
// them). Both outputs are slices among canaries that must survive.
void run_cases(Context& ctx, Precision prec = Precision::fp32) {
  std::mt19937 rng(7);
  const DType dt = precision_dtype(prec);
  struct C { int64_t n, c, h, w, extra, c0; };
  for (const C& c : std::vector<C>{{1, 3, 20, 30, 0, 0}, {2, 5, 33, 7, 3, 2}, {1, 2, 1, 13, 0, 0}, {1, 1, 1, 1, 1, 1},
                                   {1, 67, 5, 9, 0, 0}}) {
    const Pads pads = size_adapter_pads(c.h, c.w);
    HostTensor x = random_tensor({c.n, c.c + c.extra, c.h, c.w}, rng);
    if (prec == Precision::fp16) x = rounded_to_half(x);
    const Shape ps{c.n, c.c, c.h + pads.top + pads.bottom, c.w + pads.left + pads.right};
    const CanarySlice pcs = canary_slice(ps, rng);
    HostTensor padded_ref = pcs.host;
    reflection_pad_ref(HostSlice(x, c.c0, c.c), pcs.of(padded_ref), pads);
    const CanarySlice ycs = canary_slice({c.n, c.c, c.h, c.w}, rng, c.c0 + 1, c.extra - c.c0 + 1);
    HostTensor y_ref = ycs.host;
    crop_ref(HostSlice(padded_ref, pcs.c0, pcs.c, pcs.n0, pcs.n), ycs.of(y_ref), pads.top, pads.left);
    Tensor xd = to_device(ctx, x, dt), pd = to_device(ctx, pcs.host, dt), yd = to_device(ctx, ycs.host, dt);
    CommandStream cs(ctx);
    reflection_pad(cs, Slice(xd, c.c0, c.c), pcs.of(pd), pads);
    crop(cs, pcs.of(pd), ycs.of(yd), pads.top, pads.left);
    cs.submit_and_wait();
    const HostTensor p = to_host(pd), y = to_host(yd);
    EXPECT_EQ(max_abs_diff(p, padded_ref, pcs), 0.0) << c.h << "x" << c.w;
    EXPECT_EQ(canary_damage(p, pcs), "") << "reflection_pad " << c.h << "x" << c.w;
    EXPECT_EQ(max_abs_diff(y, y_ref, ycs), 0.0);
    EXPECT_EQ(canary_damage(y, ycs), "") << "crop " << c.h << "x" << c.w;
    // The crop undoes the pad.
    for (int64_t n = 0; n < c.n; ++n)
      for (int64_t ch = 0; ch < c.c; ++ch)
        for (int64_t yy = 0; yy < c.h; ++yy)
          for (int64_t xx = 0; xx < c.w; ++xx)
            ASSERT_EQ(y_ref.at(ycs.n0 + n, ycs.c0 + ch, yy, xx), x.at(n, c.c0 + ch, yy, xx));
  }
}
}  // namespace

TEST(ReflectionPad, PadAndCropMatchReference) {
  run_cases(vktest::context());
  Context& ctx = vktest::context();
  Tensor a(ctx, {1, 1, 4, 4}), b(ctx, {1, 1, 3, 3});
  CommandStream cs(ctx);
  EXPECT_THROW(crop(cs, Slice(a), Slice(b), 2, 0), Error);
  EXPECT_THROW(reflection_pad(cs, Slice(a), Slice(b), Pads{}), Error);
}

// On a context that binds whole tensors a write outside an output slice lands on a canary.
TEST(ReflectionPad, Fp16PadAndCropMatchReference) { run_cases(vktest::context(), Precision::fp16); }
TEST(ReflectionPad, WritesNothingOutsideItsSlice) {
  run_cases(vktest::whole_binding_context());
  run_cases(vktest::whole_binding_context(), Precision::fp16);
}
