// The EDI physics unroller: analytic cases, stability, and GPU == CPU.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <random>

#include "op_test_harness.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/kernels/physics_unroll.hpp"
#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;

namespace {
std::vector<float> run_gpu(const std::vector<float>& rs, int channels, const PixelEventLists& ev,
                           const PhysicsUnrollParams& prm) {
  Context& ctx = vktest::context();
  Tensor rs_t(ctx, {1, channels, ev.height, ev.width}), out_t(ctx, {1, channels, ev.height, ev.width});
  rs_t.upload(rs);
  PhysicsUnroll op(ctx, ev);
  CommandStream cs(ctx);
  op.record(cs, rs_t, out_t, prm);
  cs.submit_and_wait();
  return out_t.download<float>();
}

// One row, one pixel, exposure [0, 1000) µs.
std::vector<double> starts(int h, double s0, double delay) {
  std::vector<double> v(h);
  for (int y = 0; y < h; ++y) v[y] = s0 + y * delay;
  return v;
}
std::vector<double> plus(std::vector<double> v, double d) {
  for (auto& x : v) x += d;
  return v;
}
}  // namespace

TEST(PhysicsUnroll, NoEventsReturnsTheInput) {
  EventStream es;
  es.width = 5, es.height = 3;
  auto s = starts(3, 0, 10);
  auto ev = gather_pixel_events(es, 500, s, plus(s, 1000), 0, 0, 5, 3);
  std::vector<float> rs(15);
  for (int i = 0; i < 15; ++i) rs[i] = i / 15.f;
  PhysicsUnrollParams prm;
  auto cpu = physics_unroll_ref(rs, 1, ev, prm);
  auto gpu = run_gpu(rs, 1, ev, prm);
  for (int i = 0; i < 15; ++i) {
    EXPECT_NEAR(cpu[i], rs[i], 1e-6);
    EXPECT_NEAR(gpu[i], rs[i], 1e-5);
  }
  // Without events the formula is clamp(v, 0, (max_value - log_offset)^(1/gamma)): the GPU gives that
  // bit for bit (no fp32 round trip x^2.2 + offset, exp(log), - offset, ^(1/2.2), which loses bits on
  // dark pixels), below 0, above 1 and above the cap too; the CPU reference in double agrees.
  prm.gamma = 2.2f;
  prm.log_offset = 0.05f;
  const float cap = static_cast<float>(std::pow(double(prm.max_value) - double(prm.log_offset), 1.0 / double(prm.gamma)));
  rs = {0.f, 1e-4f, 0.003f, 0.01f, 0.25f, 0.5f, 0.999f, 1.f, 1.5f, 3.f, -0.5f, 0.7f, 100.f, 0.9f, 0.1f};
  gpu = run_gpu(rs, 1, ev, prm);
  cpu = physics_unroll_ref(rs, 1, ev, prm);
  for (int i = 0; i < 15; ++i) {
    const float expected = std::clamp(rs[i], 0.f, cap);
    EXPECT_EQ(gpu[i], expected) << "pixel " << i;
    EXPECT_NEAR(cpu[i], expected, 1e-6 * std::max(1.f, expected)) << "pixel " << i;
  }
}

TEST(PhysicsUnroll, OneEventAnalytic) {
  // Pixel brightness L before the event at tau, L*e^c after. RS = mean over [0, 1000).
  const double c = 0.25, tau = 300, L = 0.2;
  const double rs = (L * tau + L * std::exp(c) * (1000 - tau)) / 1000;
  EventStream es;
  es.width = 1, es.height = 1;
  es.push(static_cast<int64_t>(tau), 0, 0, 1);
  PhysicsUnrollParams prm;
  prm.contrast = static_cast<float>(c);
  for (double t_star : {-200.0, 0.0, 100.0, 299.0, 301.0, 800.0, 1500.0}) {
    auto ev = gather_pixel_events(es, t_star, {0.0}, {1000.0}, 0, 0, 1, 1);
    const double expect = t_star < tau ? L : L * std::exp(c);
    auto cpu = physics_unroll_ref({static_cast<float>(rs)}, 1, ev, prm);
    auto gpu = run_gpu({static_cast<float>(rs)}, 1, ev, prm);
    EXPECT_NEAR(cpu[0], expect, 1e-6) << "t*=" << t_star;
    EXPECT_NEAR(gpu[0], expect, 1e-5) << "t*=" << t_star;
  }
}

