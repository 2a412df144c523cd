// Sequence folders: the generic layout and the reference datasets' layouts, built tiny in a temp
// dir; timing derivation, overrides, clear errors; value lists; `vkunroll voxelize` end to end.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>

#include "event_test_encoders.hpp"
#include "event_test_util.hpp"
#include "vkunroll/host/events/event_writer.hpp"
#include "vkunroll/host/model/safetensors.hpp"
#include "vkunroll/host/events/sequence.hpp"
#include "vkunroll/host/sim/recording.hpp"
#include "vkunroll/host/unroll/value_list.hpp"
#include "vkunroll/kernels/event_tensor.hpp"
#include "vkunroll/base/error.hpp"

using namespace vkunroll;
namespace fs = std::filesystem;

namespace {

Rational R(const std::string& s) { return Rational::parse(s); }

fs::path fresh_dir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("vkunroll_seq_" + std::to_string(::getpid())) / name;
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

void png(const fs::path& p, int w, int h) {
  fs::create_directories(p.parent_path());
  cv::Mat m(h, w, CV_8UC3, cv::Scalar(10, 20, 30));
  ASSERT_TRUE(cv::imwrite(p.string(), m));
}

void text(const fs::path& p, const std::string& s) {
  std::ofstream(p) << s;
}

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// A generic sequence: 16x12 sensor, 3 frames, events from write_events_hdf5.
fs::path make_generic(const std::string& name, const EventStream& ev) {
  const fs::path d = fresh_dir(name);
  for (int k = 0; k < 3; ++k) png(d / "rs" / ("00000" + std::to_string(k) + ".png"), 16, 12);
  write_events_hdf5((d / "events.h5").string(), ev);
  text(d / "meta.json", R"({"width": 16, "height": 12, "line_delay_us": "1000/7", "exposure_us": 900.5,
    "readout": "top-down", "events": "events.h5",
    "frames": [{"file": "rs/000000.png", "t0_us": 1000}, {"file": "rs/000001.png", "t0_us": 4000},
               {"file": "rs/000002.png", "t0_us": 7000.25}],
    "ground_truth": [{"file": "rs/000000.png", "t_us": 1500}]})");
  return d;
}

}  // namespace

TEST(Sequence, ValueAndFrameLists) {
  auto v = parse_value_list("0:1:5", "--times");
  ASSERT_EQ(v.size(), 5u);
  EXPECT_EQ(v[1], R("1/4"));
  EXPECT_EQ(v[4], R("1"));
  v = parse_value_list("-0.25,0.5,1.25,1/3", "--times");
  ASSERT_EQ(v.size(), 4u);
  EXPECT_EQ(v[0], R("-1/4"));
  EXPECT_EQ(v[3], R("1/3"));
  EXPECT_EQ(parse_value_list("2:9:1", "x"), std::vector<Rational>{R("2")});
  EXPECT_EQ(parse_frame_list("0:3", "--frames"), (std::vector<int>{0, 1, 2, 3}));
  EXPECT_EQ(parse_frame_list("0:8:5,11", "--frames"), (std::vector<int>{0, 2, 4, 6, 8, 11}));
  EXPECT_NE(error_of([] { parse_frame_list("0:1:3", "--frames"); }).find("--frames"), std::string::npos);
  EXPECT_THROW(parse_value_list("0:1", "--times"), Error);
  EXPECT_THROW(parse_value_list("1,,2", "--times"), Error);
  EXPECT_THROW(parse_value_list("0:1:0", "--times"), Error);
  EXPECT_THROW(parse_frame_list("-1", "--frames"), Error);
  // Each value once (issue 28: a list refuses duplicates), naming the value; a range that overlaps a value too.
  EXPECT_NE(error_of([] { parse_frame_list("1,0:2", "--frames"); }).find("frame 1 is listed twice"), std::string::npos);
  EXPECT_NE(error_of([] { parse_value_list("0.5,1/2", "--times"); }).find("--times: value 1/2 is listed twice"), std::string::npos);
  EXPECT_THROW(parse_frame_list("0:2000000", "--frames"), Error);
}

