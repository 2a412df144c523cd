// Scene simulator: event model against closed-form threshold crossings, noise rates, RS timing
// (skew = speed x line delay per row), determinism, and read-back of the written sequence.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <string>

#include <nlohmann/json.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "vkunroll/host/events/event_reader.hpp"
#include "vkunroll/host/sim/dvs.hpp"
#include "vkunroll/host/sim/scene.hpp"
#include "vkunroll/host/sim/recording.hpp"
#include "vkunroll/base/error.hpp"

namespace fs = std::filesystem;
using namespace vkunroll;
using namespace vkunroll::sim;

namespace {

fs::path temp_dir(const std::string& name) {
  const fs::path p = fs::temp_directory_path() / ("vkunroll_sim_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(p);
  fs::create_directories(p);
  return p;
}

std::string slurp(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(f), {});
}

// A clean, small configuration for tests.
SimulationConfig small_config(int w, int h) {
  SimulationConfig c = simulation_preset("clean");
  c.width = w;
  c.height = h;
  c.frames = 2;
  c.gt_per_frame = 2;
  c.fps = 100;
  c.line_delay_us = 100;
  c.exposure_us = 1000;
  c.lead_in_us = 1000;
  return c;
}

// Uniform images whose per-pixel intensity grows as I0 * exp(rate * t).
cv::Mat ramp_image(int w, int h, double t_s, double rate) {
  cv::Mat m(h, w, CV_32FC1);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) m.at<float>(y, x) = static_cast<float>((0.02 + 0.01 * (y * w + x)) * std::exp(rate * t_s));
  return m;
}

}  // namespace

TEST(Simulator, RampEventCountsMatchThresholdCrossings) {
  const int w = 8, h = 6;
  EventSimParams p = event_preset("clean");
  p.sigma = 0.03;  // per-pixel thresholds: each pixel's count must follow its own threshold
  p.seed = 5;
  EventSimulator ev(w, h, p);
  const double rate = 4.0, t_end = 0.5;  // intensity x e^2 over 0.5 s
  ev.reset(0.0, ramp_image(w, h, 0.0, rate));
  const int steps = 2000;
  for (int s = 1; s <= steps; ++s) ev.advance(t_end * 1e6 * s / steps, ramp_image(w, h, t_end * s / steps, rate));
  const EventStream& es = ev.events();
  std::map<int, std::vector<int64_t>> per_pixel;
  for (size_t i = 0; i < es.size(); ++i) {
    EXPECT_EQ(es.p[i], 1) << "a brightening ramp must give only ON events";
    if (i) {
      ASSERT_LE(es.t[i - 1], es.t[i]) << "events must be time-sorted";
    }
    per_pixel[es.y[i] * w + es.x[i]].push_back(es.t[i]);
  }
  const cv::Mat c_on = ev.thresholds_on();
  int total_expected = 0;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const double i0 = 0.02 + 0.01 * (y * w + x), i1 = i0 * std::exp(rate * t_end);
      const double c = c_on.at<float>(y, x);
      const double l0 = std::log(p.eps + i0), dl = std::log(p.eps + i1) - l0;
      const int expected = static_cast<int>(std::floor(dl / c));
      total_expected += expected;
      const auto& ts = per_pixel[y * w + x];
      ASSERT_EQ(static_cast<int>(ts.size()), expected) << "pixel " << x << "," << y << " threshold " << c;
      // The k-th event is where log(eps + I(t)) = l0 + k c: t = ln((exp(l0 + k c) - eps) / i0) / rate.
      for (int k = 1; k <= expected; ++k) {
        const double tk = std::log((std::exp(l0 + k * c) - p.eps) / i0) / rate * 1e6;
        EXPECT_NEAR(static_cast<double>(ts[k - 1]), tk, 2.0) << "pixel " << x << "," << y << " crossing " << k;
      }
    }
  EXPECT_GT(total_expected, 200);
  EXPECT_EQ(ev.stats().on, static_cast<uint64_t>(total_expected));
}

