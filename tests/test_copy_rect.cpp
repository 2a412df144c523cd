// Rectangle copy and fill (tile cutting and stitching on the device): GPU == CPU reference bit for
// bit, on channel and batch slices, with everything outside the rectangle untouched.
#include <gtest/gtest.h>

#include "kernel_test_util.hpp"
#include "vkunroll/kernels/copy_rect.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::ktest;

namespace {
// Copies and fills are exact in both precisions: fp16 inputs (already rounded to half) copy bit for bit.
void copy_cases(DType dt) {
  Context& ctx = vktest::context();
  std::mt19937 rng(11);
  struct C { int64_t n, c, ih, iw, oh, ow, c0; Rect src; int64_t dy, dx; };
  for (const C& c : std::vector<C>{{1, 3, 20, 30, 20, 30, 0, {0, 0, 20, 30}, 0, 0},
                                   {2, 5, 33, 17, 40, 9, 2, {3, 4, 12, 9}, 27, 0},
                                   {1, 2, 64, 64, 32, 32, 0, {16, 16, 32, 32}, 0, 0},
                                   {3, 1, 5, 5, 7, 7, 0, {4, 4, 1, 1}, 6, 6}}) {
    HostTensor x = rounded_to_half(random_tensor({c.n, c.c + 2, c.ih, c.iw}, rng));
    HostTensor y = rounded_to_half(random_tensor({c.n, c.c + 2, c.oh, c.ow}, rng)), y_ref = y;
    copy_rect_ref(HostSlice(x, c.c0, c.c), HostSliceOut(y_ref, c.c0, c.c), c.src, c.dy, c.dx);
    Tensor xd = to_device(ctx, x, dt), yd = to_device(ctx, y, dt);
    CommandStream cs(ctx);
    copy_rect(cs, Slice(xd, c.c0, c.c), Slice(yd, c.c0, c.c), c.src, c.dy, c.dx);
    cs.submit_and_wait();
    EXPECT_EQ(max_abs_diff(to_host(yd), y_ref), 0.0) << c.src.h << "x" << c.src.w;
    // The reference itself: inside the rectangle the input, elsewhere the old output.
    for (int64_t n = 0; n < c.n; ++n)
      for (int64_t ch = 0; ch < c.c + 2; ++ch)
        for (int64_t yy = 0; yy < c.oh; ++yy)
          for (int64_t xx = 0; xx < c.ow; ++xx) {
            const bool in_rect = ch >= c.c0 && ch < c.c0 + c.c && yy >= c.dy && yy < c.dy + c.src.h && xx >= c.dx &&
                                 xx < c.dx + c.src.w;
            const float want = in_rect ? x.at(n, ch, c.src.y + yy - c.dy, c.src.x + xx - c.dx) : y.at(n, ch, yy, xx);
            ASSERT_EQ(y_ref.at(n, ch, yy, xx), want);
          }
  }
}

void fill_cases(DType dt) {
  Context& ctx = vktest::context();
  std::mt19937 rng(12);
  HostTensor y = rounded_to_half(random_tensor({2, 4, 19, 23}, rng)), y_ref = y;
  const Rect r{5, 7, 9, 11};
  fill_rect_ref(HostSliceOut(y_ref, 1, 2, 1, 1), r, 0.25f);
  Tensor yd = to_device(ctx, y, dt);
  CommandStream cs(ctx);
  fill_rect(cs, Slice(yd, 1, 2, 1, 1), r, 0.25f);
  cs.submit_and_wait();
  EXPECT_EQ(max_abs_diff(to_host(yd), y_ref), 0.0);
  EXPECT_EQ(y_ref.at(1, 1, 5, 7), 0.25f);
  EXPECT_EQ(y_ref.at(0, 1, 5, 7), y.at(0, 1, 5, 7));  // batch item 0 untouched
}
}  // namespace

TEST(CopyRect, MatchesReferenceAndLeavesTheRestAlone) { copy_cases(DType::f32); }
TEST(CopyRect, Fp16MatchesReferenceAndLeavesTheRestAlone) { copy_cases(DType::f16); }
TEST(CopyRect, FillMatchesReference) { fill_cases(DType::f32); }
TEST(CopyRect, Fp16FillMatchesReference) { fill_cases(DType::f16); }

TEST(CopyRect, MixedPrecisionIsRefused) {
  Context& ctx = vktest::context();
  Tensor a(ctx, {1, 1, 8, 8}), b(ctx, {1, 1, 8, 8}, DType::f16);
  CommandStream cs(ctx);
  EXPECT_THROW(copy_rect(cs, Slice(a), Slice(b), {0, 0, 4, 4}, 0, 0), Error);
}

TEST(CopyRect, RectanglesOutsideTheirSlicesAreRefused) {
  Context& ctx = vktest::context();
  Tensor a(ctx, {1, 1, 8, 8}), b(ctx, {1, 1, 4, 4}), c(ctx, {1, 2, 8, 8});
  CommandStream cs(ctx);
  EXPECT_THROW(copy_rect(cs, Slice(a), Slice(b), {0, 0, 5, 4}, 0, 0), Error);  // taller than the output
  EXPECT_THROW(copy_rect(cs, Slice(a), Slice(b), {6, 6, 3, 3}, 0, 0), Error);  // source past the input
  EXPECT_THROW(copy_rect(cs, Slice(a), Slice(c), {0, 0, 2, 2}, 0, 0), Error);  // channels differ
  EXPECT_THROW(fill_rect(cs, Slice(b), {-1, 0, 2, 2}, 0.f), Error);
  HostTensor h({1, 1, 4, 4});
  EXPECT_THROW(fill_rect_ref(HostSliceOut(h), {3, 3, 2, 2}, 1.f), Error);
}
