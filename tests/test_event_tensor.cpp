// Row timing, exact rationals and the row-aware event tensors: hand-made boundary cases, GPU ==
// CPU on random streams, and the NumPy golden fixture (tools/data/event_tensors_numpy.py).
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <nlohmann/json.hpp>
#include <random>
#include <tuple>

#include "vkunroll/base/row_timing.hpp"
#include "vkunroll/host/model/safetensors.hpp"
#include "vkunroll/kernels/event_tensor.hpp"
#include "vkunroll/base/error.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;

namespace {

Rational R(const std::string& s) { return Rational::parse(s); }

// One job whose rows all share (a, b), except optional per-row overrides.
RowIntervals uniform_job(int rows, Rational a, Rational b) {
  RowIntervals j;
  j.a.assign(rows, a);
  j.b.assign(rows, b);
  return j;
}

struct Hit {
  int channel, y, x;
  float count;
};

// Every nonzero cell of a [2N, h, w] slice equals the expected list, and nothing else is set.
void expect_hits(const std::vector<float>& slice, int bins, int h, int w, const std::vector<Hit>& hits,
                 const std::string& what) {
  std::vector<float> expect(static_cast<size_t>(2 * bins) * h * w, 0.f);
  for (const auto& hit : hits) expect[(static_cast<size_t>(hit.channel) * h + hit.y) * w + hit.x] += hit.count;
  ASSERT_EQ(slice.size(), expect.size()) << what;
  for (size_t i = 0; i < expect.size(); ++i)
    EXPECT_EQ(slice[i], expect[i]) << what << ": channel " << i / (h * w) << " y " << (i / w) % h << " x " << i % w;
}

// Runs jobs on CPU and GPU, checks they are identical, returns the CPU result.
std::vector<float> both(const EventStream& ev, const std::vector<RowIntervals>& jobs, const EventTensorSpec& spec) {
  auto cpu = bin_events_ref(ev, jobs, spec);
  for (auto algo : {EventBinAlgorithm::per_row, EventBinAlgorithm::per_event, EventBinAlgorithm::per_pixel}) {
    EventTensorBuilder b(vktest::context());
    b.set_algorithm(algo);
    auto gpu = b.bin(ev, jobs, spec);
    EXPECT_EQ(b.last_algorithm(), algo);
    EXPECT_EQ(cpu.size(), gpu.size());
    size_t diff = 0;
    for (size_t i = 0; i < cpu.size() && i < gpu.size(); ++i) diff += cpu[i] != gpu[i];
    EXPECT_EQ(diff, 0u) << "GPU (" << static_cast<int>(algo)
                        << ") and CPU differ in " << diff << " cells";
  }
  return cpu;
}

EventStream random_stream(int w, int h, size_t n, int64_t t_begin, int64_t t_end, uint32_t seed) {
  std::mt19937_64 rng(seed);
  std::vector<int64_t> t(n);
  for (auto& v : t) v = t_begin + static_cast<int64_t>(rng() % static_cast<uint64_t>(t_end - t_begin));
  std::sort(t.begin(), t.end());
  EventStream ev;
  ev.width = w;
  ev.height = h;
  for (size_t i = 0; i < n; ++i)
    ev.push(t[i], static_cast<uint16_t>(rng() % w), static_cast<uint16_t>(rng() % h), (rng() & 1) ? 1 : -1);
  return ev;
}

}  // namespace

// ---- rationals and row timing ----------------------------------------------------------------