// With a log offset eps the events measure log(L + eps): after the event, L' = (L + eps) e^c - eps.
TEST(PhysicsUnroll, OneEventWithALogOffsetAnalytic) {
  const double c = 0.3, tau = 400, L = 0.05, eps = 0.05;
  const double after = (L + eps) * std::exp(c) - eps;
  const double rs = (L * tau + after * (1000 - tau)) / 1000;
  EventStream es;
  es.width = 1, es.height = 1;
  es.push(static_cast<int64_t>(tau), 0, 0, 1);
  PhysicsUnrollParams prm;
  prm.contrast = static_cast<float>(c);
  prm.log_offset = static_cast<float>(eps);
  for (double t_star : {0.0, 399.0, 401.0, 1200.0}) {
    auto ev = gather_pixel_events(es, t_star, {0.0}, {1000.0}, 0, 0, 1, 1);
    const double expect = t_star < tau ? L : after;
    auto cpu = physics_unroll_ref({static_cast<float>(rs)}, 1, ev, prm);
    auto gpu = run_gpu({static_cast<float>(rs)}, 1, ev, prm);
    EXPECT_NEAR(cpu[0], expect, 1e-6) << "t*=" << t_star;
    EXPECT_NEAR(gpu[0], expect, 1e-5) << "t*=" << t_star;
  }
  // Without the offset the same frame unrolls to another value: the offset is not ignored.
  prm.log_offset = 0.f;
  auto ev = gather_pixel_events(es, 1200.0, {0.0}, {1000.0}, 0, 0, 1, 1);
  EXPECT_GT(std::abs(physics_unroll_ref({static_cast<float>(rs)}, 1, ev, prm)[0] - after), 1e-3);
  prm.log_offset = -0.01f;
  Context& ctx = vktest::context();
  Tensor rs_t(ctx, {1, 1, 1, 1}), out_t(ctx, {1, 1, 1, 1});
  CommandStream cs(ctx);
  EXPECT_THROW(PhysicsUnroll(ctx, ev).record(cs, rs_t, out_t, prm), Error);
}

TEST(PhysicsUnroll, ThousandsOfEventsStayFinite) {
  EventStream es;
  es.width = 2, es.height = 1;
  for (int i = 0; i < 5000; ++i) es.push(i / 5, 0, 0, 1);  // 5000 ON events in 1 ms at pixel 0
  std::vector<float> rs = {0.5f, 0.f};                      // pixel 1 black
  PhysicsUnrollParams prm;
  prm.contrast = 0.3f;
  for (double t_star : {0.0, 500.0, 1000.0}) {
    auto ev = gather_pixel_events(es, t_star, {0.0}, {1000.0}, 0, 0, 2, 1);
    for (const auto& out : {physics_unroll_ref(rs, 1, ev, prm), run_gpu(rs, 1, ev, prm)}) {
      EXPECT_TRUE(std::isfinite(out[0])) << t_star;
      EXPECT_GE(out[0], 0.f);
      EXPECT_LE(out[0], prm.max_value);
      EXPECT_EQ(out[1], 0.f);
    }
  }
}

namespace {
// 20,000 events at random pixels from t = -3000 us, 0-3 us apart.
EventStream random_stream(std::mt19937& rng, int W, int H) {
  EventStream es;
  es.width = W, es.height = H;
  int64_t t = -3000;
  std::uniform_int_distribution<int> dx(0, W - 1), dy(0, H - 1), dp(0, 1), dt(0, 3);
  for (int i = 0; i < 20000; ++i) {
    t += dt(rng);
    es.push(t, static_cast<uint16_t>(dx(rng)), static_cast<uint16_t>(dy(rng)), dp(rng) ? 1 : -1);
  }
  return es;
}
}  // namespace