TEST(Sequence, GenericLayoutTimingAndOverrides) {
  auto ev = evtest::random_stream(2000, 16, 12, 3, 0, 5);
  const fs::path d = make_generic("generic", ev);
  EXPECT_EQ(detect_sequence_layout(d.string()), SequenceLayout::generic);
  const Sequence s = load_sequence(d.string());
  EXPECT_EQ(s.width, 16);
  EXPECT_EQ(s.height, 12);
  ASSERT_EQ(s.frames.size(), 3u);
  EXPECT_EQ(s.frames[2].timing.t0, R("7000.25"));
  EXPECT_EQ(s.frames[0].timing.line_delay, R("1000/7"));
  EXPECT_EQ(s.frames[0].timing.exposure, R("1801/2"));
  EXPECT_EQ(s.frames[0].timing.rows, 12);
  ASSERT_EQ(s.ground_truth.size(), 1u);
  EXPECT_EQ(s.ground_truth[0].t_us, R("1500"));
  const EventStream w = s.read_events(1000, 3000);
  ASSERT_FALSE(w.empty());
  EXPECT_GE(w.t.front(), 1000);
  EXPECT_LT(w.t.back(), 3000);
  EXPECT_THROW(s.frame(3), Error);

  SequenceOptions o;
  o.line_delay_us = R("100");
  o.exposure_us = R("50");
  o.readout = Readout::bottom_up;
  o.t0s_us = std::vector<Rational>{R("1"), R("2000"), R("4000")};  // 2000 us apart: readout 11 x 100 us fits
  const Sequence s2 = load_sequence(d.string(), o);
  EXPECT_EQ(s2.frames[1].timing.t0, R("2000"));
  EXPECT_EQ(s2.frames[1].timing.start(11), R("2000"));  // bottom-up: the last row is read first
  o.t0s_us = std::vector<Rational>{R("1"), R("2"), R("3")};  // inside the readout: the options' fault
  try {
    load_sequence(d.string(), o);
    ADD_FAILURE() << "t0s inside the readout were accepted";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::usage) << e.what();
    EXPECT_NE(std::string(e.what()).find("readout-within-frame-period"), std::string::npos) << e.what();
  }
  EXPECT_EQ(s2.frames[1].timing.exposure, R("50"));
  o.t0s_us = std::vector<Rational>{R("1")};
  EXPECT_NE(error_of([&] { load_sequence(d.string(), o); }).find("3 frames"), std::string::npos);
}

TEST(Sequence, GenericLayoutErrorsNameFileAndField) {
  auto ev = evtest::random_stream(100, 16, 12, 3, 0, 5);
  const fs::path d = make_generic("generic_bad", ev);
  const std::string meta = (d / "meta.json").string();
  text(meta, "{ not json");
  EXPECT_NE(error_of([&] { load_sequence(d.string()); }).find("meta.json: not valid JSON"), std::string::npos);
  text(meta, R"({"width": 16, "height": 12, "line_delay_us": 10, "exposure_us": 5, "events": "events.h5",
                 "frames": [{"file": "rs/000000.png", "t0_us": "abc"}]})");
  auto e = error_of([&] { load_sequence(d.string()); });
  EXPECT_NE(e.find("frames[0].t0_us"), std::string::npos) << e;
  text(meta, R"({"width": -3, "height": 12})");
  EXPECT_NE(error_of([&] { load_sequence(d.string()); }).find("meta.json:width"), std::string::npos);
  text(meta, R"({"width": 16, "height": 12, "exposure_us": 5, "events": "events.h5", "frames": []})");
  EXPECT_NE(error_of([&] { load_sequence(d.string()); }).find("line_delay_us"), std::string::npos);
  text(meta, R"({"width": 16, "height": 12, "line_delay_us": 10, "exposure_us": 5, "readout": "diagonal",
                 "events": "events.h5", "frames": [{"file": "rs/000000.png", "t0_us": 0}]})");
  EXPECT_NE(error_of([&] { load_sequence(d.string()); }).find("readout"), std::string::npos);
  // A frame of the wrong size.
  png(d / "rs" / "big.png", 20, 12);
  text(meta, R"({"width": 16, "height": 12, "line_delay_us": 10, "exposure_us": 5, "events": "events.h5",
                 "frames": [{"file": "rs/big.png", "t0_us": 0}]})");
  e = error_of([&] { load_sequence(d.string()); });
  EXPECT_NE(e.find("big.png"), std::string::npos) << e;
  EXPECT_NE(e.find("20x12"), std::string::npos) << e;
  // Missing meta.json and no other layout.
  fs::remove(meta);
  EXPECT_NE(error_of([&] { load_sequence(d.string()); }).find("cannot tell the layout"), std::string::npos);
  SequenceOptions o;
  o.layout = SequenceLayout::generic;
  EXPECT_NE(error_of([&] { load_sequence(d.string(), o); }).find("no meta.json"), std::string::npos);
}

