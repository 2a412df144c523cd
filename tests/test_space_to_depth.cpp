// space_to_depth / depth_to_space parity, PyTorch channel order, odd sizes, slices.
#include <gtest/gtest.h>

#include "kernel_test_util.hpp"
#include "op_test_harness.hpp"
#include "vkunroll/kernels/space_to_depth.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::ktest;

namespace {
// Pure data movement: the GPU result must be bit-exact (tolerance 0), in fp16 too (against the
// reference on the inputs as fp16 stores them). Both outputs are slices among canaries. texel: the
// texel-fetch forms (four values of a row per invocation: widths of 1-19 cover partial and several
// quads), else the storage-buffer forms.
optest::OpTest space_to_depth_test(bool texel) {
  std::mt19937 rng(5);
  optest::OpTest test{texel ? "space_to_depth + depth_to_space (texel)" : "space_to_depth + depth_to_space (storage)",
                      {}, {0, 0, false, true}};
  struct C { int64_t n, c, h, w, extra_in, c0_in, extra_out, c0_out; };
  for (const C& c : std::vector<C>{{1, 3, 8, 6, 0, 0, 0, 0}, {2, 5, 7, 9, 2, 1, 4, 4}, {1, 1, 1, 1, 0, 0, 0, 0},
                                   {1, 2, 1, 13, 1, 1, 0, 0}, {1, 99, 12, 10, 0, 0, 0, 0}, {2, 3, 5, 37, 1, 0, 2, 1}}) {
    const Shape os = space_to_depth_shape({c.n, c.c, c.h, c.w});
    optest::OpCase k;
    k.what = Shape{c.n, c.c, c.h, c.w}.str();
    k.inputs = {random_tensor({c.n, c.c + c.extra_in, c.h, c.w}, rng)};
    // And back: depth_to_space of the result restores the input (cropped to its size).
    k.outputs = {{os, c.c0_out + 1, c.extra_out - c.c0_out + 1}, {{c.n, c.c, os.h * 2, os.w * 2}}};
    k.reference = [c](optest::HostRun& r) {
      space_to_depth_ref(HostSlice(r.inputs[0], c.c0_in, c.c), r.out(0));
      depth_to_space_ref(r.written(0), r.out(1));
    };
    k.record = [c, texel](optest::DeviceRun& d) {
      space_to_depth(d.stream, Slice(d.inputs[0], c.c0_in, c.c), d.out(0), TexelReadOptions{texel});
      depth_to_space(d.stream, d.out(0), d.out(1), TexelReadOptions{texel});
      return true;
    };
    k.check = [c, os](const optest::HostRun& r, const std::vector<HostTensor>& got) {
      const HostSlice back(got[1], r.slices[1].c0, r.slices[1].c, r.slices[1].n0, r.slices[1].n);
      for (int64_t ch = 0; ch < c.c; ++ch)
        for (int64_t yy = 0; yy < os.h * 2; ++yy)
          for (int64_t xx = 0; xx < os.w * 2; ++xx)
            ASSERT_EQ(back.at(0, ch, yy, xx), (yy < c.h && xx < c.w) ? r.inputs[0].at(0, c.c0_in + ch, yy, xx) : 0.f);
    };
    test.cases.push_back(std::move(k));
  }
  return test;
}
}  // namespace

TEST(SpaceToDepth, MatchesReferenceOnOddSizesAndSlicesInBothPrecisions) {
  for (bool texel : {true, false}) optest::run_op_test(vktest::context(), space_to_depth_test(texel));
}
// On a context that binds whole tensors a write outside an output slice lands on a canary.
TEST(SpaceToDepth, WritesNothingOutsideItsSlice) {
  for (bool texel : {true, false}) optest::run_op_test(vktest::whole_binding_context(), space_to_depth_test(texel));
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
