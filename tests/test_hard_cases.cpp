// Numerical stability of the whole pipeline on hard inputs (docs/hard_cases.md): no events,
// millions of events in one pixel, targets far outside the exposure, zero-length intervals,
// black and saturated pixels, NaN/Inf inputs, and the fp16 refusal. Each case runs the event
// tensors (CPU reference == every GPU algorithm == an independent hand count), the tiny golden
// model (S and M, CPU and Vulkan backends) and the physics unroller (CPU and GPU).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <numeric>
#include <optional>
#include <random>
#include <string>

#include <unistd.h>

#include "vkunroll/host/model/backend_cpu.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/unroll/metrics.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/base/row_timing.hpp"
#include "vkunroll/host/unroll/unroll.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/kernels/event_tensor.hpp"
#include "vkunroll/kernels/physics_unroll.hpp"
#include "model_test_util.hpp"
#include "vkunroll/runtime/command_stream.hpp"
#include "vkunroll/runtime/context.hpp"
#include "vkunroll/base/error.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
using namespace vkunroll::modeltest;

namespace {

constexpr int kW = 24, kH = 20;  // sensor = image size of every case
constexpr int kBins = 4;         // the tiny golden model's N

RowTiming timing(int64_t t0, Rational delay, int64_t exposure, int rows = kH, Readout r = Readout::top_down) {
  RowTiming t;
  t.t0 = Rational(t0);
  t.line_delay = delay;
  t.exposure = Rational(exposure);
  t.rows = rows;
  t.readout = r;
  return t;
}

EventTensorPair pair_at(const RowTiming& tm, Rational t_star, std::optional<Rational> texp = std::nullopt) {
  EventTensorPair p;
  p.timing = tm;
  p.target_us = t_star;
  p.target_exposure_us = texp;
  return p;
}

// Independent of the library: the section-4 formula in double precision with integer counters.
// Exact for the integer row times used with it here.
std::vector<float> hand_count(const EventStream& es, const RowIntervals& job, int bins) {
  const size_t plane = static_cast<size_t>(es.width) * es.height;
  std::vector<uint64_t> n(2 * bins * plane, 0);
  for (size_t i = 0; i < es.size(); ++i) {
    const int y = es.y[i], x = es.x[i];
    const double a = job.a[y].to_double(), b = job.b[y].to_double(), t = static_cast<double>(es.t[i]);
    if (a == b || t < std::min(a, b) || t >= std::max(a, b)) continue;
    int s = es.p[i] > 0 ? 1 : -1;
    if (t < a) s = -s;
    int k = static_cast<int>(std::floor(std::fabs(t - a) * bins / std::fabs(b - a)));
    if (k == bins) k = bins - 1;
    ++n[(2 * static_cast<size_t>(k) + (s > 0)) * plane + static_cast<size_t>(y) * es.width + x];
  }
  return std::vector<float>(n.begin(), n.end());
}

size_t count_differences(const std::vector<float>& a, const std::vector<float>& b) {
  if (a.size() != b.size()) return std::max(a.size(), b.size());
  size_t d = 0;
  for (size_t i = 0; i < a.size(); ++i) d += a[i] != b[i];
  return d;
}

// The first differing cells as "(slice, channel, y, x): a vs b", for failure messages.
std::string first_differences(const std::vector<float>& a, const std::vector<float>& b, int channels) {
  std::string s;
  int shown = 0;
  const size_t plane = static_cast<size_t>(kH) * kW;
  for (size_t i = 0; i < std::min(a.size(), b.size()) && shown < 6; ++i)
    if (a[i] != b[i]) {
      const size_t slice = i / (channels * plane), c = i / plane % channels, y = i % plane / kW, x = i % kW;
      s += " (" + std::to_string(slice) + "," + std::to_string(c) + "," + std::to_string(y) + "," + std::to_string(x) +
           "): " + std::to_string(a[i]) + " vs " + std::to_string(b[i]);
      ++shown;
    }
  return s;
}

double sum(const std::vector<float>& v) {
  double s = 0;
  for (float x : v) s += x;
  return s;
}

template <class F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "(no vkunroll::Error thrown)";
}