TEST(Simulator, PolarityFollowsTheSignOfChange) {
  const int w = 6, h = 4;
  EventSimulator up(w, h, event_preset("clean")), down(w, h, event_preset("clean"));
  up.reset(0.0, ramp_image(w, h, 0.0, 3.0));
  down.reset(0.0, ramp_image(w, h, 0.0, -3.0));
  for (int s = 1; s <= 500; ++s) {
    up.advance(s * 1000.0, ramp_image(w, h, s * 1e-3, 3.0));
    down.advance(s * 1000.0, ramp_image(w, h, s * 1e-3, -3.0));
  }
  ASSERT_GT(up.events().size(), 100u);
  ASSERT_GT(down.events().size(), 50u);  // fewer: the eps floor compresses the dark end
  for (int8_t p : up.events().p) ASSERT_EQ(p, 1);
  for (int8_t p : down.events().p) ASSERT_EQ(p, -1);

  // A bright bar moving right over a dark background: ON at its leading edge, OFF at its trailing edge.
  SceneSpec spec;
  spec.width = 48;
  spec.height = 16;
  spec.background_color = cv::Scalar::all(0.05);
  SpriteSpec bar;
  bar.size = glm::dvec2(8, 40);
  bar.position = glm::dvec2(8, 8);
  bar.velocity = glm::dvec2(1500, 0);
  bar.color = cv::Scalar::all(0.8);
  spec.sprites.push_back(bar);
  Scene scene(spec);
  SimulationConfig c = small_config(48, 16);
  c.frames = 1;
  c.fps = 50;  // 20 ms: the bar moves 30 px
  const SimulatedSequence seq = simulate(c, scene);
  ASSERT_GT(seq.events.size(), 200u);
  for (size_t i = 0; i < seq.events.size(); ++i) {
    const double center = 8 + 1500 * seq.events.t[i] * 1e-6;
    const int expected = seq.events.x[i] > center ? 1 : -1;
    ASSERT_EQ(seq.events.p[i], expected) << "event " << i << " at x=" << seq.events.x[i] << " t=" << seq.events.t[i]
                                         << " with the bar centered at " << center;
  }
}

TEST(Simulator, StaticSceneWithoutNoiseGivesNoEvents) {
  SimulationConfig c = small_config(40, 30);
  c.motion = MotionKind::Static;
  c.sprites = 0;
  c.texture = TextureKind::Mixed;
  const SimulatedSequence seq = simulate(c);
  EXPECT_EQ(seq.events.size(), 0u);
  EXPECT_EQ(seq.event_stats.on + seq.event_stats.off, 0u);
  // Nothing moves, so every RS frame equals the sharp GS image.
  ASSERT_EQ(seq.rs.size(), 2u);
  ASSERT_FALSE(seq.gt.empty());
  EXPECT_LT(cv::norm(seq.rs[0], seq.gt[0].image, cv::NORM_INF), 1e-4);
  EXPECT_GT(cv::norm(seq.gt[0].image, cv::NORM_L1), 0.0);
}

TEST(Simulator, NoiseRatesMatchTheirParameters) {
  const int w = 32, h = 24;
  const cv::Mat dark(h, w, CV_32FC1, cv::Scalar(0.0));
  EventSimParams shot = event_preset("clean");
  shot.shot_hz = 50.0;
  EventSimParams leak = event_preset("clean");
  leak.leak_hz = 20.0;
  EventSimulator es(w, h, shot), el(w, h, leak);
  es.reset(0.0, dark);
  el.reset(0.0, dark);
  for (int s = 1; s <= 1000; ++s) {  // 1 s in 1 ms steps
    es.advance(s * 1000.0, dark);
    el.advance(s * 1000.0, dark);
  }
  // Shot noise: Poisson at shot_hz x (1 - 0.75 x 20/275) in the dark (v2e's intensity dependence).
  const double expected_shot = w * h * 50.0 * (1.0 - 0.75 * 20.0 / 275.0);
  EXPECT_NEAR(static_cast<double>(es.events().size()), expected_shot, 5 * std::sqrt(expected_shot));
  EXPECT_EQ(es.stats().shot, es.events().size());
  const double on_fraction = static_cast<double>(es.stats().on) / es.events().size();
  EXPECT_NEAR(on_fraction, 0.5, 0.03);
  // Leak: the reference drifts by leak_hz x C per second, so each pixel fires ~20 ON events.
  EXPECT_NEAR(static_cast<double>(el.events().size()), w * h * 20.0, w * h * 1.0);
  EXPECT_EQ(el.stats().off, 0u);
}

