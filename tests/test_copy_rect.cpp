// Rectangle copy and fill (tile cutting and stitching on the device), through the op harness: GPU ==
// CPU reference bit for bit, on channel and batch slices, with everything outside the rectangle untouched.
#include <gtest/gtest.h>

#include "kernel_test_util.hpp"
#include "op_test_harness.hpp"
#include "vkunroll/kernels/copy_rect.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::ktest;

namespace {
// Copies and fills are pure data movement: exact in both precisions (tolerance 0; in fp16 against
// the reference on the inputs as fp16 stores them). Each output is a slice among canaries, and inside
// it everything outside the rectangle keeps its contents, which the harness compares too.
optest::OpTest copy_rect_test() {
  std::mt19937 rng(11);
  optest::OpTest test{"copy_rect", {}, {0, 0, false, true}};
  struct C { int64_t n, c, ih, iw, oh, ow, c0; Rect src; int64_t dy, dx; };
  for (const C& c : std::vector<C>{{1, 3, 20, 30, 20, 30, 0, {0, 0, 20, 30}, 0, 0},
                                   {2, 5, 33, 17, 40, 9, 2, {3, 4, 12, 9}, 27, 0},
                                   {1, 2, 64, 64, 32, 32, 0, {16, 16, 32, 32}, 0, 0},
                                   {3, 1, 5, 5, 7, 7, 0, {4, 4, 1, 1}, 6, 6}}) {
    optest::OpCase k;
    k.what = std::to_string(c.src.h) + "x" + std::to_string(c.src.w) + " of " + Shape{c.n, c.c, c.ih, c.iw}.str();
    k.inputs = {random_tensor({c.n, c.c + 2, c.ih, c.iw}, rng)};
    k.outputs = {{{c.n, c.c, c.oh, c.ow}}};
    k.reference = [c](optest::HostRun& r) { copy_rect_ref(HostSlice(r.inputs[0], c.c0, c.c), r.out(0), c.src, c.dy, c.dx); };
    k.record = [c](optest::DeviceRun& d) {
      copy_rect(d.stream, Slice(d.inputs[0], c.c0, c.c), d.out(0), c.src, c.dy, c.dx);
      return true;
    };
    // The reference itself: inside the rectangle the input, elsewhere the slice's old contents.
    k.check = [c](const optest::HostRun& r, const std::vector<HostTensor>&) {
      const ktest::CanarySlice& s = r.slices[0];
      for (int64_t n = 0; n < c.n; ++n)
        for (int64_t ch = 0; ch < c.c; ++ch)
          for (int64_t yy = 0; yy < c.oh; ++yy)
            for (int64_t xx = 0; xx < c.ow; ++xx) {
              const bool in_rect = yy >= c.dy && yy < c.dy + c.src.h && xx >= c.dx && xx < c.dx + c.src.w;
              const float want = in_rect ? r.inputs[0].at(n, c.c0 + ch, c.src.y + yy - c.dy, c.src.x + xx - c.dx)
                                         : s.host.at(s.n0 + n, s.c0 + ch, yy, xx);
              ASSERT_EQ(r.outputs[0].at(s.n0 + n, s.c0 + ch, yy, xx), want);
            }
    };
    test.cases.push_back(std::move(k));
  }
  return test;
}

optest::OpTest fill_rect_test() {
  optest::OpTest test{"fill_rect", {}, {0, 0, false, true}};
  for (const Rect& r : {Rect{5, 7, 9, 11}, Rect{0, 0, 19, 23}, Rect{18, 22, 1, 1}}) {
    optest::OpCase k;
    k.what = std::to_string(r.h) + "x" + std::to_string(r.w) + " at (" + std::to_string(r.y) + ", " + std::to_string(r.x) + ")";
    k.outputs = {{{2, 2, 19, 23}}};
    k.reference = [r](optest::HostRun& h) { fill_rect_ref(h.out(0), r, 0.25f); };
    k.record = [r](optest::DeviceRun& d) {
      fill_rect(d.stream, d.out(0), r, 0.25f);
      return true;
    };
    k.check = [r](const optest::HostRun& h, const std::vector<HostTensor>&) {
      const ktest::CanarySlice& s = h.slices[0];
      EXPECT_EQ(h.outputs[0].at(s.n0, s.c0, r.y, r.x), 0.25f);
      if (r.y > 0) {  // the row above: untouched
        EXPECT_EQ(h.outputs[0].at(s.n0, s.c0, r.y - 1, r.x), s.host.at(s.n0, s.c0, r.y - 1, r.x));
      }
    };
    test.cases.push_back(std::move(k));
  }
  return test;
}
}  // namespace

TEST(CopyRect, MatchesReferenceAndLeavesTheRestAloneInBothPrecisions) { optest::run_op_test(vktest::context(), copy_rect_test()); }
TEST(CopyRect, FillMatchesReferenceInBothPrecisions) { optest::run_op_test(vktest::context(), fill_rect_test()); }
// On a context that binds whole tensors a write outside an output slice lands on a canary.
TEST(CopyRect, WritesNothingOutsideItsSlice) {
  optest::run_op_test(vktest::whole_binding_context(), copy_rect_test());
  optest::run_op_test(vktest::whole_binding_context(), fill_rect_test());
}

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