// The pairs' tensors from the CPU reference, checked equal to every GPU algorithm and (when
// `hand` is set) to the hand count, cell for cell.
EventTensors build_checked(const EventStream& es, const std::vector<EventTensorPair>& pairs, bool hand = true,
                           bool per_pixel_refuses = false) {
  EventTensorSpec spec;
  spec.bins = kBins;
  const EventTensors cpu = build_event_tensors_ref(es, pairs, spec);
  const size_t slice = cpu.slice(), P = pairs.size();
  if (hand) {
    const auto jobs = event_tensor_jobs(pairs);
    const std::vector<float>* mine[3] = {&cpu.ev1, &cpu.ev2, &cpu.ev3};
    for (size_t j = 0; j < jobs.size(); ++j) {
      const auto expect = hand_count(es, jobs[j], kBins);
      const std::vector<float> got(mine[j / P]->begin() + (j % P) * slice, mine[j / P]->begin() + (j % P + 1) * slice);
      EXPECT_EQ(count_differences(got, expect), 0u) << "CPU reference vs hand count, ev" << j / P + 1 << " pair " << j % P;
    }
  }
  for (auto algo : {EventBinAlgorithm::per_row, EventBinAlgorithm::per_event, EventBinAlgorithm::per_pixel}) {
    EventTensorBuilder b(vktest::context());
    b.set_algorithm(algo);
    if (algo == EventBinAlgorithm::per_pixel && per_pixel_refuses) {
      const std::string msg = error_of([&] { b.build(es, pairs, spec); });
      EXPECT_NE(msg.find("the per-pixel algorithm cannot bin pixel"), std::string::npos) << msg;
      continue;
    }
    const EventTensors gpu = b.build(es, pairs, spec);
    EXPECT_EQ(b.last_algorithm(), algo);
    EXPECT_EQ(count_differences(gpu.ev1, cpu.ev1), 0u)
        << "ev1 GPU " << event_bin_algorithm_name(algo) << " vs CPU:" << first_differences(gpu.ev1, cpu.ev1, 2 * kBins);
    EXPECT_EQ(count_differences(gpu.ev2, cpu.ev2), 0u)
        << "ev2 GPU " << event_bin_algorithm_name(algo) << " vs CPU:" << first_differences(gpu.ev2, cpu.ev2, 2 * kBins);
    EXPECT_EQ(count_differences(gpu.ev3, cpu.ev3), 0u)
        << "ev3 GPU " << event_bin_algorithm_name(algo) << " vs CPU:" << first_differences(gpu.ev3, cpu.ev3, 2 * kBins);
  }
  return cpu;
}

HostTensor host_array(const std::vector<float>& v, int64_t n, int64_t c) {
  return HostTensor{Shape{n, c, kH, kW}, v};
}

std::vector<float> random_image(int64_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::vector<float> v(static_cast<size_t>(n) * 3 * kH * kW);
  for (auto& x : v) x = u(rng);
  return v;
}

// Runs the tiny golden model on both backends, S on every item and M (items 2k, 2k+1 = frames 1
// and 2), and checks every output: finite, and inside the range its last activation allows
// (E = tanh, sys = rs + E, flow = 100 tanh, m = hardsigmoid); fused/out only finite.
void expect_model_stable(const ModelInputs& in, const std::string& what) {
  const Weights w = load_weights(fixture("selfunroll_tiny.safetensors"));
  ASSERT_EQ(w.config.N, kBins);
  float rs_lo = 1e30f, rs_hi = -1e30f;
  for (float v : in.rs.data) rs_lo = std::min(rs_lo, v), rs_hi = std::max(rs_hi, v);
  CpuBackend cpu;
  VulkanBackend vk(vktest::context());
  for (Backend* backend : {static_cast<Backend*>(&cpu), static_cast<Backend*>(&vk)}) {
    Model model(*backend, w);
    for (Mode mode : {Mode::s, Mode::m}) {
      if (mode == Mode::m && in.rs.shape.n % 2) continue;
      RunOptions opt;
      opt.mode = mode;
      const auto res = model.run(in, opt);
      const std::string where = what + (backend == &cpu ? " cpu" : " vulkan") + (mode == Mode::s ? " S" : " M");
      EXPECT_EQ(res.size(), mode == Mode::s ? 5u : 7u) << where;
      for (const auto& [name, arr] : res) {
        ASSERT_EQ(static_cast<int64_t>(arr.data.size()), arr.shape.count()) << where << " " << name;
        size_t bad = 0;
        float lo = 1e30f, hi = -1e30f;
        for (float v : arr.data) {
          bad += !std::isfinite(v);
          lo = std::min(lo, v), hi = std::max(hi, v);
        }
        EXPECT_EQ(bad, 0u) << where << ": " << bad << " non-finite values in '" << name << "'";
        float want_lo = -INFINITY, want_hi = INFINITY;
        if (name == ModelOutput::E) want_lo = -1.f, want_hi = 1.f;
        if (name == ModelOutput::sys) want_lo = rs_lo - 1.f, want_hi = rs_hi + 1.f;
        if (name == ModelOutput::flow) want_lo = -100.f, want_hi = 100.f;
        if (name == ModelOutput::m) want_lo = 0.f, want_hi = 1.f;
        EXPECT_TRUE(lo >= want_lo && hi <= want_hi) << where << " " << name << " in [" << lo << ", " << hi << "]";
      }
    }
  }
}

ModelInputs model_inputs(const std::vector<float>& rs, const EventTensors& t) {
  const int64_t n = t.pairs;
  return {host_array(rs, n, 3), host_array(t.ev1, n, 2 * kBins), host_array(t.ev2, n, 2 * kBins),
          host_array(t.ev3, n, 2 * kBins)};
}

struct PhysicsOut {
  std::vector<float> cpu, gpu;
};

