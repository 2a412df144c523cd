// The physics contrast estimate on noisy sensors: seeded sequences with the realistic preset's
// event noise (mismatch, refractory period, leak, shot noise, photoreceptor filter, frame noise),
// then more background activity and hot pixels on top; the estimate stays within 0.02 of the
// simulator's threshold, and the noise alone is no evidence.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <numeric>
#include <random>

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/sim/recording.hpp"
#include "vkunroll/host/unroll/unroll_plan.hpp"

using namespace vkunroll;

namespace {

struct Noisy {
  sim::SimulationConfig cfg;
  sim::SimulatedSequence seq;
  std::vector<RowTiming> timings;
  std::vector<cv::Mat> frames;  // BGR float32 in [0, 1], as the PNGs decode
};

// The simulated sequence of `cfg` with its row timings and its frames as the 8-bit PNGs decode.
Noisy simulate_sequence(const sim::SimulationConfig& cfg) {
  Noisy n;
  n.cfg = cfg;
  n.seq = sim::simulate(cfg);
  for (size_t k = 0; k < n.seq.rs.size(); ++k) {
    RowTiming t;
    t.t0 = Rational::from_double(n.seq.frame_t0_us[k]);
    t.line_delay = Rational::from_double(cfg.line_delay_us);
    t.exposure = Rational::from_double(cfg.exposure_us);
    t.rows = cfg.height;
    n.timings.push_back(t);
    cv::Mat f;
    sim::encode_image(n.seq.rs[k], cfg.gamma, 8, true).convertTo(f, CV_32FC3, 1.0 / 255);
    n.frames.push_back(f);
  }
  return n;
}

Noisy simulate_noisy(double c, uint64_t seed) {
  sim::SimulationConfig cfg = sim::simulation_preset("realistic");
  cfg.seed = seed;
  cfg.frames = 4;
  cfg.events.c_on = cfg.events.c_off = c;
  return simulate_sequence(cfg);
}

// Background activity (random pixels, times and polarities at `ba_hz` per pixel) and `hot` pixels
// firing ON at 2 kHz, merged into the stream in time order.
EventStream add_noise(const EventStream& in, double ba_hz, int hot, uint64_t seed) {
  std::mt19937_64 rng(seed);
  const int64_t t0 = in.t.front(), t1 = in.t.back();
  const double span_s = double(t1 - t0) * 1e-6;
  std::vector<std::array<int64_t, 4>> ev;
  for (size_t i = 0; i < in.size(); ++i) ev.push_back({in.t[i], in.x[i], in.y[i], in.p[i]});
  std::uniform_int_distribution<int64_t> t(t0, t1);
  std::uniform_int_distribution<int> x(0, in.width - 1), y(0, in.height - 1), p(0, 1);
  const auto ba = static_cast<size_t>(ba_hz * span_s * in.width * in.height);
  for (size_t i = 0; i < ba; ++i) ev.push_back({t(rng), x(rng), y(rng), p(rng) ? 1 : -1});
  for (int h = 0; h < hot; ++h) {
    const int hx = x(rng), hy = y(rng);
    for (int64_t ts = t0; ts < t1; ts += 500) ev.push_back({ts, hx, hy, 1});
  }
  std::stable_sort(ev.begin(), ev.end(), [](const auto& a, const auto& b) { return a[0] < b[0]; });
  EventStream out;
  out.width = in.width, out.height = in.height;
  for (const auto& e : ev) out.push(e[0], uint16_t(e[1]), uint16_t(e[2]), int8_t(e[3]));
  return out;
}

ContrastEstimate estimate(const Noisy& n, const EventStream& events) {
  auto window = [&](double lo, double hi) {
    EventStream out;
    out.width = events.width, out.height = events.height;
    const auto a = std::lower_bound(events.t.begin(), events.t.end(), int64_t(std::floor(lo)));
    const auto b = std::upper_bound(events.t.begin(), events.t.end(), int64_t(std::ceil(hi)));
    for (auto i = size_t(a - events.t.begin()); i < size_t(b - events.t.begin()); ++i)
      out.push(events.t[i], events.x[i], events.y[i], events.p[i]);
    return out;
  };
  return estimate_contrast(n.timings, {0, 1, 2}, n.cfg.gamma, n.cfg.width, n.cfg.height,
                           [&](int k) { return n.frames[size_t(k)]; }, window);
}

}  // namespace

