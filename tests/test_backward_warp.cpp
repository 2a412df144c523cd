// backward_warp: grid_sample(align_corners=True, padding_mode='border') semantics.
#include <gtest/gtest.h>


#include "kernel_test_util.hpp"
#include "op_test_harness.hpp"
#include "vkunroll/kernels/backward_warp.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::ktest;

TEST(BackwardWarp, ReferenceKnownValues) {
  // Row image [0 10 20 30]; flow x = +1 shifts left, +0.5 interpolates, far out clamps to the border.
  HostTensor img({1, 1, 1, 4}, std::vector<float>{0, 10, 20, 30});
  HostTensor flow({1, 2, 1, 4}, std::vector<float>{1, 0.5f, -100, 100, 7, 7, 7, 7}), out({1, 1, 1, 4});
  backward_warp_ref(HostSlice(img), HostSlice(flow), HostSliceOut(out));
  EXPECT_EQ(out.data, (std::vector<float>{10, 15, 0, 30}));
}

namespace {
// fp32 bilinear of values in [0, 1]: max abs error 1e-5. fp16: image, flow and output stored as
// half, against the same fp32 reference (docs/kernels.md, "Precision").
optest::OpTest warp_test() {
  std::mt19937 rng(11);
  optest::OpTest test{"backward_warp", {}, {1e-5, 5e-3}};
  struct C { int64_t n, c, h, w, img_extra, img_c0, flow_c0; };
  for (const C& c : std::vector<C>{{1, 3, 12, 16, 0, 0, 0}, {2, 3, 9, 7, 2, 1, 3}, {1, 3, 1, 11, 0, 0, 0},
                                   {1, 2, 10, 1, 0, 0, 0}, {1, 1, 1, 1, 0, 0, 1}}) {
    optest::OpCase k;
    k.what = Shape{c.n, c.c, c.h, c.w}.str();
    k.inputs = {random_tensor({c.n, c.c + c.img_extra, c.h, c.w}, rng, 0.f, 1.f),
                random_tensor({c.n, 2 + c.flow_c0, c.h, c.w}, rng, -6.f, 6.f)};
    k.outputs = {{{c.n, c.c, c.h, c.w}}};
    k.reference = [c](optest::HostRun& r) {
      backward_warp_ref(HostSlice(r.inputs[0], c.img_c0, c.c), HostSlice(r.inputs[1], c.flow_c0, 2), r.out(0));
    };
    k.record = [c](optest::DeviceRun& d) {
      backward_warp(d.stream, Slice(d.inputs[0], c.img_c0, c.c), Slice(d.inputs[1], c.flow_c0, 2), d.out(0));
      return true;
    };
    test.cases.push_back(std::move(k));
  }
  return test;
}
}  // namespace

TEST(BackwardWarp, MatchesReferenceInBothPrecisions) { optest::run_op_test(vktest::context(), warp_test()); }
// On a context that binds whole tensors a write outside the output slice lands on a canary.
TEST(BackwardWarp, WritesNothingOutsideItsSlice) { optest::run_op_test(vktest::whole_binding_context(), warp_test()); }

TEST(BackwardWarp, ZeroFlowIsIdentityAndWrongFlowShapeIsAnError) {
  Context& ctx = vktest::context();
  std::mt19937 rng(3);
  HostTensor img = random_tensor({1, 3, 5, 6}, rng);
  Tensor id = to_device(ctx, img), fd = to_device(ctx, HostTensor({1, 2, 5, 6})), od(ctx, img.shape);
  CommandStream cs(ctx);
  backward_warp(cs, Slice(id), Slice(fd), Slice(od));
  cs.submit_and_wait();
  EXPECT_EQ(max_abs_diff(to_host(od), img), 0.0);
  Tensor bad(ctx, {1, 3, 5, 6});
  EXPECT_THROW(backward_warp(cs, Slice(id), Slice(bad), Slice(od)), Error);
}