TEST(Sequence, EventsOutsideTheSensorAreAnErrorNamingTheFile) {
  auto ev = evtest::random_stream(100, 16, 12, 3, 0, 5);
  ev.width = 40;  // the file says 40 wide; meta.json says 16
  ev.x[50] = 30;
  const fs::path d = make_generic("generic_oob", ev);
  const Sequence s = load_sequence(d.string());
  const auto e = error_of([&] { s.read_events(0, 1 << 20); });
  EXPECT_NE(e.find("events.h5"), std::string::npos) << e;
  SequenceOptions o;
  o.events.on_bad = BadEventPolicy::drop;
  EventReadReport rep;
  const EventStream kept = load_sequence(d.string(), o).read_events(0, 1 << 20, &rep);
  EXPECT_EQ(kept.size(), 99u);
  EXPECT_EQ(rep.dropped_out_of_sensor, 1u);
}

TEST(Sequence, GevRsLayout) {
  const fs::path d = fresh_dir("gevrs");
  for (int k = 0; k < 3; ++k) png(d / "rs" / (std::to_string(k) + ".png"), 16, 12);
  for (int k = 0; k < 12; ++k) png(d / "gs" / (std::to_string(k) + ".png"), 16, 12);
  auto ev = evtest::random_stream(500, 16, 12, 4, 0, 200);
  evtest::write_h5_nx4((d / "seq.h5").string(), ev, H5T_STD_I64LE, true);
  EXPECT_EQ(detect_sequence_layout(d.string()), SequenceLayout::gev_rs);
  const Sequence s = load_sequence(d.string());
  ASSERT_EQ(s.frames.size(), 3u);
  EXPECT_EQ(s.frames[2].timing.t0, R("40000"));  // GS frame 200 at 200 us
  EXPECT_EQ(s.frames[2].timing.line_delay, R("200"));
  EXPECT_EQ(s.frames[2].timing.exposure, R("3200"));
  EXPECT_EQ(s.ground_truth.size(), 12u);
  EXPECT_EQ(s.ground_truth[11].t_us, R("2200"));
  EXPECT_EQ(fs::path(s.frames[2].image).filename(), "2.png");  // natural order
  SequenceOptions half;
  half.gev_half_row = true;
  const Sequence h = load_sequence(d.string(), half);
  EXPECT_EQ(h.frames[1].timing.line_delay, R("100"));
  EXPECT_EQ(h.frames[1].timing.exposure, R("1600"));
  EXPECT_EQ(s.read_events(0, 1 << 30).size(), 500u);
}

TEST(Sequence, DreLayout) {
  const fs::path d = fresh_dir("dre");
  for (int k = 0; k < 3; ++k) png(d / "images" / (std::to_string(k) + ".png"), 16, 12);
  auto ev = evtest::random_stream(300, 16, 12, 5, 0, 5);
  evtest::write_h5_dre((d / "rec.h5").string(), ev);
  EXPECT_EQ(detect_sequence_layout(d.string()), SequenceLayout::dre);
  const Sequence s = load_sequence(d.string());
  ASSERT_EQ(s.frames.size(), 3u);
  EXPECT_EQ(s.frames[1].timing.t0, R("950"));
  EXPECT_EQ(s.frames[1].timing.exposure, R("100"));
  EXPECT_EQ(s.frames[1].timing.line_delay, R("70"));
  // An image without a timestamp is an error naming the h5 file.
  png(d / "images" / "3.png", 16, 12);
  const auto e = error_of([&] { load_sequence(d.string()); });
  EXPECT_NE(e.find("rec.h5"), std::string::npos) << e;
  EXPECT_NE(e.find("4 images"), std::string::npos) << e;
}

