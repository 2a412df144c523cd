// Reflection pad and crop: the size adapter's pads, PyTorch's reflection, big pads, round trip.
#include <gtest/gtest.h>

#include "kernel_test_util.hpp"
#include "op_test_harness.hpp"
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
// them). Both outputs are slices among canaries. texel: the pad's and the crop's texel-fetch forms,
// else their storage-buffer forms. 20x30 and 12x21 reflect once (REFLECT_ONCE, no pad reaches its
// axis); 11x12 does not (its bottom pad, 11, reaches its height), nor do the rest.
optest::OpTest pad_and_crop_test(bool texel) {
  std::mt19937 rng(7);
  optest::OpTest test{texel ? "reflection_pad (texel) + crop" : "reflection_pad (storage) + crop", {}, {0, 0, false, true}};
  struct C { int64_t n, c, h, w, extra, c0; };
  for (const C& c : std::vector<C>{{1, 3, 20, 30, 0, 0}, {2, 5, 33, 7, 3, 2}, {1, 2, 1, 13, 0, 0}, {1, 1, 1, 1, 1, 1},
                                   {1, 67, 5, 9, 0, 0}, {1, 2, 11, 12, 0, 0},
                                   {1, 2, 12, 21, 1, 1}}) {
    const Pads pads = size_adapter_pads(c.h, c.w);
    optest::OpCase k;
    k.what = Shape{c.n, c.c, c.h, c.w}.str();
    k.inputs = {random_tensor({c.n, c.c + c.extra, c.h, c.w}, rng)};
    k.outputs = {{{c.n, c.c, c.h + pads.top + pads.bottom, c.w + pads.left + pads.right}},
                 {{c.n, c.c, c.h, c.w}, c.c0 + 1, c.extra - c.c0 + 1}};
    k.reference = [c, pads](optest::HostRun& r) {
      reflection_pad_ref(HostSlice(r.inputs[0], c.c0, c.c), r.out(0), pads);
      crop_ref(r.written(0), r.out(1), pads.top, pads.left);
    };
    k.record = [c, pads, texel](optest::DeviceRun& d) {
      reflection_pad(d.stream, Slice(d.inputs[0], c.c0, c.c), d.out(0), pads, TexelReadOptions{texel});
      crop(d.stream, d.out(0), d.out(1), pads.top, pads.left, TexelReadOptions{texel});
      return true;
    };
    // The crop undoes the pad.
    k.check = [c](const optest::HostRun& r, const std::vector<HostTensor>&) {
      const HostSlice y = r.written(1);
      for (int64_t n = 0; n < c.n; ++n)
        for (int64_t ch = 0; ch < c.c; ++ch)
          for (int64_t yy = 0; yy < c.h; ++yy)
            for (int64_t xx = 0; xx < c.w; ++xx) ASSERT_EQ(y.at(n, ch, yy, xx), r.inputs[0].at(n, c.c0 + ch, yy, xx));
    };
    test.cases.push_back(std::move(k));
  }
  return test;
}
}  // namespace

TEST(ReflectionPad, PadAndCropMatchReferenceInBothPrecisions) {
  for (bool texel : {true, false}) optest::run_op_test(vktest::context(), pad_and_crop_test(texel));
  Context& ctx = vktest::context();
  Tensor a(ctx, {1, 1, 4, 4}), b(ctx, {1, 1, 3, 3});
  CommandStream cs(ctx);
  EXPECT_THROW(crop(cs, Slice(a), Slice(b), 2, 0), Error);
  EXPECT_THROW(reflection_pad(cs, Slice(a), Slice(b), Pads{}), Error);
}

// On a context that binds whole tensors a write outside an output slice lands on a canary.
TEST(ReflectionPad, WritesNothingOutsideItsSlice) {
  for (bool texel : {true, false}) optest::run_op_test(vktest::whole_binding_context(), pad_and_crop_test(texel));
}