TEST(RowTiming, RationalParseAndFromDouble) {
  EXPECT_EQ(R("12"), Rational(12));
  EXPECT_EQ(R("-3.25"), Rational(-13, 4));
  EXPECT_EQ(R("1e3"), Rational(1000));
  EXPECT_EQ(R("2.5e-1"), Rational(1, 4));
  EXPECT_EQ(R("73000/259").str(), "73000/259");
  EXPECT_EQ(R("-1/3"), Rational(-1, 3));
  EXPECT_THROW(R("abc"), Error);
  EXPECT_THROW(R("1/0"), Error);
  EXPECT_THROW(R("1.2.3"), Error);
  EXPECT_THROW(R(""), Error);
  EXPECT_EQ(Rational::from_double(0.1), Rational(1, 10));
  EXPECT_EQ(Rational::from_double(73000.0 / 259.0), Rational(73000, 259));
  EXPECT_EQ(Rational::from_double(-2.5), Rational(-5, 2));
  EXPECT_EQ(Rational::from_double(1e6 / 2400 / 2), Rational(625, 3));
  EXPECT_EQ(Rational::from_double(123456789.0), Rational(123456789));
  // A double with no short fraction keeps its exact binary value.
  const double odd = 0.1234567890123456;
  EXPECT_EQ(Rational::from_double(odd).to_double(), odd);
  EXPECT_THROW(Rational::from_double(1e-300), Error);
  EXPECT_THROW(Rational::from_double(1e300), Error);
  EXPECT_THROW(Rational::from_double(std::nan("")), Error);
  EXPECT_EQ(R("7/2").floor(), 3);
  EXPECT_EQ(R("7/2").ceil(), 4);
  EXPECT_EQ(R("-7/2").floor(), -4);
  EXPECT_EQ(R("-7/2").ceil(), -3);
  EXPECT_EQ(R("1/3") + R("1/6"), R("1/2"));
  EXPECT_EQ(R("1/3") * R("3/7"), R("1/7"));
  EXPECT_LT(R("1/3"), R("0.3334"));
}

TEST(RowTiming, StartEndAndTargetsBothReadouts) {
  RowTiming td{R("100"), R("73000/259"), R("5000"), 260, Readout::top_down};
  EXPECT_EQ(td.start(0), R("100"));
  EXPECT_EQ(td.start(259), R("73100"));  // exact: 259 * 73000/259
  EXPECT_EQ(td.end(259), R("78100"));
  EXPECT_EQ(td.target_time(R("0")), R("100"));
  EXPECT_EQ(td.target_time(R("1")), R("78100"));
  EXPECT_EQ(td.target_time(R("0.5")), R("39100"));
  EXPECT_EQ(td.tau_of(R("39100")), R("1/2"));
  EXPECT_EQ(td.resolve(Target::absolute(R("-5"))), R("-5"));
  EXPECT_THROW(td.start(260), Error);
  EXPECT_THROW(td.start(-1), Error);
  RowTiming bu{R("0"), R("10"), R("50"), 4, Readout::bottom_up};
  EXPECT_EQ(bu.start(3), R("0"));   // the bottom row is read first
  EXPECT_EQ(bu.start(0), R("30"));
  EXPECT_EQ(bu.end(0), R("80"));
  EXPECT_EQ(bu.target_time(R("1")), R("80"));  // end of the last row read (row 0)
  EXPECT_EQ(bu.target_time(R("-0.25")), R("-20"));
  RowTiming bad{R("0"), R("-1"), R("5"), 4};
  EXPECT_THROW(bad.validate("frame 3"), Error);
  EXPECT_THROW(parse_readout("sideways"), Error);
}

// ---- hand-made boundaries (CPU and GPU) ------------------------------------------------------

TEST(EventTensor, ForwardIntervalBoundaries) {
  // a = 10 < b = 26, N = 4: bins [10,14) [14,18) [18,22) [22,26); t = 26 and t = 9 are outside.
  EventStream ev;
  ev.width = 4;
  ev.height = 3;
  ev.push(9, 0, 1, 1);
  ev.push(10, 0, 1, 1);   // exactly at a: bin 0, positive
  ev.push(13, 1, 1, -1);  // bin 0, negative
  ev.push(14, 1, 1, 1);   // first instant of bin 1
  ev.push(25, 2, 1, 1);   // last bin
  ev.push(26, 3, 1, 1);   // exactly at b: excluded (half-open)
  EventTensorSpec spec{4, {}};
  auto out = both(ev, {uniform_job(3, 10, 26)}, spec);
  expect_hits(out, 4, 3, 4, {{1, 1, 0, 1}, {0, 1, 1, 1}, {3, 1, 1, 1}, {7, 1, 2, 1}}, "forward");
}

