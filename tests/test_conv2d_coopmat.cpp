// conv2d `coopmat` (the implicit GEMM on cooperative matrices, fp16, any kernel and stride) against the
// CPU reference: the emulated shader (the same tiling in plain GLSL) on every device, the real
// VK_NV_cooperative_matrix one where the device has it (else skipped, naming the extension).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <cstdio>
#include <memory>
#include <optional>

#include "conv_test_cases.hpp"
#include "kernel_test_util.hpp"
#include "op_test_harness.hpp"
#include "vkunroll/kernels/common.hpp"
#include "vkunroll/kernels/conv2d.hpp"
#include "vkunroll/kernels/shaders.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/runtime/pipeline.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::ktest;

namespace {
// fp16 storage against the fp32 reference: the tolerance of the other fp16 conv tests.
using convtest::kTolFp16;

struct Case {
  int k;  // 1, 3 or 5 (pad k / 2)
  int64_t cin, cout, h, w;
  Act act;
  bool residual;
  int64_t in_extra_c = 0, in_c0 = 0, out_extra_c = 0, out_c0 = 0;  // slices inside larger tensors
  int64_t batch = 1, in_n0 = 0, in_batch_total = 1;
  // Real cooperative matrices only: the emulated GEMM of a long reduction stops early on lavapipe
  // (its loop limit; measured: 3x3 1100->96 and 5x5 396->96 wrong with 16x16x16 or 16x8x8 fragments,
  // 3x3 800->96 and 5x5 200->96 right), so SFENet1's reduction runs where the device has the extension.
  bool real_only = false;
  int s = 1;  // stride
};

// test_conv2d.cpp's 1x1 and 3x3 stride-1 cases, odd channel counts (padding to 16 in both), several
// workgroups along the pixels and along the channels (FM 1, 3 and 4), slices at channel offsets,
// residuals, batch 2.
std::vector<Case> cases() {
  const Act lrelu01 = leaky_relu(0.1f);
  return {
      // k cin cout  h   w  act                                res   in slice  out slice  batch
      {1, 6, 3, 1, 1, Act{Activation::sigmoid}, false, 2, 1, 0, 0},
      {1, 13, 9, 7, 10, lrelu01, true},
      {1, 130, 96, 5, 7, lrelu01, true, 3, 1, 2, 1},
      {1, 129, 64, 3, 11, Act{Activation::tanh}, false, 0, 0, 0, 0, 2, 0, 2},
      {1, 13, 32, 7, 10, lrelu01, true, 0, 0, 0, 0, 2},
      {1, 130, 96, 5, 7, lrelu01, true, 3, 1, 2, 1, 2},
      {1, 3, 17, 9, 13, lrelu01, false, 1, 1, 2, 2},
      {1, 17, 3, 11, 12, Act{Activation::hardsigmoid}, true, 0, 0, 1, 1, 2},
      {1, 3, 96, 6, 9, Act{}, true},
      {1, 48, 48, 20, 13, lrelu01, true, 48, 48, 96, 48, 2, 1, 3},  // RDB-like: a slice of a wider tensor
      {1, 64, 80, 16, 24, Act{}, false},                             // 80: FM 1, 5 channel workgroups
      {1, 160, 64, 9, 31, lrelu01, false, 0, 0, 0, 0, 2},
      // 3x3 implicit GEMM: odd sizes and channel counts, borders (1-pixel images and rows), slices, batch
      {3, 5, 7, 9, 11, leaky_relu(0.01f), true, 4, 2, 5, 3, 2, 0, 2},
      {3, 17, 19, 16, 12, lrelu01, false},
      {3, 8, 16, 13, 35, Act{}, true, 0, 0, 8, 8},
      {3, 7, 5, 21, 1, lrelu01, false},
      {3, 6, 3, 1, 1, Act{Activation::sigmoid}, false},
      {3, 9, 1, 19, 13, Act{Activation::hardsigmoid}, false, 2, 1, 3, 2},
      {3, 48, 48, 20, 13, lrelu01, true, 48, 48, 96, 48, 2, 1, 3},  // the RDB convs' shape, a dense-block slice
      {3, 144, 48, 9, 10, lrelu01, false},
      {3, 96, 64, 7, 33, Act{Activation::tanh}, false, 0, 0, 0, 0, 2},
      // 5x5 implicit GEMM (SFENet1's kernel): pad 2 reaches past 1- and 2-pixel borders; 200 input
      // channels (5000 taps, 313 steps of 16); SFENet1's 396 (9900 taps) on real cooperative matrices; a slice, batch 2
      {5, 7, 9, 11, 13, lrelu01, false},
      {5, 3, 5, 2, 1, Act{Activation::sigmoid}, true},
      {5, 200, 96, 6, 7, lrelu01, false},
      {5, 396, 96, 6, 7, lrelu01, false, 0, 0, 0, 0, 1, 0, 1, true},
      {5, 13, 17, 9, 10, Act{}, true, 3, 2, 4, 1, 2, 0, 2},
      // stride 2 (the UNets' down convs), 1x1 stride 2, two pixel workgroups and channel tiles
      {3, 9, 12, 16, 18, lrelu01, false, 3, 3, 0, 0, 1, 1, 3, false, 2},
      {3, 64, 70, 13, 17, lrelu01, false, 0, 0, 0, 0, 2, 0, 2, false, 2},
      {1, 3, 5, 9, 8, Act{}, false, 0, 0, 0, 0, 1, 0, 1, false, 2},
      {5, 5, 4, 11, 14, Act{Activation::sigmoid}, true, 0, 0, 0, 0, 1, 0, 1, false, 2},
  };
}

struct Run {
  bool emulated = true;
  uint32_t n = 8, k = 16;  // emulated fragment 16 x n x k
  int splits = 0;          // > 0: the reduction in that many splits (partial sums, then the reduce)
};

// One case of the op in fp16: the conv built when it is recorded, on a shared scratch full of fp16
// NaNs (split-K's partial sums must be written before the reduce reads them, or NaNs reach the output).
optest::OpCase coopmat_case(const Case& cc, const Run& run, const std::shared_ptr<ConvWorkspace>& workspace,
                            std::mt19937& rng) {
  const convtest::Case c{cc.k, cc.s, cc.cin, cc.cout, cc.h, cc.w, cc.act, cc.residual, cc.in_extra_c, cc.in_c0,
                         cc.out_extra_c, cc.out_c0, cc.batch, cc.in_n0, cc.in_batch_total};
  convtest::ConvCaseData data = convtest::conv_case_data(c, rng);
  optest::OpCase k = std::move(data.op);
  k.record = [c, w = data.w, b = data.b, p = data.p, run, workspace](optest::DeviceRun& d) {
    CommandStream poison(d.ctx);
    poison.fill(workspace->get(d.ctx, 2, 4u << 20), 0x7fc00000u);  // fp32 NaN in the partial sums' slot
    poison.submit_and_wait();
    ConvOptions options;
    options.precision = Precision::fp16;
    auto conv = std::make_shared<Conv2d>(d.ctx, w, b, p, "conv_coopmat", workspace, options);
    if (run.emulated) conv->set_coopmat_emulation(true, run.n, run.k);
    conv->set_igemm_splits(run.splits);
    const Slice in(d.inputs[0], c.in_c0, c.cin, c.in_n0, c.batch);
    if (!conv->supports(ConvAlgo::coopmat) || !conv->supports(ConvAlgo::coopmat, in.shape())) {
      ADD_FAILURE() << "coopmat does not apply to a case it is for";
      return false;
    }
    const Slice residual(d.inputs[1], 0, -1, c.in_n0, c.batch);
    conv->record(d.stream, in, d.out(0), c.residual ? std::optional<Slice>(residual) : std::nullopt, ConvAlgo::coopmat);
    // One dispatch, epilogue fused; split-K adds the reduce (a reduction of one stage stays whole).
    const bool split = run.splits > 1 && c.cin * c.k * c.k > 16;
    EXPECT_EQ(d.stream.recorded(), split ? 2u : 1u);
    d.keep_alive = conv;
    return true;
  };
  return k;
}

// Every case against the reference in fp16 (coopmat's only precision); the output slice sits among
// canaries (op_test_harness.hpp).
void run_cases(Context& ctx, const std::vector<Case>& all, const Run& run) {
  std::vector<Case> list;
  for (const Case& c : all)
    if (!(c.real_only && run.emulated)) list.push_back(c);
  std::mt19937 rng(4321);
  auto workspace = std::make_shared<ConvWorkspace>();
  optest::OpTest test{std::string("conv2d coopmat ") + (run.emulated ? "emulated" : "NV") + " 16x" +
                          std::to_string(run.n) + "x" + std::to_string(run.k) +
                          (run.splits > 1 ? ", split-K " + std::to_string(run.splits) : ""),
                      {}, {0, kTolFp16}, {Precision::fp16}};
  for (const Case& c : list) test.cases.push_back(coopmat_case(c, run, workspace, rng));
  const optest::OpTestReport report = optest::run_op_test(ctx, test);
  double worst[3] = {0, 0, 0};  // 1x1, 3x3, 5x5
  int ran[3] = {0, 0, 0};
  for (size_t i = 0; i < list.size(); ++i) {
    if (report.error[1][i] < 0) continue;
    const int kind = list[i].k / 2;
    worst[kind] = std::max(worst[kind], report.error[1][i]);
    ++ran[kind];
  }
  std::printf("[ measured ] %s: max abs error %.3g over %d 1x1 cases, %.3g over %d 3x3, %.3g over %d 5x5\n",
              test.op.c_str(), worst[0], ran[0], worst[1], ran[1], worst[2], ran[2]);
}

// The device's NV shape, or a skip naming what is missing.
std::string nv_missing(const Context& ctx) {
  const DeviceInfo& d = ctx.info();
  if (!d.coopmat_nv) return "device '" + d.name + "' has no VK_NV_cooperative_matrix (with fp16 and the Vulkan memory model)";
  if (!d.coopmat_fp16_shape()) return "VK_NV_cooperative_matrix offers no 16x{8,16}x{8,16} fp16*fp16+fp32 subgroup shape";
  if (d.subgroup_size != 32) return "subgroup size " + std::to_string(d.subgroup_size) + ", the coopmat path needs 32";
  return "";
}
}  // namespace