// The physics unroller of one frame at t*, CPU reference and GPU, on 3-channel planes.
PhysicsOut physics(const EventStream& es, const std::vector<double>& starts, const std::vector<double>& ends,
                   double t_star, const std::vector<float>& rs, const PhysicsUnrollParams& prm) {
  const PixelEventLists lists = gather_pixel_events(es, t_star, starts, ends, 0, 0, kW, kH);
  PhysicsOut o;
  o.cpu = physics_unroll_ref(rs, 3, lists, prm);
  Context& ctx = vktest::context();
  check_physics_image(rs, 3, lists);
  Tensor rs_t(ctx, {1, 3, kH, kW}), out_t(ctx, {1, 3, kH, kW});
  rs_t.upload(rs);
  PhysicsUnroll op(ctx, lists);
  CommandStream cs(ctx);
  op.record(cs, rs_t, out_t, prm);
  cs.submit_and_wait();
  o.gpu = out_t.download<float>();
  return o;
}
PhysicsOut physics(const EventStream& es, const RowTiming& tm, double t_star, const std::vector<float>& rs,
                   const PhysicsUnrollParams& prm) {
  std::vector<double> s(tm.rows), e(tm.rows);
  for (int y = 0; y < tm.rows; ++y) s[y] = tm.start(y).to_double(), e[y] = tm.end(y).to_double();
  return physics(es, s, e, t_star, rs, prm);
}

// Both results finite, in [0, max_value], and GPU within 1e-4 (relative above 1) of the CPU.
void expect_physics_stable(const PhysicsOut& o, const PhysicsUnrollParams& prm, const std::string& what) {
  ASSERT_EQ(o.cpu.size(), o.gpu.size());
  for (size_t i = 0; i < o.cpu.size(); ++i) {
    ASSERT_TRUE(std::isfinite(o.cpu[i]) && std::isfinite(o.gpu[i])) << what << " i=" << i;
    ASSERT_TRUE(o.cpu[i] >= 0.f && o.cpu[i] <= prm.max_value) << what << " cpu " << o.cpu[i] << " i=" << i;
    ASSERT_TRUE(o.gpu[i] >= 0.f && o.gpu[i] <= prm.max_value) << what << " gpu " << o.gpu[i] << " i=" << i;
    ASSERT_NEAR(o.gpu[i], o.cpu[i], 1e-4 * std::max(1.f, o.cpu[i])) << what << " i=" << i;
  }
}

EventStream random_stream(size_t n, int64_t t_begin, int64_t t_end, uint32_t seed) {
  std::mt19937_64 rng(seed);
  std::vector<int64_t> t(n);
  for (auto& v : t) v = t_begin + static_cast<int64_t>(rng() % static_cast<uint64_t>(t_end - t_begin));
  std::sort(t.begin(), t.end());
  EventStream es;
  es.width = kW;
  es.height = kH;
  for (size_t i = 0; i < n; ++i)
    es.push(t[i], static_cast<uint16_t>(rng() % kW), static_cast<uint16_t>(rng() % kH), (rng() & 1) ? 1 : -1);
  return es;
}

size_t pixel(int c, int y, int x) { return (static_cast<size_t>(c) * kH + y) * kW + x; }


}  // namespace

// ---- 1. no events at all --------------------------------------------------------------------

TEST(HardCases, NoEventsAtAll) {
  EventStream none;
  none.width = kW;
  none.height = kH;
  const RowTiming f1 = timing(1000, 10, 500), f2 = timing(2000, 10, 500);
  const Rational t_star = f1.target_time(Rational(1, 2));
  const EventTensors t = build_checked(none, {pair_at(f1, t_star), pair_at(f2, t_star)});
  EXPECT_EQ(sum(t.ev1) + sum(t.ev2) + sum(t.ev3), 0.0);
  EXPECT_EQ(t.events_considered, 0u);

  const auto rs = random_image(2, 1);
  expect_model_stable(model_inputs(rs, t), "no events");

  // Physics: with no event the brightness is constant, so I(t*) = I_rs (gamma 1 and 2.2).
  const std::vector<float> rs1(rs.begin(), rs.begin() + 3 * kH * kW);
  for (float gamma : {1.0f, 2.2f}) {
    PhysicsUnrollParams prm;
    prm.gamma = gamma;
    const PhysicsOut o = physics(none, f1, t_star.to_double(), rs1, prm);
    for (size_t i = 0; i < rs1.size(); ++i) {
      ASSERT_NEAR(o.cpu[i], rs1[i], 1e-6) << "gamma " << gamma << " i=" << i;
      ASSERT_NEAR(o.gpu[i], rs1[i], 1e-5) << "gamma " << gamma << " i=" << i;
    }
  }
}

// ---- 2. millions of events in one pixel ----------------------------------------------------

