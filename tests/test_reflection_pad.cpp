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

// Pure data movement: bit-exact.
TEST(ReflectionPad, PadAndCropMatchReference) {
  Context& ctx = vktest::context();
  std::mt19937 rng(7);
  struct C { int64_t n, c, h, w, extra, c0; };
  for (const C& c : std::vector<C>{{1, 3, 20, 30, 0, 0}, {2, 5, 33, 7, 3, 2}, {1, 2, 1, 13, 0, 0}, {1, 1, 1, 1, 1, 1},
                                   {1, 67, 5, 9, 0, 0}}) {
    const Pads pads = size_adapter_pads(c.h, c.w);
    HostTensor x = random_tensor({c.n, c.c + c.extra, c.h, c.w}, rng);
    const Shape ps{c.n, c.c, c.h + pads.top + pads.bottom, c.w + pads.left + pads.right};
    HostTensor padded_ref(ps);
    reflection_pad_ref(HostSlice(x, c.c0, c.c), HostSliceOut(padded_ref), pads);
    HostTensor y = random_tensor({c.n, c.c + c.extra, c.h, c.w}, rng), y_ref = y;
    crop_ref(HostSlice(padded_ref), HostSliceOut(y_ref, c.c0, c.c), pads.top, pads.left);
    Tensor xd = to_device(ctx, x), pd(ctx, ps), yd = to_device(ctx, y);
    CommandStream cs(ctx);
    reflection_pad(cs, Slice(xd, c.c0, c.c), Slice(pd), pads);
    crop(cs, Slice(pd), Slice(yd, c.c0, c.c), pads.top, pads.left);
    cs.submit_and_wait();
    EXPECT_EQ(max_abs_diff(to_host(pd), padded_ref), 0.0) << c.h << "x" << c.w;
    EXPECT_EQ(max_abs_diff(to_host(yd), y_ref), 0.0);
    EXPECT_EQ(max_abs_diff(y_ref, x, c.c0, c.c), 0.0);  // the crop undoes the pad
  }
  Tensor a(ctx, {1, 1, 4, 4}), b(ctx, {1, 1, 3, 3});
  CommandStream cs(ctx);
  EXPECT_THROW(crop(cs, Slice(a), Slice(b), 2, 0), Error);
  EXPECT_THROW(reflection_pad(cs, Slice(a), Slice(b), Pads{}), Error);
}