TEST(Conv2dCoopmat, EmulatedMatchesReference) {
  Context& ctx = vktest::context();
  for (auto [n, k] : {std::pair{8u, 16u}, {16u, 16u}, {8u, 8u}}) run_cases(ctx, cases(), {true, n, k});
}

// Subgroup size control: a pipeline that asks for the device's width compiles and runs (full
// subgroups); one that asks for a width the device lacks is refused, naming the device and the width;
// the real coopmat form (it asks for 32) does not apply where 32 is refused. Runs at lavapipe's 8 and 4.
TEST(Conv2dCoopmat, EmulatedSubgroupWidthIsAskedForOrRefused) {
  Context& ctx = vktest::context();
  const DeviceInfo& d = ctx.info();
  EXPECT_LE(d.min_subgroup_size, d.subgroup_size);
  EXPECT_GE(d.max_subgroup_size, d.subgroup_size);
  if (const char* want = std::getenv("VKUNROLL_EXPECT_SUBGROUP")) {
    EXPECT_EQ(d.subgroup_size, uint32_t(std::atoi(want)));
  }
  std::mt19937 rng(9);
  ConvOptions fp16;
  fp16.precision = Precision::fp16;
  Conv2d c1(ctx, random_tensor({8, 4, 1, 1}, rng), random_tensor({1, 1, 1, 8}, rng), {1, 1, 0, {}}, "c1", nullptr, fp16);
  if (!d.subgroup_width_refusal(32).empty()) {
    EXPECT_FALSE(c1.supports(ConvAlgo::coopmat));
  }
  for (uint32_t w : {d.max_subgroup_size * 2, 3u}) {
    const std::string why = d.subgroup_width_refusal(w);
    EXPECT_NE(why.find("'" + d.name + "'"), std::string::npos) << why;
    EXPECT_NE(why.find("subgroups of " + std::to_string(w) + " "), std::string::npos) << why;
    try {
      kernel_pipeline(ctx, "fill_rect", {}, 40, w);
      ADD_FAILURE() << "a pipeline asking for subgroups of " << w << " was made";
    } catch (const DeviceUnavailableError& e) {
      EXPECT_NE(std::string(e.what()).find(why), std::string::npos) << e.what();
    }
  }
  if (!d.compute_subgroup_size_control || !d.compute_full_subgroups) GTEST_SKIP() << "no subgroup size control";
  // fill_rect (64 invocations a workgroup) at the device's own width, full subgroups: it fills.
  struct FillPush {
    uint32_t out_off, out_bs, c, oh, ow, y0, x0, rh, rw;
    float value;
  };
  Tensor t(ctx, {1, 2, 5, 30});
  CommandStream cs(ctx);
  cs.fill(t, 0u);
  const BoundSlice bo = bind_slice(Slice(t), Access::write);
  const FillPush push{bo.offset, bo.batch_stride, 2, 5, 30, 0, 0, 5, 30, 2.5f};
  const Pipeline& pl = kernel_pipeline(ctx, "fill_rect", {}, sizeof push, d.min_subgroup_size);
  EXPECT_EQ(pl.required_subgroup_size(), d.min_subgroup_size);
  cs.dispatch(pl, {bo.arg}, push, Groups{(150 + 63) / 64, 2, 1}, {"fill_rect_width", 0, 0});
  cs.submit_and_wait();
  for (float v : t.download<float>()) ASSERT_EQ(v, 2.5f);
}