TEST(EventTensor, BackwardIntervalFlipsAndClampsAtB) {
  // a = 26 > b = 10: selected t in [10, 26); every selected event is before a: sign flipped.
  // |t - a| = 16 at t = b gives k = N, clamped to N - 1.
  EventStream ev;
  ev.width = 4;
  ev.height = 3;
  ev.push(9, 3, 0, 1);    // before b: excluded
  ev.push(10, 0, 0, 1);   // at b: k = 4 -> 3, positive flipped -> channel 6
  ev.push(22, 1, 0, 1);   // |t-a| = 4 -> k = 1, flipped -> channel 2
  ev.push(23, 2, 0, -1);  // |t-a| = 3 -> k = 0, negative flipped -> channel 1
  ev.push(26, 3, 0, 1);   // exactly at a: excluded (a is the later end)
  EventTensorSpec spec{4, {}};
  auto out = both(ev, {uniform_job(3, 26, 10)}, spec);
  expect_hits(out, 4, 3, 4, {{6, 0, 0, 1}, {2, 0, 1, 1}, {1, 0, 2, 1}}, "backward");
}

TEST(EventTensor, UnsortedStreamIsAnError) {
  EventStream ev;
  ev.width = 2;
  ev.height = 1;
  ev.push(5, 0, 0, 1);
  ev.push(4, 1, 0, 1);
  EXPECT_THROW(bin_events_ref(ev, {uniform_job(1, 0, 10)}, {4, {}}), Error);
  EventTensorBuilder b(vktest::context());
  EXPECT_THROW(b.bin(ev, {uniform_job(1, 0, 10)}, {4, {}}), Error);
}

TEST(EventTensor, EmptyIntervalSelectsNothing) {
  EventStream ev;
  ev.width = 2;
  ev.height = 2;
  for (int64_t t = 5; t <= 15; ++t) ev.push(t, 1, 1, 1);
  EventTensorSpec spec{16, {}};
  auto out = both(ev, {uniform_job(2, 10, 10), uniform_job(2, R("10.5"), R("10.5"))}, spec);
  for (float v : out) ASSERT_EQ(v, 0.f);
}

TEST(EventTensor, FractionalBoundsAndEveryPolarity) {
  // a = 10, b = 10 + 7/3, N = 4: bin = floor((t-10) * 12 / 7): t=10 -> 0, 11 -> 1, 12 -> 3;
  // t = 13 > b excluded. Polarity: +1 odd channel, -1 and 0 (a {0,1} stream not yet mapped)
  // both even.
  EventStream ev;
  ev.width = 3;
  ev.height = 1;
  ev.push(10, 0, 0, 1);
  ev.push(10, 1, 0, -1);
  ev.push(10, 2, 0, 0);
  ev.push(11, 0, 0, 1);
  ev.push(12, 0, 0, -1);
  ev.push(13, 0, 0, 1);
  EventTensorSpec spec{4, {}};
  auto out = both(ev, {uniform_job(1, 10, R("10") + R("7/3"))}, spec);
  expect_hits(out, 4, 1, 3, {{1, 0, 0, 1}, {0, 0, 1, 1}, {0, 0, 2, 1}, {3, 0, 0, 1}, {6, 0, 0, 1}}, "fractional");
  // The same with a = 10.5 (non-integer a): t = 10 is outside, t = 11 is the first selected.
  auto out2 = both(ev, {uniform_job(1, R("10.5"), R("12.5"))}, spec);
  // t=11: floor(0.5*4/2) = 1; t=12: floor(1.5*2) = 3; 10 and 13 outside.
  expect_hits(out2, 4, 1, 3, {{3, 0, 0, 1}, {6, 0, 0, 1}}, "half-integer a");
}