TEST(HardCases, MillionsOfEventsInOnePixel) {
  // Pixel (5, 7): 1,000,000 OFF events at t = 100 us and 3,000,000 ON events at t = 1500 us (one
  // cell gets 3e6, far beyond fp16's 65504), over a light random background elsewhere.
  constexpr int px = 5, py = 7;
  constexpr size_t kOff = 1'000'000, kOn = 3'000'000;
  const EventStream bg = random_stream(3000, -2000, 6000, 2);
  EventStream es;
  es.width = kW;
  es.height = kH;
  es.reserve(kOff + kOn + bg.size());
  auto push_bg_until = [&](size_t& i, int64_t t) {
    for (; i < bg.size() && bg.t[i] < t; ++i)
      if (!(bg.x[i] == px && bg.y[i] == py)) es.push(bg.t[i], bg.x[i], bg.y[i], bg.p[i]);
  };
  size_t i = 0;
  push_bg_until(i, 100);
  for (size_t k = 0; k < kOff; ++k) es.push(100, px, py, -1);
  push_bg_until(i, 1500);
  for (size_t k = 0; k < kOn; ++k) es.push(1500, px, py, 1);
  push_bg_until(i, INT64_MAX);

  // Frame 1: t0 = 0, delay 10, exposure 1000 (row 7: [70, 1070]); frame 2 one period later.
  const RowTiming f1 = timing(0, 10, 1000), f2 = timing(1190, 10, 1000);
  const Rational t_mid = f1.target_time(Rational(1, 2));  // 595
  const EventTensors t = build_checked(es, {pair_at(f1, t_mid), pair_at(f2, t_mid)}, true, /*per_pixel_refuses=*/true);
  const size_t slice = t.slice();
  // ev1 (t* -> start, backward): the OFF events, sign flipped, bin floor(495 * 4 / 525) = 3 -> channel 7.
  EXPECT_EQ(t.ev1[pixel(7, py, px)], static_cast<float>(kOff));
  // ev3 [595, 1595): the ON events, bin floor(905 * 4 / 1000) = 3 -> channel 7.
  EXPECT_EQ(t.ev3[pixel(7, py, px)], static_cast<float>(kOn));
  // Frame 2's ev1 [595, start = 1260): the ON events are not in it; ev2 [595, 2260): they are.
  EXPECT_EQ(t.ev1[slice + pixel(7, py, px)], 0.f);
  EXPECT_EQ(t.ev2[slice + pixel(2 * int(std::floor(905.0 * 4 / 1665)) + 1, py, px)], static_cast<float>(kOn));

  const auto rs = random_image(2, 3);
  expect_model_stable(model_inputs(rs, t), "4M events in one pixel");

  // Physics (row 7's exposure [70, 1070]). At t* = 595 the 1e6 OFF events at 100 make the 30 us
  // before them e^(0.2 * 1e6) brighter than t*: I(t*) underflows to 0, finite. At t* = t0 + 3T =
  // 3570 both bursts lie before t*, the net +2e6 after the whole exposure makes every exposure
  // segment e^(-0.2 * 2e6) or darker than t*: I(t*) = I_rs * e^(4e5), capped at max_value.
  // The GPU kernel refuses a pixel with more than PhysicsUnroll::kMaxPixelEvents (lavapipe's loop
  // limit), naming it; `vkunroll unroll` then uses the CPU reference for that target.
  const std::vector<float> rs1(rs.begin(), rs.begin() + 3 * kH * kW);
  PhysicsUnrollParams prm;
  std::vector<double> s(kH), e(kH);
  for (int y = 0; y < kH; ++y) s[y] = f1.start(y).to_double(), e[y] = f1.end(y).to_double();
  const PixelEventLists mid = gather_pixel_events(es, 595, s, e, 0, 0, kW, kH);
  EXPECT_FALSE(PhysicsUnroll::fits(mid));
  const std::string msg = error_of([&] { PhysicsUnroll(vktest::context(), mid); });
  EXPECT_NE(msg.find("pixel (x=5, y=7) has 1000000 events"), std::string::npos) << msg;
  const auto mid_out = physics_unroll_ref(rs1, 3, mid, prm);
  expect_physics_stable({mid_out, mid_out}, prm, "t*=595");
  EXPECT_LE(mid_out[pixel(0, py, px)], 1e-30f);
  const Rational t_late = f1.t0 + Rational(3) * (f1.last_end() - f1.t0);
  ASSERT_EQ(t_late, Rational(3570));
  const auto late = physics_unroll_ref(rs1, 3, gather_pixel_events(es, 3570, s, e, 0, 0, kW, kH), prm);
  expect_physics_stable({late, late}, prm, "t*=3570");
  for (int c = 0; c < 3; ++c) EXPECT_EQ(late[pixel(c, py, px)], prm.max_value);
  // The tensors for t* = 3570 are exact too (ev1 backward over [70, 3570): both bursts).
  const EventTensors tl = build_checked(es, {pair_at(f1, t_late)}, true, /*per_pixel_refuses=*/true);
  EXPECT_EQ(tl.ev1[pixel(7, py, px)], static_cast<float>(kOff));  // bin floor(3470*4/3500) = 3, flipped to ON
  EXPECT_EQ(tl.ev1[pixel(4, py, px)], static_cast<float>(kOn));   // bin floor(2070*4/3500) = 2, flipped to OFF
}