TEST(Sequence, GevRsRealAndFastecLayouts) {
  const fs::path g = fresh_dir("0815_5000_73000");
  for (int k = 0; k < 2; ++k) png(g / "image" / (std::to_string(k) + ".png"), 16, 12);
  text(g / "events.npz", "not read when t0s are given");
  EXPECT_EQ(detect_sequence_layout(g.string()), SequenceLayout::gev_rs_real);
  SequenceOptions o;
  o.t0s_us = std::vector<Rational>{R("100"), R("48200")};
  const Sequence s = load_sequence(g.string(), o);
  EXPECT_EQ(s.frames[0].timing.exposure, R("5000"));
  EXPECT_EQ(s.frames[0].timing.line_delay, R("73000/11"));  // readout / (H - 1)
  EXPECT_EQ(s.frames[1].timing.t0, R("48200"));

  const fs::path f = fresh_dir("fastec");
  for (int k = 0; k < 2; ++k) png(f / "RS" / (std::to_string(k) + ".png"), 16, 12);
  text(f / "events" / "0.npz", "x");
  fs::create_directories(f / "events");
  text(f / "events" / "0.npz", "x");
  text(f / "events" / "1.npz", "x");
  EXPECT_EQ(detect_sequence_layout(f.string()), SequenceLayout::fastec);
  const Sequence fs_ = load_sequence(f.string());
  EXPECT_EQ(fs_.event_files.size(), 2u);
  EXPECT_EQ(fs_.frames[1].timing.line_delay, R("625/3"));
  EXPECT_EQ(fs_.frames[1].timing.t0, R("1250/3") * R("260"));
}

TEST(Sequence, VoxelizeCliMatchesTheLibrary) {
  auto ev = evtest::random_stream(6000, 16, 12, 9, 0, 3);
  const fs::path d = make_generic("voxelize", ev);
  const std::string out = d.string() + "-ev.safetensors";  // beside the sequence: never inside an input
  const std::string cmd = std::string(VKUNROLL_CLI_PATH) + " voxelize " + d.string() +
                          " --frames 0:1 --times 0:1:3 --bins 4 --crop 2,1,10,9 --out " + out + " > " +
                          (d / "log.txt").string() + " 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << std::ifstream(d / "log.txt").rdbuf();
  const auto f = read_safetensors(out);
  const auto& ev1 = f.get("ev1");
  EXPECT_EQ(ev1.shape, (std::vector<int64_t>{6, 8, 9, 10}));
  const Sequence s = load_sequence(d.string());
  std::vector<EventTensorPair> pairs;
  for (int k : {0, 1})
    for (const char* tau : {"0", "0.5", "1"})
      pairs.push_back({s.frames[k].timing, s.frames[k].timing.target_time(R(tau)), std::nullopt});
  const auto want = build_event_tensors_ref(s.read_events(-100000, 100000), pairs, {4, {2, 1, 10, 9}});
  EXPECT_EQ(f.get("ev1").to_f32(), want.ev1);
  EXPECT_EQ(f.get("ev2").to_f32(), want.ev2);
  EXPECT_EQ(f.get("ev3").to_f32(), want.ev3);
  double total = 0;
  for (float v : want.ev2) total += v;
  EXPECT_GT(total, 100);
  EXPECT_NE(f.metadata.at("pairs").find("t_star_us"), std::string::npos);
  // Bad arguments are clear errors.
  const std::string bad = std::string(VKUNROLL_CLI_PATH) + " voxelize " + d.string() +
                          " --frames 7 --times 0.5 --out " + out + " --overwrite > " + (d / "err.txt").string() + " 2>&1";
  EXPECT_NE(std::system(bad.c_str()), 0);
  std::stringstream err;
  err << std::ifstream(d / "err.txt").rdbuf();
  EXPECT_NE(err.str().find("frame 7"), std::string::npos) << err.str();
  fs::remove(out);
}

TEST(Sequence, ReadsWhatTheSimulatorWrites) {
  // The project's own writer (host/sim_sequence) and this loader must agree on the generic layout.
  sim::SimulationConfig c = sim::simulation_preset("clean");
  c.width = 24;
  c.height = 16;
  c.frames = 2;
  c.gt_per_frame = 2;
  c.fps = 200;
  c.line_delay_us = 125.5;
  c.exposure_us = 700;
  c.lead_in_us = 1000;
  c.readout = "bottom-up";
  const sim::SimulatedSequence simulated = sim::simulate(c);
  const fs::path d = fresh_dir("simulated");
  sim::write_sequence(c, simulated, d.string());
  const Sequence s = load_sequence(d.string());
  EXPECT_EQ(s.layout, SequenceLayout::generic);
  ASSERT_EQ(s.frames.size(), 2u);
  EXPECT_EQ(s.width, 24);
  EXPECT_EQ(s.frames[1].timing.t0, Rational::from_double(c.frame_t0_us(1)));
  EXPECT_EQ(s.frames[1].timing.line_delay, R("251/2"));
  EXPECT_EQ(s.frames[1].timing.readout, Readout::bottom_up);
  for (int y : {0, 7, 15})
    EXPECT_EQ(s.frames[1].timing.start(y).to_double(), c.row_start_us(1, y));
  EXPECT_EQ(s.ground_truth.size(), simulated.gt.size());
  const EventStream ev = s.read_events(0, 1 << 30);
  EXPECT_EQ(ev.t, simulated.events.t);
  // ev3 over a window holding the whole stream counts every event exactly once.
  ASSERT_GT(ev.size(), 0u);
  const EventTensorPair pair{s.frames[0].timing, Rational(ev.t.front()), Rational(ev.t.back() - ev.t.front() + 1)};
  const auto t = build_event_tensors_ref(ev, {pair}, {16, {}});
  double total = 0;
  for (float x : t.ev3) total += x;
  EXPECT_EQ(total, static_cast<double>(ev.size()));
}

