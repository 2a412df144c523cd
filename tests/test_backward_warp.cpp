// backward_warp: grid_sample(align_corners=True, padding_mode='border') semantics.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>

#include "kernel_test_util.hpp"
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
// The output is a slice among canaries that must survive. fp16: image, flow and output stored as
// half, against the same fp32 reference (docs/kernels.md, "Precision").
constexpr double kTolFp16 = 5e-3;
void run_cases(Context& ctx, Precision prec = Precision::fp32) {
  std::mt19937 rng(11);
  const DType dt = precision_dtype(prec);
  double worst = 0;
  struct C { int64_t n, c, h, w, img_extra, img_c0, flow_c0; };
  // fp32 bilinear of values in [0, 1]: max abs error 1e-5.
  for (const C& c : std::vector<C>{{1, 3, 12, 16, 0, 0, 0}, {2, 3, 9, 7, 2, 1, 3}, {1, 3, 1, 11, 0, 0, 0},
                                   {1, 2, 10, 1, 0, 0, 0}, {1, 1, 1, 1, 0, 0, 1}}) {
    HostTensor img = random_tensor({c.n, c.c + c.img_extra, c.h, c.w}, rng, 0.f, 1.f);
    HostTensor flow = random_tensor({c.n, 2 + c.flow_c0, c.h, c.w}, rng, -6.f, 6.f);
    const CanarySlice os = canary_slice({c.n, c.c, c.h, c.w}, rng);
    HostTensor out_ref = os.host;
    backward_warp_ref(HostSlice(img, c.img_c0, c.c), HostSlice(flow, c.flow_c0, 2), os.of(out_ref));
    Tensor id = to_device(ctx, img, dt), fd = to_device(ctx, flow, dt), od = to_device(ctx, os.host, dt);
    CommandStream cs(ctx);
    backward_warp(cs, Slice(id, c.img_c0, c.c), Slice(fd, c.flow_c0, 2), os.of(od));
    cs.submit_and_wait();
    const HostTensor out = to_host(od);
    const double err = max_abs_diff(out, out_ref, os);
    worst = std::max(worst, err);
    EXPECT_LE(err, prec == Precision::fp16 ? kTolFp16 : 1e-5) << c.h << "x" << c.w << " " << precision_name(prec);
    EXPECT_EQ(canary_damage(out, os), "") << c.h << "x" << c.w;
  }
  std::printf("[ measured ] backward_warp %s: max abs error %.3g\n", precision_name(prec), worst);
}
}  // namespace

TEST(BackwardWarp, MatchesReference) { run_cases(vktest::context()); }
TEST(BackwardWarp, Fp16MatchesReference) { run_cases(vktest::context(), Precision::fp16); }
// On a context that binds whole tensors a write outside the output slice lands on a canary.
TEST(BackwardWarp, WritesNothingOutsideItsSlice) {
  run_cases(vktest::whole_binding_context());
  run_cases(vktest::whole_binding_context(), Precision::fp16);
}

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