// 20000 events in one pixel selected by four jobs of a chunk: the per-pixel kernel would loop
// 4 x 20000 times in one invocation (beyond lavapipe's 65535), so it splits the jobs over dispatches;
// every algorithm still equals the CPU reference and the hand count.
TEST(HardCases, BusyPixelWithManyJobsStaysExact) {
  const EventStream bg = random_stream(2000, 0, 2000, 17);
  EventStream es;
  es.width = kW, es.height = kH;
  size_t i = 0;
  for (int k = 0; k < 20000; ++k) {
    const int64_t t = 500 + k / 20;  // 20 events per microsecond over [500, 1500)
    for (; i < bg.size() && bg.t[i] <= t; ++i)
      if (!(bg.x[i] == 9 && bg.y[i] == 11)) es.push(bg.t[i], bg.x[i], bg.y[i], bg.p[i]);
    es.push(t, 9, 11, (k % 3) ? 1 : -1);
  }
  for (; i < bg.size(); ++i)
    if (!(bg.x[i] == 9 && bg.y[i] == 11)) es.push(bg.t[i], bg.x[i], bg.y[i], bg.p[i]);
  // t* = 100, before the burst: ev2 and ev3 of each pair select all 20000 events; the builder
  // bins ev2 of the four pairs together (one chunk): 4 x 20000 loop iterations for that pixel.
  const EventTensors t = build_checked(
      es, {pair_at(timing(0, 10, 3000), Rational(100)), pair_at(timing(5, 10, 3000), Rational(100)),
           pair_at(timing(10, 10, 3000), Rational(100)), pair_at(timing(15, 10, 3000), Rational(100))});
  for (const auto* v : {&t.ev2, &t.ev3})
    for (int p = 0; p < 4; ++p) {
      double at_pixel = 0;
      for (int c = 0; c < 2 * kBins; ++c) at_pixel += (*v)[p * t.slice() + pixel(c, 11, 9)];
      EXPECT_EQ(at_pixel, 20000.0) << "pair " << p;
    }
}

// The GPU physics kernel at its per-pixel limit equals the CPU reference (on lavapipe a pixel
// beyond ~32000 events came out wrong without an error before the limit existed).
TEST(HardCases, PhysicsGpuAtItsPerPixelEventLimit) {
  EventStream es = random_stream(4000, 0, 1200, 14);
  {
    // Pixel (3, 4): kMaxPixelEvents events spread over [100, 1100), polarities mostly balanced.
    std::mt19937 rng(15);
    EventStream burst;
    burst.width = kW, burst.height = kH;
    for (uint32_t k = 0; k < PhysicsUnroll::kMaxPixelEvents; ++k)
      burst.push(100 + static_cast<int64_t>(k) * 1000 / PhysicsUnroll::kMaxPixelEvents, 3, 4, (rng() % 100) < 51 ? 1 : -1);
    EventStream merged;
    merged.width = kW, merged.height = kH;
    size_t i = 0, j = 0;
    while (i < es.size() || j < burst.size()) {
      const bool take_es = j >= burst.size() || (i < es.size() && es.t[i] <= burst.t[j]);
      if (take_es && es.x[i] == 3 && es.y[i] == 4) { ++i; continue; }
      if (take_es) merged.push(es.t[i], es.x[i], es.y[i], es.p[i]), ++i;
      else merged.push(burst.t[j], burst.x[j], burst.y[j], burst.p[j]), ++j;
    }
    es = std::move(merged);
  }
  std::vector<double> s(kH), e(kH);
  for (int y = 0; y < kH; ++y) s[y] = 0, e[y] = 1200;  // every row's exposure holds the whole burst
  const PixelEventLists lists = gather_pixel_events(es, 600, s, e, 0, 0, kW, kH);
  ASSERT_EQ(lists.offsets[4 * kW + 4] - lists.offsets[4 * kW + 3], PhysicsUnroll::kMaxPixelEvents);
  EXPECT_TRUE(PhysicsUnroll::fits(lists));
  PhysicsUnrollParams prm;
  prm.contrast = 0.01f;  // keeps the burst's pixel well inside (0, max_value), so a wrong loop shows
  const auto rs = random_image(1, 16);
  const PhysicsOut o = physics(es, s, e, 600, rs, prm);
  expect_physics_stable(o, prm, "pixel at the GPU limit");
  EXPECT_GT(std::fabs(o.cpu[pixel(0, 4, 3)] - rs[pixel(0, 4, 3)]), 1e-3);  // the burst does change it
}

// float32 counts are exact only up to 2^24: a pixel with more events in the window is refused
// with a clear error by the CPU reference and the GPU builder instead of saturating silently.
TEST(HardCases, MoreThan2To24EventsInOnePixelIsAClearError) {
  const size_t n = (size_t{1} << 24) + 1;
  EventStream es;
  es.width = kW;
  es.height = kH;
  es.t.assign(n, 600);
  es.x.assign(n, 3);
  es.y.assign(n, 2);
  es.p.assign(n, 1);
  const std::vector<EventTensorPair> pairs = {pair_at(timing(0, 10, 1000), Rational(595))};
  EventTensorSpec spec;
  spec.bins = kBins;
  for (const std::string& msg : {error_of([&] { build_event_tensors_ref(es, pairs, spec); }),
                                error_of([&] { EventTensorBuilder(vktest::context()).build(es, pairs, spec); })}) {
    EXPECT_NE(msg.find("pixel (x=3, y=2)"), std::string::npos) << msg;
    EXPECT_NE(msg.find("2^24"), std::string::npos) << msg;
  }
  // One event fewer in the window is accepted (the guard is not off by one): drop one event.
  es.t.back() = 5000;  // outside every window of the pair
  EXPECT_NO_THROW(plan_binning(es, event_tensor_jobs(pairs), spec));
}