TEST(Sequence, GevRsRealInfersTheFrameRateFromTheRecording) {
  // Three frames and events spanning 3 x 51000 us: closer to 19.61 fps (50994 us) than 20.79.
  const fs::path g = fresh_dir("0001_8000_60000");
  for (int k = 0; k < 3; ++k) png(g / "image" / (std::to_string(k) + ".png"), 16, 12);
  const std::string py = "/usr/bin/python3 -c \"import numpy as np; n=4000; "
                         "r=np.zeros(n, dtype=[('x','<u2'),('y','<u2'),('p','|b1'),('t','<i8')]); "
                         "r['t']=np.linspace(5000, 5000+153000, n).astype(np.int64); r['x']=np.arange(n)%16; "
                         "r['y']=np.arange(n)%12; r['p']=np.arange(n)%2==0; np.savez('" +
                         (g / "events.npz").string() + "', event=r)\"";
  if (std::system(py.c_str()) != 0) GTEST_SKIP() << "/usr/bin/python3 with numpy is needed to write the .npz";
  const Sequence s = load_sequence(g.string());
  EXPECT_EQ(s.layout, SequenceLayout::gev_rs_real);
  ASSERT_EQ(s.frames.size(), 3u);
  EXPECT_EQ(s.frames[0].timing.t0, R("5000"));
  EXPECT_EQ(s.frames[2].timing.t0, R("5000") + R("2") * R("100000000/1961"));
  EXPECT_EQ(s.frames[0].timing.exposure, R("8000"));
  EXPECT_EQ(s.frames[0].timing.line_delay, R("60000/11"));
  EXPECT_EQ(s.read_events(0, 1 << 30).size(), 4000u);
  SequenceOptions o;
  o.frame_period_us = R("48000");
  EXPECT_EQ(load_sequence(g.string(), o).frames[1].timing.t0, R("53000"));
}

// ---- issue 18: nothing silent (each of these failed before its fix) ---------------------------

namespace {

// A generic sequence of `frames` 16x12 frames, t0 = 1000 k, events.txt holding `events_txt`.
fs::path make_text_sequence(const std::string& name, int frames, const std::string& events_txt,
                            const std::string& t0s = "") {
  const fs::path d = fresh_dir(name);
  std::string list;
  for (int k = 0; k < frames; ++k) {
    char file[32];
    std::snprintf(file, sizeof file, "rs/%06d.png", k);
    png(d / file, 16, 12);
    list += std::string(k ? ", " : "") + "{\"file\": \"" + file + "\", \"t0_us\": " + std::to_string(1000 * k) + "}";
  }
  text(d / "events.txt", events_txt);
  text(d / "meta.json", "{\"width\": 16, \"height\": 12, \"line_delay_us\": 10, \"exposure_us\": 500, \"events\": "
                        "\"events.txt\", \"frames\": [" + (t0s.empty() ? list : t0s) + "]}");
  return d;
}

}  // namespace