TEST(ContrastEstimate, WithinTwoHundredthsOnNoisySensors) {
  for (double c : {0.2, 0.35}) {
    const Noisy n = simulate_noisy(c, 7);
    ASSERT_GT(n.seq.event_stats.shot, 0u) << "the preset's shot noise is on";
    const ContrastEstimate plain = estimate(n, n.seq.events);
    EXPECT_FALSE(plain.is_default) << plain.source;
    EXPECT_NEAR(plain.contrast, c, 0.02) << plain.source;
    EXPECT_TRUE(plain.warning.empty()) << plain.warning;
    // Ten times the preset's shot noise as background activity, and 50 hot pixels.
    const ContrastEstimate noisy = estimate(n, add_noise(n.seq.events, 5.0, 50, 99));
    EXPECT_NEAR(noisy.contrast, c, 0.02) << noisy.source;
    EXPECT_GE(noisy.pixels, 1000u) << noisy.source;
    std::printf("c %.2f: estimate %.4f (log offset %g, %zu pixels); with more noise %.4f (%zu pixels)\n", c, plain.contrast,
                plain.log_offset, plain.pixels, noisy.contrast, noisy.pixels);
  }
}

// The log offset is fitted on a grid; where its largest candidate binds (a sensor whose dark offset
// is larger), the run says that the contrast is the grid's, not the data's. Where it does not, silence.
TEST(ContrastEstimate, WarnsWhenTheLargestLogOffsetBindsTheFit) {
  for (double eps : {0.01, 0.3}) {
    sim::SimulationConfig cfg = sim::simulation_preset("clean");
    cfg.seed = 5;
    cfg.frames = 4;
    cfg.events.eps = eps;
    const Noisy n = simulate_sequence(cfg);
    const ContrastEstimate e = estimate(n, n.seq.events);
    ASSERT_FALSE(e.is_default) << e.source;
    const bool warned = e.warning.find("largest candidate (0.05)") != std::string::npos;
    std::printf("true log offset %g: fitted %g, c %.4f; %s\n", eps, e.log_offset, e.contrast, e.warning.c_str());
    if (eps > 0.05) {
      EXPECT_EQ(e.log_offset, 0.05);
      EXPECT_TRUE(warned) << e.warning;
      EXPECT_NE(e.warning.find("bounded by the offset grid"), std::string::npos) << e.warning;
    } else {
      EXPECT_LT(e.log_offset, 0.05);
      EXPECT_FALSE(warned) << e.warning;
    }
  }
}

TEST(ContrastEstimate, NoiseAloneIsNoEvidence) {
  sim::SimulationConfig cfg = sim::simulation_preset("clean");
  cfg.seed = 3;
  cfg.frames = 3;
  cfg.width = 160, cfg.height = 120;
  cfg.motion = sim::MotionKind::Static;
  cfg.sprites = 0;
  const Noisy n = simulate_sequence(cfg);
  // A still scene: only background activity and hot pixels fire, and nothing in the frames moves.
  EventStream seed_stream;
  seed_stream.width = cfg.width, seed_stream.height = cfg.height;
  seed_stream.push(0, 0, 0, 1);
  seed_stream.push(int64_t(n.seq.frame_t0_us.back() + 60000), 0, 0, -1);
  const ContrastEstimate e = estimate(n, add_noise(seed_stream, 20.0, 30, 5));
  EXPECT_TRUE(e.is_default) << e.source;
  EXPECT_EQ(e.contrast, 0.2);
  EXPECT_NE(e.warning.find("too few pixels"), std::string::npos) << e.warning;
}