TEST(EventTensor, FirstAndLastRowsKeepTheirOwnTimesUnderACrop) {
  // 3 rows with different intervals; crop rows 1..2 and columns 1..2 of a 4x3 sensor.
  RowIntervals job;
  job.a = {0, 0, 0};
  job.b = {10, 20, 30};
  EventStream ev;
  ev.width = 4;
  ev.height = 3;
  ev.push(5, 1, 0, 1);    // row 0: outside the crop
  ev.push(15, 1, 1, 1);   // row 1 (crop row 0): [0,20), k = floor(15*2/20) = 1 -> channel 3
  ev.push(15, 0, 1, 1);   // column 0: outside the crop
  ev.push(20, 2, 1, 1);   // row 1 at b: excluded
  ev.push(20, 2, 2, -1);  // row 2 (crop row 1): [0,30), k = floor(20*2/30) = 1 -> channel 2
  ev.push(29, 1, 2, 1);   // last instant of the last row: k = 1 -> channel 3
  EventTensorSpec spec{2, {1, 1, 2, 2}};
  auto out = both(ev, {job}, spec);
  expect_hits(out, 2, 2, 2, {{3, 0, 0, 1}, {2, 1, 1, 1}, {3, 1, 0, 1}}, "crop");
  EXPECT_THROW(bin_events_ref(ev, {job}, {2, {3, 0, 2, 1}}), Error);  // crop beyond the sensor
  EXPECT_THROW(bin_events_ref(ev, {uniform_job(2, 0, 1)}, spec), Error);  // wrong row count
  EXPECT_THROW(bin_events_ref(ev, {job}, {0, {}}), Error);
}

TEST(EventTensor, ThreeTensorsOfAPair) {
  // 3 rows, t0 = 100, delay 10, exposure 50: starts 100/110/120, ends 150/160/170; tau 0.5 ->
  // t* = 135. ev1 row 0: [100, 135) backward; ev2 row 0: [135, 150) forward; ev3: [135, 185).
  RowTiming tm{R("100"), R("10"), R("50"), 3, Readout::top_down};
  EventTensorPair pair{tm, tm.target_time(R("0.5")), std::nullopt};
  EXPECT_EQ(pair.target_us, R("135"));
  EventStream ev;
  ev.width = 1;
  ev.height = 3;
  ev.push(100, 0, 0, 1);  // ev1 row 0: |t-a| = 35 of 35 -> k = 2 clamped to 1, flipped -> ch 2
  ev.push(140, 0, 0, 1);  // ev2 row 0: (140-135)*2/15 = 0 -> ch 1; ev3: 5*2/50 = 0 -> ch 1
  ev.push(165, 0, 2, 1);  // ev2 row 2 ([135,170)): 30*2/35 = 1 -> ch 3; ev3: 30*2/50 = 1 -> ch 3
  EventTensorSpec spec{2, {}};
  auto cpu = build_event_tensors_ref(ev, {pair}, spec);
  EventTensorBuilder b(vktest::context());
  auto gpu = b.build(ev, {pair}, spec);
  EXPECT_EQ(cpu.ev1, gpu.ev1);
  EXPECT_EQ(cpu.ev2, gpu.ev2);
  EXPECT_EQ(cpu.ev3, gpu.ev3);
  expect_hits(cpu.ev1, 2, 3, 1, {{2, 0, 0, 1}}, "ev1");
  expect_hits(cpu.ev2, 2, 3, 1, {{1, 0, 0, 1}, {3, 2, 0, 1}}, "ev2");
  expect_hits(cpu.ev3, 2, 3, 1, {{1, 0, 0, 1}, {3, 2, 0, 1}}, "ev3");
  EXPECT_EQ(cpu.events_considered, 3u);
}

// ---- GPU == CPU on random streams --------------------------------------------------------------