// A generic sequence whose meta.json was deleted (rs/, gs/, the project's events.h5) used to be
// read as Gev-RS with its 200 us / 3200 us convention, silently.
TEST(SequenceReliability, MissingMetaJsonIsRefusedNotGuessedAsGevRs) {
  const fs::path d = fresh_dir("no_meta");
  for (int k = 0; k < 3; ++k) png(d / "rs" / (std::to_string(k) + ".png"), 16, 12);
  for (int k = 0; k < 3; ++k) png(d / "gs" / (std::to_string(k) + ".png"), 16, 12);
  write_events_hdf5((d / "events.h5").string(), evtest::random_stream(300, 16, 12, 40, 0, 5));
  const std::string e = error_of([&] { load_sequence(d.string()); });
  for (const char* part : {"no_meta", "no meta.json", "rs/ (3 images)", "gs/ (3 images)", "events.h5",
                           "events/{t,x,y,p}", "meta.json is missing", "with layout gev-rs"})
    EXPECT_NE(e.find(part), std::string::npos) << "missing '" << part << "' in: " << e;
  // Choosing the layout explicitly still works.
  SequenceOptions o;
  o.layout = SequenceLayout::gev_rs;
  EXPECT_EQ(load_sequence(d.string(), o).frames[1].timing.line_delay, R("200"));
  // The same folder with Gev-RS's own N x 4 events + img_to_idx is unambiguous (GevRsLayout test).
  fs::remove(d / "events.h5");
  evtest::write_h5_nx4((d / "seq.h5").string(), evtest::random_stream(300, 16, 12, 40, 0, 5), H5T_STD_I64LE, true);
  EXPECT_EQ(detect_sequence_layout(d.string()), SequenceLayout::gev_rs);
  // DRE's timing needs its timestamps in the file; Fastec one .npz per frame.
  const fs::path r = fresh_dir("no_meta_dre");
  png(r / "images" / "0.png", 16, 12);
  write_events_hdf5((r / "events.h5").string(), evtest::random_stream(30, 16, 12, 41, 0, 5));
  EXPECT_NE(error_of([&] { detect_sequence_layout(r.string()); }).find("DRE needs"), std::string::npos);
  const fs::path f = fresh_dir("no_meta_fastec");
  for (int k = 0; k < 5; ++k) png(f / "RS" / (std::to_string(k) + ".png"), 16, 12);
  text(f / "events.npz", "x");
  EXPECT_NE(error_of([&] { detect_sequence_layout(f.string()); }).find("5 frames, 1 .npz"), std::string::npos);
}

// A t0 near the int64 limit gave a window ending at -9223372036854775807; swapped t0s reported the
// recording as [110000, 17700]. Both are now errors at load naming the field and the frame.
TEST(SequenceReliability, FrameTimesOutOfRangeOrOutOfOrderNameTheFieldAndFrame) {
  const std::string frames_huge =
      R"({"file": "rs/000000.png", "t0_us": 0}, {"file": "rs/000001.png", "t0_us": 9223372036854775000})";
  fs::path d = make_text_sequence("t0_huge", 2, "10 1 1 1\n", frames_huge);
  std::string e = error_of([&] { load_sequence(d.string()); });
  for (const char* part : {"meta.json:frames[1].t0_us = 9223372036854775000", "2^53"})
    EXPECT_NE(e.find(part), std::string::npos) << "missing '" << part << "' in: " << e;
  const std::string frames_beyond = R"({"file": "rs/000000.png", "t0_us": 18446744073709551615})";
  d = make_text_sequence("t0_beyond", 1, "10 1 1 1\n", frames_beyond);
  e = error_of([&] { load_sequence(d.string()); });
  EXPECT_NE(e.find("frames[0].t0_us"), std::string::npos) << e;
  const std::string frames_swapped =
      R"({"file": "rs/000000.png", "t0_us": 110000}, {"file": "rs/000001.png", "t0_us": 17700})";
  d = make_text_sequence("t0_swapped", 2, "10 1 1 1\n", frames_swapped);
  e = error_of([&] { load_sequence(d.string()); });
  for (const char* part : {"frames[1].t0_us", "frame 1", "17700", "110000", "t0s must increase"})
    EXPECT_NE(e.find(part), std::string::npos) << "missing '" << part << "' in: " << e;
  SequenceOptions o;  // the same through the --t0s-us option
  o.t0s_us = std::vector<Rational>{R("5000"), R("5000")};
  d = make_text_sequence("t0_option", 2, "10 1 1 1\n");
  e = error_of([&] { load_sequence(d.string(), o); });
  EXPECT_NE(e.find("t0s value 2"), std::string::npos) << e;
  text(d / "meta.json", R"({"width": 16, "height": 12, "line_delay_us": 10, "exposure_us": 1e300, "events": "events.txt",
                            "frames": [{"file": "rs/000000.png", "t0_us": 0}]})");
  e = error_of([&] { load_sequence(d.string()); });
  EXPECT_NE(e.find("exposure_us"), std::string::npos) << e;
}