TEST(Simulator, RefractoryPeriodSeparatesEventsOfAPixel) {
  const int w = 4, h = 3;
  EventSimParams p = event_preset("clean");
  p.c_on = p.c_off = 0.05;
  p.refractory_us = 2000;
  EventSimulator ev(w, h, p);
  // log intensity rises up to 60/s: a 0.05 crossing every ~0.8 ms, faster than the 2 ms refractory period.
  ev.reset(0.0, ramp_image(w, h, 0.0, 60.0));
  for (int s = 1; s <= 200; ++s) ev.advance(s * 100.0, ramp_image(w, h, s * 1e-4, 60.0));
  std::map<int, int64_t> last;
  for (size_t i = 0; i < ev.events().size(); ++i) {
    const int k = ev.events().y[i] * w + ev.events().x[i];
    if (last.count(k)) {
      EXPECT_GE(ev.events().t[i] - last[k], 1999) << "event " << i;
    }
    last[k] = ev.events().t[i];
  }
  EXPECT_GT(ev.stats().dropped_refractory, 0u);
  EXPECT_GT(ev.events().size(), 0u);
}

// Centroid of (luminance - background) per row of a linear image.
static std::vector<double> row_centroids(const cv::Mat& bgr, double bg) {
  std::vector<double> c;
  for (int y = 0; y < bgr.rows; ++y) {
    double s = 0, sx = 0;
    for (int x = 0; x < bgr.cols; ++x) {
      const cv::Vec3f v = bgr.at<cv::Vec3f>(y, x);
      const double l = std::max(0.0, kLumB * v[0] + kLumG * v[1] + kLumR * v[2] - bg);
      s += l;
      sx += l * x;
    }
    c.push_back(sx / s);
  }
  return c;
}

TEST(Simulator, VerticalBarGivesTheRollingShutterSkewOfSpeedTimesDelay) {
  for (const std::string readout : {"top-down", "bottom-up"}) {
    const int w = 64, h = 48;
    const double v = 2000.0;  // px/s
    SceneSpec spec;
    spec.width = w;
    spec.height = h;
    spec.background_color = cv::Scalar::all(0.05);
    SpriteSpec bar;
    bar.size = glm::dvec2(6, 200);
    bar.position = glm::dvec2(8, 24);
    bar.velocity = glm::dvec2(v, 0);
    bar.color = cv::Scalar::all(0.8);
    spec.sprites.push_back(bar);
    Scene scene(spec);
    SimulationConfig c = small_config(w, h);
    c.frames = 1;
    c.readout = readout;
    c.exposure_us = 500;
    const SimulatedSequence seq = simulate(c, scene);
    const std::vector<double> cx = row_centroids(seq.rs[0], 0.05);
    // Row y sees the bar at the middle of its exposure: x = 8 + v (t0 + r(y) delay + exposure / 2).
    double sy = 0, sxy = 0, syy = 0, sx = 0;
    for (int y = 0; y < h; ++y) {
      const int r = readout == "top-down" ? y : h - 1 - y;
      const double expected = 8 + v * 1e-6 * (c.frame_t0_us(0) + r * c.line_delay_us + c.exposure_us / 2);
      EXPECT_NEAR(cx[y], expected, 0.1) << readout << " row " << y;
      sy += y; sx += cx[y]; sxy += y * cx[y]; syy += double(y) * y;
    }
    const double slope = (h * sxy - sy * sx) / (h * syy - sy * sy);
    const double predicted = (readout == "top-down" ? 1 : -1) * v * 1e-6 * c.line_delay_us;  // 0.2 px per row
    EXPECT_NEAR(slope, predicted, 0.01 * std::abs(predicted)) << readout;
  }
}