TEST(EventTensor, GpuEqualsCpuRandomBatches) {
  struct Case {
    const char* name;
    int w, h, bins;
    const char *t0, *delay, *exposure;
    Readout readout;
    std::vector<const char*> taus;
    SensorCrop crop;
  };
  const std::vector<Case> cases = {
      {"integer top-down", 32, 24, 16, "1000", "200", "3200", Readout::top_down, {"0", "0.5", "1", "-0.25", "1.25"}, {}},
      {"readout/(H-1) bottom-up", 40, 26, 16, "12345", "73000/25", "10000", Readout::bottom_up, {"0.1", "0.9", "1/3"}, {}},
      {"fractional t0, N=7, crop", 36, 20, 7, "1000.25", "625/3", "1250/3", Readout::top_down, {"0.5", "2"}, {5, 3, 17, 11}},
  };
  for (const auto& c : cases) {
    RowTiming tm{R(c.t0), R(c.delay), R(c.exposure), c.h, c.readout};
    std::vector<EventTensorPair> pairs;
    for (const char* tau : c.taus) pairs.push_back({tm, tm.target_time(R(tau)), std::nullopt});
    // A second frame one frame span later toward the first target (the SelfUnroll-M pattern).
    RowTiming next = tm;
    next.t0 = tm.t0 + (tm.last_end() - tm.t0);
    pairs.push_back({next, pairs.front().target_us, R("777")});
    const int64_t span = (next.last_end() - tm.t0).ceil();
    auto ev = random_stream(c.w, c.h, 40000, tm.t0.floor() - span / 2, tm.t0.floor() + 2 * span, 17);
    EventTensorSpec spec{c.bins, c.crop};
    auto cpu = build_event_tensors_ref(ev, pairs, spec);
    EventTensors gpu;
    for (auto algo : {EventBinAlgorithm::per_row, EventBinAlgorithm::per_event, EventBinAlgorithm::per_pixel}) {
      EventTensorBuilder b(vktest::context());
      b.set_algorithm(algo);
      gpu = b.build(ev, pairs, spec);
      const std::string an = " (algorithm " + std::to_string(static_cast<int>(algo)) + ")";
      EXPECT_EQ(cpu.ev1, gpu.ev1) << c.name << an;
      EXPECT_EQ(cpu.ev2, gpu.ev2) << c.name << an;
      EXPECT_EQ(cpu.ev3, gpu.ev3) << c.name << an;
    }
    double total = 0;
    for (float v : cpu.ev1) total += v;
    EXPECT_GT(total, 1000) << c.name << ": the case must select events";
    EXPECT_EQ(cpu.events_considered, gpu.events_considered) << c.name;
  }
}

// What the sparse tiles decide on, computed from the events alone, equals the tensors' channel sums.
TEST(EventTensor, SelectedEventCountsEqualTheTensorSums) {
  const RowTiming tm{R("100"), R("37/3"), R("400"), 12, Readout::top_down};
  const auto ev = random_stream(16, 12, 20000, -300, 1200, 21);
  std::vector<EventTensorPair> pairs;
  for (const char* t : {"-150", "0", "310.5", "1000/3", "900"}) pairs.push_back({tm, R(t), std::nullopt});
  for (const SensorCrop crop : {SensorCrop{}, SensorCrop{3, 2, 9, 7}}) {
    EventTensorSpec spec;
    spec.bins = 5;
    spec.crop = crop;
    const EventTensors t = build_event_tensors_ref(ev, pairs, spec);
    const auto counts = selected_event_counts(ev, pairs, spec);
    ASSERT_EQ(counts.size(), pairs.size());
    const size_t plane = static_cast<size_t>(t.height) * t.width;
    size_t nonzero = 0;
    for (size_t p = 0; p < pairs.size(); ++p)
      for (size_t i = 0; i < plane; ++i) {
        double sum = 0;
        for (int c = 0; c < 2 * spec.bins; ++c)
          sum += t.ev1[p * t.slice() + c * plane + i] + t.ev2[p * t.slice() + c * plane + i];
        ASSERT_EQ(static_cast<double>(counts[p][i]), sum) << "pair " << p << " pixel " << i;
        nonzero += counts[p][i] > 0;
      }
    EXPECT_GT(nonzero, plane);  // the case is not trivially empty
  }
}