namespace {
// GPU == CPU through the op harness on random streams: a fractional line delay, t* before, inside and
// after the exposure, with and without a log offset; within 1e-4 of the output's range. fp32 only:
// the unroller computes and stores f32 (its exponentials), and fp16 tensors are refused (below).
optest::OpTest physics_unroll_test() {
  std::mt19937 rng(7);
  const int W = 23, H = 17, C = 3;
  const EventStream es = random_stream(rng, W, H);
  const auto s = starts(H, 0, 37.5);
  HostTensor rs({1, C, H, W});
  std::uniform_real_distribution<float> u(0.f, 1.f);
  for (auto& v : rs.data) v = u(rng);
  rs.data[5] = 0.f;
  optest::OpTest test{"physics_unroll", {}, {1e-4, 0}};
  test.precisions = {Precision::fp32};
  for (float offset : {0.f, 0.05f})
    for (double t_star : {-1000.0, 0.0, 650.0, 2400.0}) {
      PhysicsUnrollParams prm;
      prm.contrast = 0.2f;
      prm.gamma = 2.2f;
      prm.log_offset = offset;
      const auto ev = std::make_shared<PixelEventLists>(gather_pixel_events(es, t_star, s, plus(s, 1500), 0, 0, W, H));
      EXPECT_GT(ev->tau.size(), 100u);
      double scale = 1;
      for (float v : physics_unroll_ref(rs.data, C, *ev, prm)) scale = std::max(scale, double(std::abs(v)));
      optest::OpCase k;
      k.what = "offset " + std::to_string(offset) + ", t* " + std::to_string(t_star) + " us";
      k.inputs = {rs};
      k.outputs = {{{1, C, H, W}, 0, 0, scale}};  // whole items: the unroller writes items, not channel slices
      k.reference = [ev, prm](optest::HostRun& r) {
        const std::vector<float> v = physics_unroll_ref(r.inputs[0].data, int(r.inputs[0].shape.c), *ev, prm);
        HostSliceOut out = r.out(0);
        const Shape sh = out.shape();
        for (int64_t c = 0; c < sh.c; ++c)
          for (int64_t y = 0; y < sh.h; ++y)
            for (int64_t x = 0; x < sh.w; ++x) out.at(0, c, y, x) = v[size_t((c * sh.h + y) * sh.w + x)];
      };
      k.record = [ev, prm](optest::DeviceRun& d) {
        auto op = std::make_shared<PhysicsUnroll>(d.ctx, *ev);
        op->record(d.stream, Slice(d.inputs[0]), d.out(0), prm);
        d.keep_alive = op;
        return true;
      };
      test.cases.push_back(std::move(k));
    }
  return test;
}
}  // namespace

TEST(PhysicsUnroll, GpuMatchesCpuOnRandomStreams) { optest::run_op_test(vktest::context(), physics_unroll_test()); }
// On a context that binds whole tensors a write outside the output item lands on a canary.
TEST(PhysicsUnroll, WritesNothingOutsideItsItem) { optest::run_op_test(vktest::whole_binding_context(), physics_unroll_test()); }

// The session writes each target's physics straight into its item of the batch: item 2 of an image
// batch into item 1 of an output batch, the other items (canaries) untouched; a channel slice is refused.
TEST(PhysicsUnroll, WritesOneItemOfABatchInPlace) {
  std::mt19937 rng(11);
  const int W = 19, H = 13, C = 3;
  const EventStream es = random_stream(rng, W, H);
  const auto s = starts(H, 0, 50);
  const PixelEventLists ev = gather_pixel_events(es, 400, s, plus(s, 1500), 0, 0, W, H);
  ASSERT_GT(ev.tau.size(), 100u);
  const size_t item = size_t(C) * W * H;
  std::vector<float> images(3 * item);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  for (auto& v : images) v = u(rng);
  PhysicsUnrollParams prm;
  prm.contrast = 0.25f;
  prm.gamma = 2.2f;
  prm.log_offset = 0.05f;
  const auto cpu = physics_unroll_ref(std::vector<float>(images.begin() + 2 * item, images.end()), C, ev, prm);

  Context& ctx = vktest::context();
  Tensor rs_t(ctx, {3, C, H, W}), out_t(ctx, {3, C, H, W});
  rs_t.upload(images);
  out_t.upload(std::vector<float>(3 * item, -7.f));
  PhysicsUnroll op(ctx, ev);
  CommandStream cs(ctx);
  op.record(cs, Slice(rs_t, 0, -1, 2, 1), Slice(out_t, 0, -1, 1, 1), prm);
  cs.submit_and_wait();
  const auto out = out_t.download<float>();
  for (size_t i = 0; i < item; ++i) {
    ASSERT_EQ(out[i], -7.f) << "item 0, element " << i;
    ASSERT_NEAR(out[item + i], cpu[i], 1e-4 * std::max(1.f, std::abs(cpu[i]))) << "item 1, element " << i;
    ASSERT_EQ(out[2 * item + i], -7.f) << "item 2, element " << i;
  }
  EXPECT_THROW(op.record(cs, Slice(rs_t, 0, 2, 0, 1), Slice(out_t, 0, 2, 0, 1), prm), Error);
}