// ---- 3. targets far outside the exposure ---------------------------------------------------

TEST(HardCases, TargetsFarOutsideTheExposure) {
  // Frame: t0 = 10000, delay 10, exposure 500: T = 19 * 10 + 500 = 690 us.
  const RowTiming f1 = timing(10000, 10, 500), f2 = timing(10690, 10, 500);
  const int64_t T = 690;
  ASSERT_EQ(f1.last_end() - f1.t0, Rational(T));
  const EventStream es = random_stream(30000, 10000 - 2 * T, 10000 + 5 * T, 4);
  for (int64_t t_star : {10000 - T, 10000 + 3 * T}) {
    const EventTensors t = build_checked(es, {pair_at(f1, t_star), pair_at(f2, t_star)});
    // Not vacuous: every tensor of both pairs sees events.
    for (const auto* v : {&t.ev1, &t.ev2, &t.ev3})
      for (int p = 0; p < 2; ++p)
        EXPECT_GT(std::accumulate(v->begin() + p * t.slice(), v->begin() + (p + 1) * t.slice(), 0.0), 100.0)
            << "t*=" << t_star << " pair " << p;
    // ev3 covers [t*, t* + 500): every event of that window counts once, at some cell.
    const auto in_ev3 = std::count_if(es.t.begin(), es.t.end(), [&](int64_t v) { return v >= t_star && v < t_star + 500; });
    EXPECT_EQ(std::accumulate(t.ev3.begin(), t.ev3.begin() + t.slice(), 0.0), static_cast<double>(in_ev3));
    expect_model_stable(model_inputs(random_image(2, 5), t), "t*=" + std::to_string(t_star));
    const auto rs = random_image(1, 6);
    for (float gamma : {1.0f, 2.2f}) {
      PhysicsUnrollParams prm;
      prm.gamma = gamma;
      expect_physics_stable(physics(es, f1, static_cast<double>(t_star), rs, prm), prm,
                            "t*=" + std::to_string(t_star) + " gamma " + std::to_string(gamma));
    }
  }
  // Fractional line delay and bottom-up readout, targets at tau = -1 and 4: CPU == GPU (the hand
  // count in double is not exact for 1000/7, see docs/event_tensors.md).
  const RowTiming fr = timing(10000, Rational(1000, 7), 500, kH, Readout::bottom_up);
  const EventStream wide = random_stream(30000, 10000 - 4000, 10000 + 15000, 5);
  build_checked(wide, {pair_at(fr, fr.target_time(Rational(-1))), pair_at(fr, fr.target_time(Rational(4)))},
                /*hand=*/false);
}

// ---- 4. zero-length segments ---------------------------------------------------------------

TEST(HardCases, ZeroLengthSegments) {
  const EventStream es = random_stream(20000, 0, 3000, 7);
  EventTensorSpec spec;
  spec.bins = kBins;
  // a == b on even rows (select nothing), [300, 700) on odd rows.
  RowIntervals job;
  for (int y = 0; y < kH; ++y) {
    job.a.push_back(Rational(y % 2 ? 300 : 500));
    job.b.push_back(Rational(y % 2 ? 700 : 500));
  }
  const auto cpu = bin_events_ref(es, {job}, spec);
  EXPECT_EQ(count_differences(cpu, hand_count(es, job, kBins)), 0u);
  for (auto algo : {EventBinAlgorithm::per_row, EventBinAlgorithm::per_event, EventBinAlgorithm::per_pixel}) {
    EventTensorBuilder b(vktest::context());
    b.set_algorithm(algo);
    EXPECT_EQ(count_differences(b.bin(es, {job}, spec), cpu), 0u) << event_bin_algorithm_name(algo);
  }
  double even = 0, odd = 0;
  for (int c = 0; c < 2 * kBins; ++c)
    for (int y = 0; y < kH; ++y)
      for (int x = 0; x < kW; ++x) (y % 2 ? odd : even) += cpu[pixel(c, y, x)];
  EXPECT_EQ(even, 0.0);
  EXPECT_GT(odd, 1000.0);

  // Target exposure 0: ev3 is empty, ev1 and ev2 are not.
  const RowTiming f = timing(0, 10, 1000);
  const EventTensors t0 = build_checked(es, {pair_at(f, Rational(800), Rational(0))});
  EXPECT_EQ(sum(t0.ev3), 0.0);
  EXPECT_GT(sum(t0.ev1), 0.0);
  EXPECT_GT(sum(t0.ev2), 0.0);

  // Line delay 0 (a global-shutter input): every row has the same interval; at tau = 0 ev1 is
  // empty (t* = start), at tau = 1 ev2 is empty (t* = end).
  const RowTiming gs = timing(500, 0, 1000), gs2 = timing(1500, 0, 1000);
  const EventTensors g = build_checked(es, {pair_at(gs, gs.target_time(Rational(0))),
                                            pair_at(gs2, gs.target_time(Rational(0)))});
  EXPECT_EQ(std::accumulate(g.ev1.begin(), g.ev1.begin() + g.slice(), 0.0), 0.0);
  EXPECT_GT(sum(g.ev2), 0.0);
  const EventTensors g1 = build_checked(es, {pair_at(gs, gs.target_time(Rational(1)))});
  EXPECT_EQ(sum(g1.ev2), 0.0);
  EXPECT_GT(sum(g1.ev1), 0.0);
  expect_model_stable(model_inputs(random_image(2, 8), g), "global shutter, tau 0");

  // Exposure 0: RowTiming refuses it with an error naming the exposure.
  const std::string msg = error_of([&] { event_tensor_jobs({pair_at(timing(0, 10, 0), Rational(10))}); });
  EXPECT_NE(msg.find("exposure must be > 0 us, got 0"), std::string::npos) << msg;
  EXPECT_NE(error_of([&] { EventTensorBuilder(vktest::context()).build(es, {pair_at(timing(0, 10, 0), Rational(10))}, spec); })
                .find("exposure must be > 0"),
            std::string::npos);

  // The physics unroller takes raw row times: an empty exposure (S == E) returns the RS image,
  // events or not (log_ratio is 0 by definition, no 0/0).
  std::vector<double> starts(kH);
  for (int y = 0; y < kH; ++y) starts[y] = 200.0 + 10 * y;
  const auto rs = random_image(1, 9);
  PhysicsUnrollParams prm;
  const PhysicsOut o = physics(es, starts, starts, 250.0, rs, prm);
  for (size_t i = 0; i < rs.size(); ++i) {
    ASSERT_NEAR(o.cpu[i], rs[i], 1e-6) << i;
    ASSERT_NEAR(o.gpu[i], rs[i], 1e-5) << i;
  }
}