TEST(EventTensor, ChunkedJobsAndEventPiecesMatch) {
  RowTiming tm{R("0"), R("1000/7"), R("900"), 12, Readout::top_down};
  std::vector<EventTensorPair> pairs;
  for (const char* tau : {"0", "0.2", "0.4", "0.6", "0.8", "1"}) pairs.push_back({tm, tm.target_time(R(tau)), std::nullopt});
  auto ev = random_stream(16, 12, 20000, -500, 3500, 5);
  EventTensorSpec spec{16, {}};
  auto cpu = build_event_tensors_ref(ev, pairs, spec);
  EventTensorBuilder b(vktest::context());
  b.set_chunk_limits(4, 1000);  // 18 jobs in 5 chunks, events in ~pieces of 1000 (per-event path)
  for (auto algo : {EventBinAlgorithm::per_row, EventBinAlgorithm::per_event, EventBinAlgorithm::per_pixel}) {
    b.set_algorithm(algo);
    auto gpu = b.build(ev, pairs, spec);
    EXPECT_EQ(cpu.ev1, gpu.ev1);
    EXPECT_EQ(cpu.ev2, gpu.ev2);
    EXPECT_EQ(cpu.ev3, gpu.ev3);
  }
  b.set_algorithm(EventBinAlgorithm::automatic);
  // Device-resident: ev1, ev2, ev3 as consecutive ranges of one tensor.
  Tensor dev = b.build_on_device(ev, pairs, spec);
  EXPECT_EQ(dev.shape(), (Shape{18, 32, 12, 16}));
  auto all = dev.download<float>();
  const size_t n = cpu.ev1.size();
  EXPECT_TRUE(std::equal(cpu.ev1.begin(), cpu.ev1.end(), all.begin()));
  EXPECT_TRUE(std::equal(cpu.ev3.begin(), cpu.ev3.end(), all.begin() + 2 * n));
}

TEST(EventTensor, LargeBinCountsWorkAndPerPixelRefusesThem) {
  RowTiming tm{R("0"), R("3"), R("500"), 8, Readout::bottom_up};
  std::vector<EventTensorPair> pairs = {{tm, tm.target_time(R("0.3")), std::nullopt}};
  auto ev = random_stream(10, 8, 5000, -100, 700, 8);
  EventTensorSpec spec{100, {}};
  auto cpu = build_event_tensors_ref(ev, pairs, spec);
  EventTensorBuilder b(vktest::context());
  auto gpu = b.build(ev, pairs, spec);
  EXPECT_EQ(b.last_algorithm(), EventBinAlgorithm::sparse);
  EXPECT_EQ(cpu.ev1, gpu.ev1);
  EXPECT_EQ(cpu.ev2, gpu.ev2);
  EXPECT_EQ(cpu.ev3, gpu.ev3);
  b.set_algorithm(EventBinAlgorithm::per_event);
  gpu = b.build(ev, pairs, spec);
  EXPECT_EQ(cpu.ev2, gpu.ev2);
  EXPECT_EQ(cpu.ev3, gpu.ev3);
  b.set_algorithm(EventBinAlgorithm::per_pixel);
  EXPECT_THROW(b.build(ev, pairs, spec), Error);
}

TEST(EventTensor, PlanSelectsTheEventWindowByBinarySearch) {
  RowTiming tm{R("1000"), R("10"), R("100"), 4, Readout::top_down};
  EventTensorPair pair{tm, R("1050"), std::nullopt};
  EventStream ev;
  ev.width = 2;
  ev.height = 4;
  for (int64_t t = 0; t < 3000; ++t) ev.push(t, 0, t % 4, 1);
  const auto plan = plan_binning(ev, event_tensor_jobs({pair}), {16, {}});
  // Window: ev1 from start[0] = 1000 to t* = 1050; ev2 to end[3] = 1130; ev3 to 1150.
  EXPECT_EQ(plan.origin_us, 1000);
  EXPECT_EQ(plan.first_event, 1000u);
  EXPECT_EQ(plan.last_event, 1150u);
  EXPECT_EQ(plan.records.size(), 3u * 4 * 20);
}

// ---- golden fixture from NumPy float64 + np.add.at -------------------------------------------