TEST(Simulator, BrightnessRampThroughTheFullPipelineCountsCrossings) {
  // Global illumination ramp on a textured static scene: the adaptive step must not lose crossings.
  SceneOptions o;
  o.width = 24;
  o.height = 16;
  o.motion = MotionKind::Static;
  o.sprites = 0;
  o.texture = TextureKind::Noise;
  o.duration_us = 30000;
  o.seed = 3;
  SceneSpec spec = build_scene(o);
  spec.log_gain_rate = 30.0;  // x e^0.9 over 30 ms
  spec.gain = 0.3;
  Scene scene(spec);
  SimulationConfig c = small_config(24, 16);
  c.frames = 1;
  c.fps = 1e6 / 29000.0;
  c.lead_in_us = 1000;  // events cover [0, 30 ms)
  const SimulatedSequence seq = simulate(c, scene);
  cv::Mat i0, i1;
  scene.render_luminance(0.0, i0);
  scene.render_luminance(c.end_us(), i1);
  uint64_t expected = 0;
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 24; ++x)
      expected += static_cast<uint64_t>(std::floor((std::log(c.events.eps + i1.at<float>(y, x)) - std::log(c.events.eps + i0.at<float>(y, x))) / c.events.c_on));
  EXPECT_GT(expected, 500u);
  EXPECT_EQ(seq.events.size(), expected);
  EXPECT_EQ(seq.event_stats.off, 0u);
  EXPECT_EQ(seq.steps.over_limit, 0u);
}

TEST(Simulator, AdaptiveStepConverges) {
  // Halving the allowed change per sample barely changes the events of a moving scene.
  SimulationConfig c = small_config(32, 24);
  c.frames = 2;
  c.seed = 11;
  c.sprites = 1;
  c.speed_scale = 8.0;  // preset speeds scale with width/346: make a 32-px view move like a full one
  SimulationConfig fine = c;
  fine.step_fraction = 0.25;
  const SimulatedSequence a = simulate(c), b = simulate(fine);
  ASSERT_GT(a.events.size(), 500u);
  EXPECT_GT(b.steps.samples, a.steps.samples);
  EXPECT_NEAR(static_cast<double>(b.events.size()) / a.events.size(), 1.0, 0.03);
  EXPECT_EQ(a.steps.over_limit, 0u);
}

TEST(Simulator, SameSeedSameResultUnderAnyThreadCount) {
  SimulationConfig c = simulation_preset("realistic");
  c.width = 40;
  c.height = 30;
  c.frames = 2;
  c.gt_per_frame = 1;
  c.fps = 100;
  c.line_delay_us = 100;
  c.exposure_us = 1000;
  c.lead_in_us = 1000;
  c.seed = 21;
  c.events.seed = 21;
  const int threads = cv::getNumThreads();
  cv::setNumThreads(1);
  const SimulatedSequence a = simulate(c);
  cv::setNumThreads(std::max(2, threads));
  const SimulatedSequence b = simulate(c);
  cv::setNumThreads(threads);
  ASSERT_GT(a.events.size(), 100u);
  EXPECT_EQ(a.events.t, b.events.t);
  EXPECT_EQ(a.events.x, b.events.x);
  EXPECT_EQ(a.events.y, b.events.y);
  EXPECT_EQ(a.events.p, b.events.p);
  for (size_t k = 0; k < a.rs.size(); ++k) EXPECT_EQ(cv::norm(a.rs[k], b.rs[k], cv::NORM_INF), 0.0);
}

TEST(Simulator, CliOutputIsDeterministicPerSeed) {
  const fs::path root = temp_dir("det");
  auto run = [&](const std::string& name, int seed) {
    const std::string cmd = std::string(VKUNROLL_CLI_PATH) + " simulate --quiet --preset realistic --size 48x32 --frames 2 "
                            "--gt-per-frame 2 --fps 100 --exposure-us 1000 --lead-in-us 1000 --events-format both --seed " +
                            std::to_string(seed) + " --out " + (root / name).string();
    ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  };
  run("a", 7);
  run("b", 7);
  run("c", 8);
  size_t files = 0;
  for (const auto& entry : fs::recursive_directory_iterator(root / "a")) {
    if (!entry.is_regular_file()) continue;
    const fs::path rel = fs::relative(entry.path(), root / "a");
    ASSERT_TRUE(fs::exists(root / "b" / rel)) << rel;
    EXPECT_EQ(slurp(entry.path()), slurp(root / "b" / rel)) << rel << " differs between two runs with the same seed";
    ++files;
  }
  EXPECT_EQ(files, 2u + 4u + 3u + 1u);  // rs x2, gs x4, events.h5, events.txt, meta.json, .vkunroll-manifest
  EXPECT_NE(slurp(root / "a" / "events.h5"), slurp(root / "c" / "events.h5"));
  EXPECT_NE(slurp(root / "a" / "rs" / "000000.png"), slurp(root / "c" / "rs" / "000000.png"));
  fs::remove_all(root);
}