// ---- 5. black and saturated pixels -----------------------------------------------------------

TEST(HardCases, BlackAndSaturatedPixels) {
  // Columns 0-7 black (0), 8-15 saturated (1.0 = 255/255), 16-23 mid grey; events everywhere
  // except column 15 (to check a saturated pixel without events stays exactly saturated).
  EventStream es = random_stream(20000, -1000, 3000, 10);
  {
    EventStream kept;
    kept.width = kW, kept.height = kH;
    for (size_t i = 0; i < es.size(); ++i)
      if (es.x[i] != 15) kept.push(es.t[i], es.x[i], es.y[i], es.p[i]);
    es = std::move(kept);
  }
  std::vector<float> rs(3 * kH * kW);
  for (int c = 0; c < 3; ++c)
    for (int y = 0; y < kH; ++y)
      for (int x = 0; x < kW; ++x) rs[pixel(c, y, x)] = x < 8 ? 0.f : x < 16 ? 255.f / 255.f : 0.5f;
  const RowTiming f = timing(0, 10, 1000);
  for (double t_star : {-500.0, 595.0, 2500.0})
    for (float gamma : {1.0f, 2.2f}) {
      PhysicsUnrollParams prm;
      prm.gamma = gamma;
      const std::string what = "t*=" + std::to_string(t_star) + " gamma " + std::to_string(gamma);
      const PhysicsOut o = physics(es, f, t_star, rs, prm);
      expect_physics_stable(o, prm, what);
      // What the writers store: to_unit_float (host/unroll/metrics.hpp) clamps to [0, 1].
      for (const auto* v : {&o.cpu, &o.gpu}) {
        cv::Mat unit = to_unit_float(cv::Mat(1, static_cast<int>(v->size()), CV_32F, const_cast<float*>(v->data())));
        double lo = 0, hi = 0;
        cv::minMaxLoc(unit, &lo, &hi);
        ASSERT_TRUE(lo >= 0 && hi <= 1 && cv::checkRange(unit)) << what;
      }
      for (int c = 0; c < 3; ++c)
        for (int y = 0; y < kH; ++y) {
          for (int x = 0; x < 8; ++x) {
            ASSERT_EQ(o.cpu[pixel(c, y, x)], 0.f) << what;  // black stays black: no log(0)
            ASSERT_EQ(o.gpu[pixel(c, y, x)], 0.f) << what;
          }
          ASSERT_NEAR(o.cpu[pixel(c, y, 15)], 1.f, 1e-6) << what;
          ASSERT_NEAR(o.gpu[pixel(c, y, 15)], 1.f, 1e-5) << what;
        }
    }
  // The model: all black, all saturated, and the striped image; outputs finite and in range.
  EventTensors t = build_checked(es, {pair_at(f, Rational(595)), pair_at(timing(1190, 10, 1000), Rational(595))});
  std::vector<float> two(rs);
  two.insert(two.end(), rs.begin(), rs.end());
  expect_model_stable(model_inputs(two, t), "striped black/saturated");
  expect_model_stable(model_inputs(std::vector<float>(two.size(), 0.f), t), "all black");
  expect_model_stable(model_inputs(std::vector<float>(two.size(), 1.f), t), "all saturated");
}

// ---- 6. NaN / Inf inputs ---------------------------------------------------------------------