// The noise measures behind `--gate-radius auto`: a clean static scene with movers reads clean, the
// realistic preset (and it with more background activity and hot pixels) noisy; the choice follows.
TEST(ContrastEstimate, NoiseMeasuresTellACleanRecordingFromANoisyOne) {
  auto plan_of = [](const ContrastEstimate& e) {
    PhysicsPlan p;
    p.frame_noise = e.frame_noise;
    p.isolated_event_fraction = e.isolated_event_fraction;
    return p;
  };
  sim::SimulationConfig cfg = sim::simulation_preset("clean");
  cfg.seed = 11;
  cfg.frames = 4;
  cfg.motion = sim::MotionKind::Static;
  const Noisy clean = simulate_sequence(cfg);
  ASSERT_GT(clean.seq.events.size(), 1000u) << "the movers fire";
  const ContrastEstimate c = estimate(clean, clean.seq.events);
  const Noisy realistic = simulate_noisy(0.25, 7);
  const ContrastEstimate r = estimate(realistic, realistic.seq.events);
  const ContrastEstimate more = estimate(realistic, add_noise(realistic.seq.events, 5.0, 50, 99));
  std::printf("frame noise / isolated events: clean %.4f / %.3f, realistic %.4f / %.3f, more noise %.4f / %.3f\n",
              c.frame_noise, c.isolated_event_fraction, r.frame_noise, r.isolated_event_fraction, more.frame_noise,
              more.isolated_event_fraction);
  EXPECT_GE(c.frame_noise, 0.0);
  EXPECT_LT(c.frame_noise, kCleanFrameNoise);
  EXPECT_GE(c.isolated_event_fraction, 0.0);
  EXPECT_LT(c.isolated_event_fraction, kCleanIsolatedEvents);
  EXPECT_TRUE(r.frame_noise >= kCleanFrameNoise || r.isolated_event_fraction >= kCleanIsolatedEvents);
  // Dense background activity is no longer isolated (a neighbour fires too): the frame noise tells.
  EXPECT_TRUE(more.frame_noise >= kCleanFrameNoise || more.isolated_event_fraction >= kCleanIsolatedEvents);
  const GateRadiusOption automatic;
  EXPECT_EQ(choose_gate_radius(automatic, 1, plan_of(c)).radius, 1);
  EXPECT_EQ(choose_gate_radius(automatic, 1, plan_of(r)).radius, kNoisyGateRadius);
  EXPECT_EQ(choose_gate_radius(automatic, 3, plan_of(more)).radius, 3) << "never below the model's own";
  const GateChoice noisy = choose_gate_radius(automatic, 1, plan_of(more));
  EXPECT_NE(noisy.source.find("noisy recording"), std::string::npos) << noisy.source;
}

TEST(ContrastEstimate, GateRadiusOptionIsParsedAndApplied) {
  EXPECT_EQ(parse_gate_radius("auto", "gate_radius").kind, GateRadiusOption::Kind::automatic);
  EXPECT_EQ(parse_gate_radius("model", "gate_radius").kind, GateRadiusOption::Kind::model);
  const GateRadiusOption three = parse_gate_radius("3", "gate_radius");
  EXPECT_EQ(three.kind, GateRadiusOption::Kind::fixed);
  EXPECT_EQ(three.radius, 3);
  EXPECT_EQ(gate_radius_text(three), "3");
  for (const char* bad : {"", "-1", "16", "2x", "one"}) {
    try {
      parse_gate_radius(bad, "gate_radius");
      ADD_FAILURE() << "accepted '" << bad << "'";
    } catch (const OptionError& e) {
      EXPECT_EQ(e.field(), "gate_radius");
      EXPECT_EQ(e.kind(), ErrorKind::usage);
      EXPECT_NE(std::string(e.what()).find("gate_radius '" + std::string(bad) + "'"), std::string::npos) << e.what();
    }
  }
  PhysicsPlan unmeasured;  // a given contrast: no noise measure
  const GateChoice own = choose_gate_radius(GateRadiusOption{}, 1, unmeasured);
  EXPECT_EQ(own.radius, 1);
  EXPECT_NE(own.source.find("not measured"), std::string::npos) << own.source;
  PhysicsPlan noisy;
  noisy.frame_noise = 0.05, noisy.isolated_event_fraction = 0.3;
  EXPECT_EQ(choose_gate_radius({GateRadiusOption::Kind::model, 0}, 1, noisy).radius, 1);
  EXPECT_EQ(choose_gate_radius(three, 1, noisy).radius, 3);
  EXPECT_EQ(choose_gate_radius(GateRadiusOption{}, -1, noisy).radius, -1) << "no gate: none chosen";
  EXPECT_THROW(choose_gate_radius(three, -1, noisy), OptionError);
}