TEST(Simulator, WrittenSequenceIsReadBackByTheProjectReaders) {
  const fs::path dir = temp_dir("readback");
  SimulationConfig c = simulation_preset("noisy");
  c.width = 40;
  c.height = 30;
  c.frames = 3;
  c.gt_per_frame = 3;
  c.fps = 100;
  c.line_delay_us = 150;
  c.exposure_us = 800;
  c.lead_in_us = 2000;
  c.readout = "bottom-up";
  c.events_format = "both";
  c.bit_depth = 16;
  const SimulatedSequence seq = simulate(c);
  write_sequence(c, seq, dir.string());
  ASSERT_GT(seq.events.size(), 100u);

  for (const char* name : {"events.h5", "events.txt"}) {
    EventReadReport report;
    const EventStream back = read_events((dir / name).string(), {}, &report);
    EXPECT_EQ(back.width, 40) << name;
    EXPECT_EQ(back.height, 30) << name;
    EXPECT_EQ(back.t, seq.events.t) << name;
    EXPECT_EQ(back.x, seq.events.x) << name;
    EXPECT_EQ(back.y, seq.events.y) << name;
    EXPECT_EQ(back.p, seq.events.p) << name;
    EXPECT_EQ(report.dropped(), 0u) << name;
  }

  std::ifstream f(dir / "meta.json");
  const nlohmann::json meta = nlohmann::json::parse(f);
  EXPECT_EQ(meta.at("width").get<int>(), 40);
  EXPECT_EQ(meta.at("height").get<int>(), 30);
  EXPECT_DOUBLE_EQ(meta.at("line_delay_us").get<double>(), 150.0);
  EXPECT_DOUBLE_EQ(meta.at("exposure_us").get<double>(), 800.0);
  EXPECT_EQ(meta.at("readout").get<std::string>(), "bottom-up");
  EXPECT_EQ(meta.at("events").get<std::string>(), "events.h5");
  ASSERT_EQ(meta.at("frames").size(), 3u);
  for (int k = 0; k < 3; ++k) {
    const auto& fr = meta.at("frames")[k];
    EXPECT_DOUBLE_EQ(fr.at("t0_us").get<double>(), 2000.0 + k * 10000.0);
    const cv::Mat img = cv::imread((dir / fr.at("file").get<std::string>()).string(), cv::IMREAD_UNCHANGED);
    ASSERT_FALSE(img.empty());
    EXPECT_EQ(img.type(), CV_16UC3);
    EXPECT_EQ(img.cols, 40);
    EXPECT_EQ(img.rows, 30);
  }
  ASSERT_EQ(meta.at("ground_truth").size(), 9u);
  for (const auto& g : meta.at("ground_truth")) {
    EXPECT_TRUE(fs::exists(dir / g.at("file").get<std::string>())) << g.dump();
    const double t = g.at("t_us").get<double>();
    EXPECT_GE(t, 2000.0);
    EXPECT_LT(t, 32000.0);
  }
  const auto& src = meta.at("source");
  EXPECT_EQ(src.at("preset").get<std::string>(), "noisy");
  EXPECT_EQ(src.at("settings").at("event_model").at("shot_hz").get<double>(), 5.0);
  EXPECT_EQ(src.at("event_count").get<size_t>(), seq.events.size());
  fs::remove_all(dir);
}