// A large image (1.1M pixels: pass 0 runs four an invocation; some 350k pixels with events, over
// 4096 x 64): both passes cover every pixel, against the reference.
TEST(PhysicsUnroll, LargeImagesSpanSeveralGridRows) {
  std::mt19937 rng(5);
  const int W = 1100, H = 1000;
  EventStream es;
  es.width = W, es.height = H;
  std::uniform_int_distribution<int> dx(0, W - 1), dy(0, H - 1), dp(0, 1);
  for (int i = 0; i < 700000; ++i) es.push(i / 700, static_cast<uint16_t>(dx(rng)), static_cast<uint16_t>(dy(rng)), dp(rng) ? 1 : -1);
  const auto s = starts(H, 0, 0.5);
  const PixelEventLists ev = gather_pixel_events(es, 500, s, plus(s, 600), 0, 0, W, H);
  size_t with_events = 0;
  for (size_t k = 0; k + 1 < ev.offsets.size(); ++k) with_events += ev.offsets[k + 1] > ev.offsets[k];
  ASSERT_GT(with_events, size_t(4096 * 64));
  std::vector<float> rs(size_t(W) * H);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  for (auto& v : rs) v = u(rng);
  PhysicsUnrollParams prm;
  prm.contrast = 0.2f;
  const auto cpu = physics_unroll_ref(rs, 1, ev, prm);
  const auto gpu = run_gpu(rs, 1, ev, prm);
  for (size_t i = 0; i < cpu.size(); ++i) ASSERT_NEAR(gpu[i], cpu[i], 1e-4 * std::max(1.f, std::abs(cpu[i]))) << "pixel " << i;
}

TEST(PhysicsUnroll, GatherKeepsOnlyEachRowsWindowAndCrop) {
  EventStream es;
  es.width = 10, es.height = 10;
  es.push(50, 3, 4, 1);    // inside row 4's window
  es.push(50, 3, 9, 1);    // outside the crop (rows 2..5)
  es.push(5000, 3, 4, 1);  // after the exposure and t*
  es.push(60, 1, 4, -1);   // outside the crop columns (2..6)
  auto s = starts(10, 0, 10);
  auto ev = gather_pixel_events(es, 0, s, plus(s, 100), 2, 2, 5, 4);
  ASSERT_EQ(ev.tau.size(), 1u);
  const int pix = (4 - 2) * 5 + (3 - 2);
  EXPECT_EQ(ev.offsets[pix + 1] - ev.offsets[pix], 1u);
  EXPECT_FLOAT_EQ(ev.tau[0], 50.f);
  EXPECT_THROW(gather_pixel_events(es, 0, s, plus(s, 100), 0, 8, 5, 4), Error);
}

// The unroller stays fp32 (its exponentials): an f16 image or output is a named error.
TEST(PhysicsUnroll, Fp16TensorsAreRefused) {
  Context& ctx = vktest::context();
  EventStream es;
  es.width = 4, es.height = 2;
  auto s = starts(2, 0, 10);
  auto ev = gather_pixel_events(es, 50, s, plus(s, 100), 0, 0, 4, 2);
  PhysicsUnroll op(ctx, ev);
  Tensor rs16(ctx, {1, 1, 2, 4}, DType::f16), out32(ctx, {1, 1, 2, 4});
  CommandStream cs(ctx);
  try {
    op.record(cs, rs16, out32, {});
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("f32"), std::string::npos) << e.what();
  }
}