// An empty event file gave exit 0 and the RS input back with nothing said; now the stream is
// empty without an error and the totals say "no event records".
TEST(SequenceReliability, EmptyEventFileIsVisibleInTheTotals) {
  const fs::path d = make_text_sequence("empty_events", 3, "");
  const Sequence s = load_sequence(d.string());
  EventReadReport rep;
  EXPECT_TRUE(s.read_events(0, 5000, &rep).empty());
  EXPECT_TRUE(rep.empty_file);
  const EventTotals t = s.event_totals();
  EXPECT_EQ(t.records, 0u);
  EXPECT_EQ(t.empty_files, 1u);
  EXPECT_EQ(t.reads, 1u);
  EXPECT_NE(t.summary().find("no event records"), std::string::npos) << t.summary();
  EXPECT_NE(t.summary().find("empty"), std::string::npos) << t.summary();
}

// --on-bad drop never said how many it dropped. The totals count each record once, however many
// overlapping frame windows read it.
TEST(SequenceReliability, DroppedEventsAreCountedOnceAcrossOverlappingWindows) {
  std::string ev;
  uint64_t n = 0, out_of_order = 0;
  for (int i = 0; i < 22219; ++i, ++n) {
    const int64_t t = 10 + i / 2;
    const bool late = i % 2 == 1;  // every other record 5 us early: out of time order
    out_of_order += late && i > 1;
    ev += std::to_string(late ? std::max<int64_t>(t - 5, 0) : t) + " " + std::to_string(i % 16) + " " +
          std::to_string(i % 12) + " 1\n";
  }
  const fs::path d = make_text_sequence("drops", 12, ev);
  SequenceOptions o;
  o.events.on_bad = BadEventPolicy::drop;
  const Sequence s = load_sequence(d.string(), o);
  EventReadReport full;
  EventReadOptions ro = s.event_options;
  read_events(s.event_files[0], ro, &full);
  ASSERT_GT(full.dropped_time_order, 10000u);
  uint64_t summed = 0;
  for (int k = 0; k + 1 < 12; ++k) {  // windows over frames k and k+1: each event is read twice
    EventReadReport r;
    s.read_events(1000 * k, 1000 * (k + 2), &r);
    summed += r.dropped_time_order;
  }
  const EventTotals t = s.event_totals();
  EXPECT_EQ(t.records, n);
  EXPECT_EQ(t.dropped_time_order, full.dropped_time_order);
  EXPECT_EQ(t.valid, full.kept);
  EXPECT_GT(summed, t.dropped_time_order);  // the per-read counts overlap; the totals do not
  EXPECT_NE(t.summary().find(std::to_string(full.dropped_time_order) + " out of time order"), std::string::npos)
      << t.summary();
  (void)out_of_order;
}

// Images listed in meta.json that cannot be read: missing, a folder, garbage, cut short.
TEST(SequenceReliability, UnreadableFrameAndGroundTruthImagesAreClearErrors) {
  fs::path d = make_text_sequence("bad_images", 2, "10 1 1 1\n");
  const fs::path img = d / "rs" / "000001.png";
  const std::string png_bytes = [&] {
    std::ifstream f(img, std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(f)), {});
  }();
  text(img, png_bytes.substr(0, png_bytes.size() - 20));  // cut short
  std::string e = error_of([&] { load_sequence(d.string()); });
  EXPECT_NE(e.find("000001.png"), std::string::npos) << e;
  EXPECT_NE(e.find("truncated PNG"), std::string::npos) << e;
  text(img, "not an image at all");
  e = error_of([&] { load_sequence(d.string()); });
  EXPECT_NE(e.find("000001.png: not a readable image"), std::string::npos) << e;
  fs::remove(img);
  EXPECT_NE(error_of([&] { load_sequence(d.string()); }).find("does not exist"), std::string::npos);
  fs::create_directories(img);
  EXPECT_NE(error_of([&] { load_sequence(d.string()); }).find("is a folder"), std::string::npos);
  d = make_text_sequence("bad_gt", 1, "10 1 1 1\n");
  text(d / "meta.json", R"({"width": 16, "height": 12, "line_delay_us": 10, "exposure_us": 5, "events": "events.txt",
                            "frames": [{"file": "rs/000000.png", "t0_us": 0}],
                            "ground_truth": [{"file": "gs/missing.png", "t_us": 3}]})");
  e = error_of([&] { load_sequence(d.string()); });
  EXPECT_NE(e.find("ground-truth image"), std::string::npos) << e;
  EXPECT_NE(e.find("gs/missing.png"), std::string::npos) << e;
}