TEST(Simulator, ImageFileTextureIsLinearizedAndCoversTheView) {
  const fs::path dir = temp_dir("texture");
  // A left-dark / right-bright 8-bit image: the texture must keep that layout, in linear intensity.
  cv::Mat img(60, 80, CV_8UC3, cv::Scalar::all(40));
  img(cv::Rect(40, 0, 40, 60)).setTo(cv::Scalar::all(220));
  const std::string path = (dir / "tex.png").string();
  ASSERT_TRUE(cv::imwrite(path, img));
  const cv::Mat lin = load_texture(path, 2.2);
  ASSERT_EQ(lin.type(), CV_32FC3);
  const double dark = lin.at<cv::Vec3f>(30, 10)[1], bright = lin.at<cv::Vec3f>(30, 70)[1];
  EXPECT_NEAR(dark, std::pow(0.12 + 0.8 * 40 / 255.0, 2.2), 1e-4);
  EXPECT_NEAR(bright, std::pow(0.12 + 0.8 * 220 / 255.0, 2.2), 1e-4);

  SimulationConfig c = small_config(32, 24);
  c.texture_file = path;
  c.motion = MotionKind::Static;
  c.sprites = 0;
  c.frames = 1;
  const SimulatedSequence seq = simulate(c);
  EXPECT_EQ(seq.events.size(), 0u);
  // The view shows the center of the (cover-scaled) image: dark on the left, bright on the right.
  const cv::Mat& gt = seq.gt.at(0).image;
  EXPECT_LT(gt.at<cv::Vec3f>(12, 1)[1], 0.2f);
  EXPECT_GT(gt.at<cv::Vec3f>(12, 30)[1], 0.5f);
  fs::remove_all(dir);
}

TEST(Simulator, RejectsImpossibleTimingAndNamesTheSetting) {
  SimulationConfig c = small_config(64, 48);
  c.line_delay_us = 500;  // 47 rows x 500 us = 23.5 ms of readout > 10 ms frame period
  try {
    c.validate();
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("line_delay_us"), std::string::npos) << e.what();
  }
  c = small_config(64, 48);
  c.readout = "sideways";
  EXPECT_THROW(c.validate(), Error);
  EXPECT_THROW(event_preset("loud"), Error);
  EXPECT_THROW(parse_motion_kind("spin"), Error);
  EXPECT_THROW(load_texture("/nonexistent/texture.png", 2.2), Error);
}

// Every noise option is seeded: with the scene held fixed (its own seed), the same simulator seed
// gives identical events and frames, another seed other ones, for each option on its own.
TEST(Simulator, EachNoiseOptionIsSeededAndDeterministic) {
  SimulationConfig base = simulation_preset("clean");
  base.width = 40, base.height = 30, base.frames = 2, base.gt_per_frame = 1, base.fps = 100;
  base.line_delay_us = 100, base.exposure_us = 1000, base.lead_in_us = 1000;
  base.motion = MotionKind::Pan, base.speed_scale = 3;
  auto run = [](const SimulationConfig& c, uint64_t seed) {
    SceneOptions o;
    o.width = c.width, o.height = c.height, o.texture = c.texture, o.motion = c.motion, o.sprites = c.sprites;
    o.speed_scale = c.speed_scale;
    o.duration_us = c.end_us(), o.gamma = c.gamma, o.seed = 5;  // the scene's seed, fixed
    Scene scene(build_scene(o));
    SimulationConfig s = c;
    s.seed = seed;
    return simulate(s, scene);
  };
  struct Option {
    const char* name;
    void (*set)(SimulationConfig&);
    bool frames;  // the option acts on the frames (else on the events)
  };
  const Option options[] = {
      {"--sigma", [](SimulationConfig& c) { c.events.sigma = 0.05; }, false},
      {"--shot-hz", [](SimulationConfig& c) { c.events.shot_hz = 200; }, false},
      {"--leak-hz", [](SimulationConfig& c) { c.events.leak_hz = 50; }, false},
      {"--hot-pixels", [](SimulationConfig& c) { c.events.hot_fraction = 0.05, c.events.hot_hz = 500; }, false},
      {"--jitter-us", [](SimulationConfig& c) { c.events.jitter_us = 300; }, false},
      {"--full-well", [](SimulationConfig& c) { c.frame_noise.full_well_e = 1500; }, true},
      {"--read-noise", [](SimulationConfig& c) { c.frame_noise.read_noise = 0.008; }, true},
  };
  const SimulatedSequence clean = run(base, 1);
  for (const Option& opt : options) {
    SimulationConfig c = base;
    opt.set(c);
    const SimulatedSequence a = run(c, 1), b = run(c, 1), other = run(c, 2);
    ASSERT_GT(a.events.size(), 100u) << opt.name;
    EXPECT_EQ(a.events.t, b.events.t) << opt.name;
    EXPECT_EQ(a.events.x, b.events.x) << opt.name;
    EXPECT_EQ(a.events.p, b.events.p) << opt.name;
    for (size_t k = 0; k < a.rs.size(); ++k) EXPECT_EQ(cv::norm(a.rs[k], b.rs[k], cv::NORM_INF), 0.0) << opt.name;
    if (opt.frames) {
      EXPECT_GT(cv::norm(a.rs[0], other.rs[0], cv::NORM_INF), 0.0) << opt.name << ": another seed, the same frame noise";
      EXPECT_GT(cv::norm(a.rs[0], clean.rs[0], cv::NORM_INF), 0.0) << opt.name << " adds no noise";
    } else {
      EXPECT_TRUE(a.events.t != other.events.t || a.events.x != other.events.x || a.events.y != other.events.y)
          << opt.name << ": another seed, the same events";
      EXPECT_TRUE(a.events.t != clean.events.t || a.events.x != clean.events.x) << opt.name << " changes no event";
    }
  }
}