TEST(EventTensor, MatchesNumpyGoldenExactly) {
  const std::string path = std::string(VKUNROLL_SOURCE_DIR) + "/tests/data/event_tensor_golden.safetensors";
  const auto file = read_safetensors(path);
  const int width = std::stoi(file.metadata.at("width")), height = std::stoi(file.metadata.at("height"));
  const auto cases = nlohmann::json::parse(file.metadata.at("cases"));
  ASSERT_GE(cases.size(), 4u);
  EventTensorBuilder builder(vktest::context());
  for (size_t ci = 0; ci < cases.size(); ++ci) {
    const auto& c = cases[ci];
    const std::string pre = "c" + std::to_string(ci) + "_";
    EventStream ev;
    ev.width = width;
    ev.height = height;
    const auto& t = file.get(pre + "t");
    const auto x = file.get(pre + "x").to_f32(), y = file.get(pre + "y").to_f32(), p = file.get(pre + "p").to_f32();
    for (size_t i = 0; i < x.size(); ++i) {
      int64_t ti;
      std::memcpy(&ti, t.data.data() + 8 * i, 8);
      ev.push(ti, static_cast<uint16_t>(x[i]), static_cast<uint16_t>(y[i]), static_cast<int8_t>(p[i]));
    }
    RowTiming tm{R(c["t0"]), R(c["delay"]), R(c["exposure"]), height, parse_readout(c["readout"])};
    std::vector<EventTensorPair> pairs;
    for (const auto& tau : c["taus"])
      pairs.push_back({tm, tm.target_time(R(tau)),
                       c["texp"].is_null() ? std::nullopt : std::optional<Rational>(R(c["texp"]))});
    const auto crop = c["crop"];
    EventTensorSpec spec{c["bins"].get<int>(), {crop[0].get<int>(), crop[1].get<int>(), crop[2].get<int>(), crop[3].get<int>()}};
    const auto cpu = build_event_tensors_ref(ev, pairs, spec);
    const auto gpu = builder.build(ev, pairs, spec);
    const std::vector<float>* mine_cpu[3] = {&cpu.ev1, &cpu.ev2, &cpu.ev3};
    const std::vector<float>* mine_gpu[3] = {&gpu.ev1, &gpu.ev2, &gpu.ev3};
    for (int k = 0; k < 3; ++k) {
      const std::string name = pre + "ev" + std::to_string(k + 1);
      const auto golden = file.get(name).to_f32();  // NumPy float64 + np.add.at
      // Where float64 rounds a non-dyadic row time that sits on an integer event time, the tool
      // also stored the exact (fractions.Fraction) answer and how many cells float64 got wrong.
      const auto exact = file.has(name + "_exact") ? file.get(name + "_exact").to_f32() : golden;
      const size_t float64_wrong = c["float64_differs_from_exact"][k].get<size_t>();
      ASSERT_EQ(golden.size(), mine_cpu[k]->size()) << c["name"] << " ev" << k + 1;
      size_t diff_cpu = 0, diff_gpu = 0, diff_float64 = 0;
      double total = 0;
      for (size_t i = 0; i < golden.size(); ++i) {
        diff_cpu += exact[i] != (*mine_cpu[k])[i];
        diff_gpu += exact[i] != (*mine_gpu[k])[i];
        diff_float64 += golden[i] != (*mine_cpu[k])[i];
        total += golden[i];
      }
      EXPECT_EQ(diff_cpu, 0u) << c["name"] << " ev" << k + 1 << ": CPU differs from the reference";
      EXPECT_EQ(diff_gpu, 0u) << c["name"] << " ev" << k + 1 << ": GPU differs from the reference";
      EXPECT_EQ(diff_float64, float64_wrong) << c["name"] << " ev" << k + 1;
      EXPECT_GT(total, 50) << c["name"] << " ev" << k + 1;
    }
  }
}