TEST(HardCases, NonFiniteModelInputsAreNamedErrors) {
  const Weights w = load_weights(fixture("selfunroll_tiny.safetensors"));
  const ModelInputs good = random_inputs(2, kH, kW, kBins, 11);
  CpuBackend cpu;
  VulkanBackend vk(vktest::context());
  for (Backend* backend : {static_cast<Backend*>(&cpu), static_cast<Backend*>(&vk)}) {
    Model model(*backend, w);
    {
      ModelInputs in = good;
      in.rs.data[((1 * 3 + 2) * kH + 3) * kW + 4] = NAN;
      const std::string msg = error_of([&] { model.run(in, {}); });
      EXPECT_NE(msg.find("'rs' holds NaN at (batch 1, channel 2, y 3, x 4)"), std::string::npos) << msg;
    }
    {
      ModelInputs in = good;
      in.ev2.data[((0 * 2 * kBins + 5) * kH + 6) * kW + 7] = INFINITY;
      in.ev2.data[((1 * 2 * kBins + 0) * kH + 0) * kW + 0] = NAN;  // later: the first is named
      const std::string msg = error_of([&] { model.run(in, {}); });
      EXPECT_NE(msg.find("'ev2' holds an infinite value at (batch 0, channel 5, y 6, x 7)"), std::string::npos) << msg;
    }
    {
      ModelInputs in = good;
      in.ev3.data.back() = -INFINITY;
      const std::string msg = error_of([&] { model.run(in, {.mode = Mode::m}); });
      EXPECT_NE(msg.find("'ev3' holds an infinite value at (batch 1, channel 7, y 19, x 23)"), std::string::npos) << msg;
    }
    // The same inputs, made finite again, run.
    EXPECT_NO_THROW(model.run(good, {}));
  }
}

TEST(HardCases, NonFinitePhysicsInputsAreNamedErrors) {
  const EventStream es = random_stream(2000, 0, 2000, 12);
  std::vector<double> s(kH), e(kH);
  for (int y = 0; y < kH; ++y) s[y] = 10.0 * y, e[y] = 10.0 * y + 1000;
  const PixelEventLists lists = gather_pixel_events(es, 500, s, e, 0, 0, kW, kH);
  std::vector<float> rs = random_image(1, 13);
  rs[pixel(1, 2, 3)] = NAN;
  const std::string msg = error_of([&] { physics_unroll_ref(rs, 3, lists, {}); });
  EXPECT_NE(msg.find("'rs' holds NaN at (channel 1, y 2, x 3)"), std::string::npos) << msg;
  rs[pixel(1, 2, 3)] = 0.5f;
  rs[pixel(2, 19, 0)] = INFINITY;
  EXPECT_NE(error_of([&] { check_physics_image(rs, 3, lists); }).find("'rs' holds an infinite value at (channel 2, y 19, x 0)"),
            std::string::npos);
  // A non-finite target or row time is refused by the gather step.
  EXPECT_NE(error_of([&] { gather_pixel_events(es, NAN, s, e, 0, 0, kW, kH); }).find("t* is not finite"), std::string::npos);
  e[4] = INFINITY;
  EXPECT_NE(error_of([&] { gather_pixel_events(es, 500, s, e, 0, 0, kW, kH); }).find("row 4"), std::string::npos);
  // NaN/Inf event times in files: rejected by the readers (tests/test_event_readers.cpp, "NaN").
}

// ---- 7. fp16 on the CPU backend is refused ------------------------------------------------------

TEST(HardCases, Fp16IsRefusedNamingTheOption) {
  // `vkunroll unroll`: refused before the sequence is even read.
  UnrollOptions o;
  o.sequence = "/nonexistent/sequence";
  o.out_dir = "/nonexistent/out";
  o.session.precision = Precision::fp16;
  o.session.backend = BackendKind::cpu;  // fp16 runs on the Vulkan backend only
  const std::string msg = error_of([&] { run_unroll(o); });
  EXPECT_NE(msg.find("precision fp16 needs backend vulkan"), std::string::npos) << msg;  // the library names fields

  // `vkunroll infer --backend cpu`: refused with the same words, a usage error, nothing written.
  const auto dir = std::filesystem::temp_directory_path() / ("vkunroll_hard_fp16_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string log = (dir / "log.txt").string(), out = (dir / "out.safetensors").string();
  const std::string cmd = std::string(VKUNROLL_CLI_PATH) + " infer --model " + fixture("selfunroll_tiny.safetensors") +
                          " --inputs " + fixture("selfunroll_golden_s_64x48.safetensors") + " --out " + out +
                          " --backend cpu --precision fp16 > " + log + " 2>&1";
  const int rc = std::system(cmd.c_str());
  EXPECT_NE(rc, 0);
  std::string text;
  if (FILE* f = std::fopen(log.c_str(), "r")) {
    char buf[4096];
    size_t n;
    while ((n = std::fread(buf, 1, sizeof buf, f)) > 0) text.append(buf, n);
    std::fclose(f);
  }
  EXPECT_NE(text.find("--precision fp16 needs --backend vulkan"), std::string::npos) << text;
  EXPECT_FALSE(std::filesystem::exists(out));
  std::filesystem::remove_all(dir);
}