// The reduction in splits: partial sums into scratch, then the family's reduce adds bias,
// activation and residual.
TEST(Conv2dCoopmat, EmulatedSplitKMatchesReference) {
  Context& ctx = vktest::context();
  run_cases(ctx, cases(), {true, 8, 16, 3});
  run_cases(ctx, cases(), {true, 16, 8, 2});
}

// Every slice binds its whole tensor: a write outside the output slice lands on a canary.
TEST(Conv2dCoopmat, EmulatedWritesNothingOutsideItsSlice) {
  run_cases(vktest::whole_binding_context(), cases(), {true, 8, 16});
  run_cases(vktest::whole_binding_context(), cases(), {true, 8, 16, 2});
}

TEST(Conv2dCoopmat, AppliesToEveryFp16Conv) {
  Context& ctx = vktest::context();
  std::mt19937 rng(7);
  ConvOptions fp16;
  fp16.precision = Precision::fp16;
  const HostTensor b = random_tensor({1, 1, 1, 8}, rng);
  Conv2d c3(ctx, random_tensor({8, 4, 3, 3}, rng), b, {3, 2, 1, {}}, "c3s2", nullptr, fp16);
  Conv2d c5(ctx, random_tensor({8, 4, 5, 5}, rng), b, {5, 1, 2, {}}, "c5", nullptr, fp16);
  Conv2d c3s1(ctx, random_tensor({8, 4, 3, 3}, rng), b, {3, 1, 1, {}}, "c3", nullptr, fp16);
  Conv2d c1_32(ctx, random_tensor({8, 4, 1, 1}, rng), b, {1, 1, 0, {}});
  Conv2d c1(ctx, random_tensor({8, 4, 1, 1}, rng), b, {1, 1, 0, {}}, "c1", nullptr, fp16);
  for (Conv2d* c : {&c3, &c5, &c1_32, &c3s1}) c->set_coopmat_emulation(true);
  EXPECT_TRUE(c3.supports(ConvAlgo::coopmat));  // stride 2: the gather reads every other pixel
  EXPECT_TRUE(c5.supports(ConvAlgo::coopmat));
  Conv2d c5p1(ctx, random_tensor({8, 4, 5, 5}, rng), b, {5, 1, 1, {}}, "c5p1", nullptr, fp16);
  Conv2d c7(ctx, random_tensor({8, 4, 7, 7}, rng), b, {7, 1, 3, {}}, "c7", nullptr, fp16);
  for (Conv2d* c : {&c5p1, &c7}) c->set_coopmat_emulation(true);
  EXPECT_TRUE(c5p1.supports(ConvAlgo::coopmat));  // any padding and kernel
  EXPECT_TRUE(c7.supports(ConvAlgo::coopmat));
  EXPECT_TRUE(c3s1.supports(ConvAlgo::coopmat));
  EXPECT_FALSE(c1_32.supports(ConvAlgo::coopmat));  // fp32: no tensor cores in this path
  EXPECT_EQ(c1.supports(ConvAlgo::coopmat), nv_missing(ctx).empty());
  c1.set_coopmat_emulation(true);
  EXPECT_TRUE(c1.supports(ConvAlgo::coopmat));
  EXPECT_NE(c1.choose_algorithm(64, 64), ConvAlgo::coopmat);  // timed by the tuner, never picked by default
  EXPECT_THROW(c1.set_coopmat_emulation(true, 12, 16), Error);
  EXPECT_STREQ(conv_algo_name(ConvAlgo::coopmat), "coopmat");
}