// The sparse path keeps its outputs between builds and only undoes the cells the previous build
// counted: successive builds with other events, other pairs, another layout and chunking must
// each equal the CPU reference exactly (a stale count from an earlier build would show here).
TEST(EventTensor, SparseBuildsReuseTheirOutputExactly) {
  RowTiming tm{R("0"), R("1000/7"), R("900"), 12, Readout::top_down};
  const std::vector<std::tuple<std::vector<const char*>, int, uint32_t, size_t>> steps = {
      {{"0.5"}, 16, 1, 0},
      {{"0.5"}, 16, 2, 0},              // same layout, other events: undo, then count
      {{"0.1"}, 16, 2, 0},              // other target
      {{"0", "0.7", "1.3"}, 16, 3, 0},  // a batch: new layout
      {{"0", "0.7", "1.3"}, 16, 4, 0},
      {{"0", "0.7", "1.3"}, 16, 4, 2},  // chunks of at most 2 jobs
      {{"0", "0.7", "1.3"}, 16, 5, 2},
      {{"0.5"}, 5, 5, 0},               // other bins
      {{"0.5"}, 5, 6, 0}};
  EventTensorBuilder b(vktest::context());
  // build() into reused host tensors, then build_resident(): each keeps its own layout.
  for (const bool resident : {false, true}) {
    EventTensors reused;
    const float* storage = nullptr;
    int step = 0;
    for (const auto& [taus, bins, seed, chunk] : steps) {
      std::vector<EventTensorPair> pairs;
      for (const char* tau : taus) pairs.push_back({tm, tm.target_time(R(tau)), std::nullopt});
      const auto ev = random_stream(16, 12, 6000, -500, 3500, seed);
      const EventTensorSpec spec{bins, {}};
      const auto cpu = build_event_tensors_ref(ev, pairs, spec);
      const std::string what = std::string(resident ? "resident" : "build") + " step " + std::to_string(step++);
      if (resident) {
        if (chunk) continue;  // one tensor, no chunks
        const Tensor& dev = b.build_resident(ev, pairs, spec);
        const auto all = dev.download<float>();
        const size_t n = cpu.ev1.size();
        ASSERT_EQ(all.size(), 3 * n);
        EXPECT_TRUE(std::equal(cpu.ev1.begin(), cpu.ev1.end(), all.begin())) << what;
        EXPECT_TRUE(std::equal(cpu.ev2.begin(), cpu.ev2.end(), all.begin() + n)) << what;
        EXPECT_TRUE(std::equal(cpu.ev3.begin(), cpu.ev3.end(), all.begin() + 2 * n)) << what;
      } else {
        b.set_chunk_limits(chunk, 0);
        b.build(ev, pairs, spec, reused);
        EXPECT_EQ(cpu.ev1, reused.ev1) << what;
        EXPECT_EQ(cpu.ev2, reused.ev2) << what;
        EXPECT_EQ(cpu.ev3, reused.ev3) << what;
        EXPECT_EQ(cpu.events_considered, reused.events_considered) << what;
        if (step == 2) {
          EXPECT_EQ(storage, reused.ev1.data()) << "a repeated shape reuses the host storage";
        }
        storage = reused.ev1.data();
      }
      EXPECT_EQ(b.last_algorithm(), EventBinAlgorithm::sparse) << what;
    }
    b.set_chunk_limits(0, 0);
  }
  // A dense algorithm in between leaves the sparse state alone; the next sparse build is exact.
  std::vector<EventTensorPair> pairs = {{tm, tm.target_time(R("0.4")), std::nullopt}};
  const EventTensorSpec spec{16, {}};
  b.set_algorithm(EventBinAlgorithm::per_row);
  (void)b.build(random_stream(16, 12, 6000, -500, 3500, 7), pairs, spec);
  EXPECT_THROW((void)b.build_resident(random_stream(16, 12, 100, -500, 3500, 7), pairs, spec), Error);
  b.set_algorithm(EventBinAlgorithm::sparse);
  auto ev = random_stream(16, 12, 6000, -500, 3500, 8);
  EXPECT_EQ(build_event_tensors_ref(ev, pairs, spec).ev2, b.build(ev, pairs, spec).ev2);
  EXPECT_THROW((void)b.build_on_device(ev, pairs, spec), Error);  // its tensor would be the builder's
}