// A 200-frame text sequence read frame by frame through the Sequence equals one-off reads.
TEST(SequenceReliability, TwoHundredFrameWindowsEqualOneOffReads) {
  const EventStream ev = evtest::random_stream(60000, 16, 12, 43, 0, 6);
  std::string lines = "# width 16 height 12\n";
  for (size_t i = 0; i < ev.size(); ++i)
    lines += std::to_string(ev.t[i]) + " " + std::to_string(ev.x[i]) + " " + std::to_string(ev.y[i]) + " " +
             (ev.p[i] > 0 ? "1\n" : "0\n");
  const fs::path d = make_text_sequence("frames200", 200, lines);
  const Sequence s = load_sequence(d.string());
  for (int k = 0; k < 200; ++k) {
    EventReadOptions o = s.event_options;
    o.t_begin_us = 1000 * k - 250;
    o.t_end_us = 1000 * k + 1750;
    const EventStream want = read_events(s.event_files[0], o);
    const EventStream got = s.read_events(*o.t_begin_us, *o.t_end_us);
    ASSERT_EQ(want.t, got.t) << "frame " << k;
    ASSERT_EQ(want.x, got.x) << "frame " << k;
  }
  EXPECT_EQ(s.event_totals().records, ev.size());
  EXPECT_EQ(s.event_totals().reads, 200u);
}

// Fastec's per-frame .npz files: each window reads only the files whose rows overlap it (each file
// opened once), and returns the merged events of a full read of every file.
TEST(SequenceReliability, PerFrameFilesAreSkippedOutsideTheWindow) {
  const fs::path d = fresh_dir("fastec_files");
  const int frames = 20;
  EventStream all;
  for (int k = 0; k < frames; ++k) {
    png(d / "RS" / (std::to_string(k) + ".png"), 16, 12);
    const EventStream ev = evtest::random_stream(300, 16, 12, uint32_t(60 + k), 100000 * k, 550);
    std::vector<std::pair<std::string, std::vector<uint8_t>>> members;
    auto column = [&](const char* name, const std::string& descr, auto get) {
      std::vector<uint8_t> b;
      for (size_t i = 0; i < ev.size(); ++i) {
        const int64_t v = get(i);
        for (int byte = 0; byte < (descr == "<i8" ? 8 : 2); ++byte) b.push_back(uint8_t(uint64_t(v) >> (8 * byte)));
      }
      members.emplace_back(std::string(name) + ".npy", evtest::encode_npy("{'descr': '" + descr + "', 'fortran_order': False, "
                                                                           "'shape': (" + std::to_string(ev.size()) + ",), }", b));
    };
    column("x", "<i2", [&](size_t i) { return int64_t(ev.x[i]); });
    column("y", "<i2", [&](size_t i) { return int64_t(ev.y[i]); });
    column("p", "<i2", [&](size_t i) { return int64_t(ev.p[i] > 0 ? 1 : 0); });
    column("t", "<i8", [&](size_t i) { return ev.t[i]; });
    fs::create_directories(d / "events");
    evtest::write_npz((d / "events" / (std::to_string(k) + ".npz")).string(), members, k % 2 == 0);
    for (size_t i = 0; i < ev.size(); ++i) all.push(ev.t[i], ev.x[i], ev.y[i], ev.p[i]);
  }
  EXPECT_EQ(detect_sequence_layout(d.string()), SequenceLayout::fastec);
  for (const BadEventPolicy policy : {BadEventPolicy::error, BadEventPolicy::sort}) {
    SequenceOptions o;
    o.events.on_bad = policy;
    const Sequence s = load_sequence(d.string(), o);
    for (int k = 0; k + 1 < frames; ++k) {
      const int64_t a = 100000 * k + 50000, b = a + 100000;
      EventReadReport rep;
      const EventStream got = s.read_events(a, b, &rep);
      std::vector<int64_t> want;
      for (int64_t t : all.t)
        if (t >= a && t < b) want.push_back(t);
      std::sort(want.begin(), want.end());
      ASSERT_EQ(got.t, want) << "window " << k;
      if (policy == BadEventPolicy::error || k > 0) {  // sort learns each file's span on its first read
        EXPECT_NE(rep.notes.back().find("2 of 20 per-frame event files"), std::string::npos) << rep.notes.back();
      }
    }
    EXPECT_EQ(s.event_totals().reads, uint64_t(frames - 1));
  }
}