// ContextOptions::without_coopmat: the device is created without the extension, and the conv says so.
TEST(Conv2dCoopmat, WithoutCoopmatTheRealFormIsUnsupported) {
  ContextOptions co;
  co.validation = true;
  co.validation_fatal = true;
  co.announce = false;
  co.without_coopmat = true;
  Context ctx(co);
  EXPECT_FALSE(ctx.info().coopmat_nv);
  EXPECT_FALSE(ctx.info().coopmat_fp16_shape().has_value());
  std::mt19937 rng(8);
  ConvOptions fp16;
  fp16.precision = Precision::fp16;
  Conv2d c1(ctx, random_tensor({8, 4, 1, 1}, rng), random_tensor({1, 1, 1, 8}, rng), {1, 1, 0, {}}, "c1", nullptr, fp16);
  EXPECT_FALSE(c1.supports(ConvAlgo::coopmat));
  Tensor x(ctx, {1, 4, 2, 2}, DType::f16), y(ctx, {1, 8, 2, 2}, DType::f16);
  CommandStream cs(ctx);
  EXPECT_THROW(c1.record(cs, Slice(x), Slice(y), std::nullopt, ConvAlgo::coopmat), Error);
}

// What the device offers, in the log of the first GPU run.
TEST(Conv2dCoopmat, DeviceReport) {
  const DeviceInfo& d = vktest::context().info();
  const auto s = d.coopmat_fp16_shape();
  std::printf("[ device   ] %s: VK_NV_cooperative_matrix %s, VK_KHR_cooperative_matrix %s, subgroup %u, %zu shapes%s\n",
              d.name.c_str(), d.coopmat_nv ? "enabled" : "absent", d.coopmat_khr_listed ? "listed" : "absent",
              d.subgroup_size, d.coopmat_shapes.size(), s ? (", coopmat uses " + s->str()).c_str() : "");
  for (const CoopMatShape& c : d.coopmat_shapes) std::printf("[ device   ]   %s\n", c.str().c_str());
  EXPECT_EQ(s.has_value() && !d.coopmat_nv, false);
}

TEST(Conv2dCoopmat, NvMatchesReference) {
  Context& ctx = vktest::context();
  if (const std::string why = nv_missing(ctx); !why.empty()) {
    std::printf("[ device   ] NV cooperative-matrix path not run: %s\n", why.c_str());  // the device check's log
    GTEST_SKIP() << why;
  }
  const CoopMatShape s = *ctx.info().coopmat_fp16_shape();
  run_cases(ctx, cases(), {false, s.n, s.k});
  run_cases(ctx, cases(), {false, s.n, s.k, 3});
  run_cases(vktest::whole_binding_context(), cases(), {false, s.n, s.k});
  run_cases(vktest::whole_binding_context(), cases(), {false, s.n, s.k, 2});
}
