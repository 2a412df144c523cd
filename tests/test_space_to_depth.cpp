// space_to_depth / depth_to_space parity, PyTorch channel order, odd sizes, slices.
#include <gtest/gtest.h>

#include "kernel_test_util.hpp"
#include "vkunroll/kernels/elementwise.hpp"
#include "vkunroll/kernels/space_to_depth.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::ktest;

namespace {
// Pure data movement: the GPU result must be bit-exact (tolerance 0), in fp16 too (against the
// reference on the inputs as fp16 stores them). Both outputs are slices among canaries that must survive.
void run_cases(Context& ctx, Precision prec = Precision::fp32) {
  std::mt19937 rng(5);
  const DType dt = precision_dtype(prec);
  struct C { int64_t n, c, h, w, extra_in, c0_in, extra_out, c0_out; };
  for (const C& c : std::vector<C>{{1, 3, 8, 6, 0, 0, 0, 0}, {2, 5, 7, 9, 2, 1, 4, 4}, {1, 1, 1, 1, 0, 0, 0, 0},
                                   {1, 2, 1, 13, 1, 1, 0, 0}, {1, 99, 12, 10, 0, 0, 0, 0}}) {
    HostTensor x = random_tensor({c.n, c.c + c.extra_in, c.h, c.w}, rng);
    if (prec == Precision::fp16) x = rounded_to_half(x);
    const Shape os = space_to_depth_shape({c.n, c.c, c.h, c.w});
    const CanarySlice ys = canary_slice(os, rng, c.c0_out + 1, c.extra_out - c.c0_out + 1);
    HostTensor y_ref = ys.host;
    space_to_depth_ref(HostSlice(x, c.c0_in, c.c), ys.of(y_ref));
    Tensor xd = to_device(ctx, x, dt), yd = to_device(ctx, ys.host, dt);
    // And back: depth_to_space of the result restores the input (cropped to its size).
    const CanarySlice bs = canary_slice({c.n, c.c, os.h * 2, os.w * 2}, rng);
    Tensor back = to_device(ctx, bs.host, dt);
    CommandStream cs(ctx);
    space_to_depth(cs, Slice(xd, c.c0_in, c.c), ys.of(yd));
    depth_to_space(cs, ys.of(yd), bs.of(back));
    cs.submit_and_wait();
    const HostTensor y = to_host(yd);
    EXPECT_EQ(max_abs_diff(y, y_ref, ys), 0.0) << c.h << "x" << c.w;
    EXPECT_EQ(canary_damage(y, ys), "") << "space_to_depth " << c.h << "x" << c.w;
    const HostTensor bd = to_host(back);
    EXPECT_EQ(canary_damage(bd, bs), "") << "depth_to_space " << c.h << "x" << c.w;
    HostTensor b({c.n, c.c, os.h * 2, os.w * 2}), b_ref = b;
    copy_ref(HostSlice(bd, bs.c0, bs.c, bs.n0, bs.n), HostSliceOut(b));
    depth_to_space_ref(HostSlice(y_ref, ys.c0, ys.c, ys.n0, ys.n), HostSliceOut(b_ref));
    EXPECT_EQ(max_abs_diff(b, b_ref), 0.0);
    for (int64_t ch = 0; ch < c.c; ++ch)
      for (int64_t yy = 0; yy < os.h * 2; ++yy)
        for (int64_t xx = 0; xx < os.w * 2; ++xx)
          ASSERT_EQ(b.at(0, ch, yy, xx), (yy < c.h && xx < c.w) ? x.at(0, c.c0_in + ch, yy, xx) : 0.f);
  }
}
}  // namespace

TEST(SpaceToDepth, MatchesReferenceOnOddSizesAndSlices) { run_cases(vktest::context()); }
TEST(SpaceToDepth, Fp16MatchesReferenceOnOddSizesAndSlices) { run_cases(vktest::context(), Precision::fp16); }
// On a context that binds whole tensors a write outside an output slice lands on a canary.
TEST(SpaceToDepth, WritesNothingOutsideItsSlice) {
  run_cases(vktest::whole_binding_context());
  run_cases(vktest::whole_binding_context(), Precision::fp16);
}

TEST(SpaceToDepth, PixelUnshuffleChannelOrder) {
  // 1 channel 2x2 [[a b] [c d]] -> 4 channels a, b, c, d (channel = i*2 + j).
  HostTensor x({1, 1, 2, 2}, std::vector<float>{1, 2, 3, 4}), y({1, 4, 1, 1});
  space_to_depth_ref(HostSlice(x), HostSliceOut(y));
  EXPECT_EQ(y.data, (std::vector<float>{1, 2, 3, 4}));
  // 2 channels: output channel c*4 + i*2 + j.
  HostTensor x2({1, 2, 2, 2}, std::vector<float>{1, 2, 3, 4, 5, 6, 7, 8}), y2({1, 8, 1, 1});
  space_to_depth_ref(HostSlice(x2), HostSliceOut(y2));
  EXPECT_EQ(y2.data, (std::vector<float>{1, 2, 3, 4, 5, 6, 7, 8}));
  EXPECT_EQ(space_to_depth_shape({1, 99, 260, 346}), (Shape{1, 396, 130, 173}));
  EXPECT_EQ(depth_to_space_shape({1, 256, 130, 173}), (Shape{1, 64, 260, 346}));
  EXPECT_THROW(depth_to_space_shape({1, 6, 2, 2}), Error);
}