// Hot pixels fire at their rate wherever they are, and jitter moves timestamps by its std without
// losing, adding or reordering-out-of-interval any event.
TEST(Simulator, HotPixelsAndJitterHaveTheirRatesAndSpread) {
  EventSimParams p;
  p.seed = 11;
  EventStream signal;
  signal.width = 100, signal.height = 80;
  for (int k = 0; k < 20000; ++k) signal.push(1000 + k * 4, static_cast<uint16_t>(k % 100), static_cast<uint16_t>(k % 80), k % 2 ? 1 : -1);
  const double t0 = 0, t1 = 200000;  // 0.2 s
  // Hot pixels only: 1% of 8000 pixels at 1 kHz for 0.2 s = 80 pixels x 200 events.
  p.hot_fraction = 0.01, p.hot_hz = 1000;
  EventStream hot = signal;
  EventSimStats stats;
  add_readout_artifacts(hot, p, t0, t1, stats);
  ASSERT_EQ(hot.size(), signal.size() + stats.hot);
  EXPECT_NEAR(double(stats.hot), 80.0 * 200.0, 0.25 * 80 * 200) << "hot-pixel events";
  for (size_t k = 0; k < hot.size(); ++k) {
    if (k > 0) {
      ASSERT_LE(hot.t[k - 1], hot.t[k]) << "sorted";
    }
    ASSERT_GE(hot.t[k], t0);
    ASSERT_LT(hot.t[k], t1);
  }
  EventSimStats again_stats;
  EventStream again = signal;
  add_readout_artifacts(again, p, t0, t1, again_stats);
  EXPECT_EQ(again.t, hot.t);
  EXPECT_EQ(again.x, hot.x);
  // Jitter only: the same events, each moved by about N(0, 50 us).
  p.hot_fraction = 0, p.hot_hz = 0, p.jitter_us = 50;
  EventStream jittered = signal;
  EventSimStats jstats;
  add_readout_artifacts(jittered, p, t0, t1, jstats);
  ASSERT_EQ(jittered.size(), signal.size());
  EXPECT_EQ(jstats.hot, 0u);
  // The polarities are kept, and the rms shift of the sorted timestamps is at most the jitter's
  // std (sorting only shrinks it) but not zero.
  double sq = 0;
  for (size_t k = 0; k < signal.size(); ++k) {
    const double d = double(jittered.t[k] - signal.t[k]);
    sq += d * d;
    if (k > 0) {
      ASSERT_LE(jittered.t[k - 1], jittered.t[k]);
    }
  }
  const double rms = std::sqrt(sq / signal.size());
  EXPECT_GT(rms, 5.0) << "jitter moved nothing";
  EXPECT_LT(rms, 60.0);
  int64_t on_before = 0, on_after = 0;
  for (size_t k = 0; k < signal.size(); ++k) on_before += signal.p[k] > 0, on_after += jittered.p[k] > 0;
  EXPECT_EQ(on_before, on_after);
  EXPECT_THROW({
    EventSimParams bad;
    bad.hot_fraction = 2;
    EventSimulator(4, 4, bad);
  }, Error);
}
