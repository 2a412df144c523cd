// vkunroll unroll end to end on small simulated sequences: outputs, metrics, modes, bad input.
#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>

#include "event_test_encoders.hpp"
#include "vkunroll/host/events/sequence.hpp"
#include "vkunroll/host/sim/recording.hpp"
#include "vkunroll/host/unroll/unroll.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
namespace fs = std::filesystem;

namespace {
fs::path temp_dir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("vkunroll-test-" + name + "-" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

// A clean 64x48 sequence of 3 frames with 3 ground-truth instants per frame period.
fs::path make_sequence(const fs::path& dir, const std::string& preset = "clean") {
  sim::SimulationConfig cfg = sim::simulation_preset(preset);
  cfg.seed = 11;
  cfg.width = 64;
  cfg.height = 48;
  cfg.frames = 3;
  cfg.gt_per_frame = 3;
  cfg.line_delay_us = 25900.0 / 48;
  const auto seq = sim::simulate(cfg);
  sim::write_sequence(cfg, seq, (dir / "seq").string());
  return dir / "seq";
}

UnrollOptions base(const fs::path& seq, const fs::path& out) {
  UnrollOptions o;
  o.sequence = seq.string();
  o.out_dir = out.string();
  o.quiet = true;
  o.session.device = "llvmpipe";
  return o;
}

std::string fixture(const std::string& name) { return std::string(VKUNROLL_SOURCE_DIR) + "/tests/data/" + name; }
}  // namespace

TEST(Unroll, PhysicsOnACleanSceneBeatsTheRsInputAndWritesEverything) {
  const fs::path dir = temp_dir("physics");
  const fs::path seq = make_sequence(dir);
  UnrollOptions o = base(seq, dir / "out");
  o.times = parse_target_times("gt");
  const auto s = run_unroll(o);
  ASSERT_TRUE(s.contains("metrics"));
  EXPECT_EQ(s["targets"].get<int>(), 9);
  EXPECT_EQ(s["metrics"]["count"].get<int>(), 9);
  EXPECT_GT(s["metrics"]["mean_psnr"].get<double>(), s["metrics"]["rs_mean_psnr"].get<double>() + 1.0);
  EXPECT_GT(s["metrics"]["mean_ssim"].get<double>(), s["metrics"]["rs_mean_ssim"].get<double>());
  EXPECT_TRUE(fs::exists(dir / "out" / "gs_video.mp4"));
  EXPECT_TRUE(fs::exists(dir / "out" / "contact_sheet.png"));
  EXPECT_TRUE(fs::exists(dir / "out" / "metrics.csv"));
  size_t pngs = 0;
  for (const auto& e : fs::directory_iterator(dir / "out" / "frames")) pngs += e.path().extension() == ".png";
  EXPECT_EQ(pngs, 9u);
  // --times gt names each output after its ground-truth file.
  for (const auto& f : s["gs_frames"])
    EXPECT_EQ(fs::path(f["file"].get<std::string>()).filename(), fs::path(f["gt_file"].get<std::string>()).filename());
  // The estimated contrast lands near the simulator's thresholds (clean preset).
  const double c = s["physics"]["contrast"].get<double>();
  EXPECT_GT(c, 0.1);
  EXPECT_LT(c, 0.45);
  fs::remove_all(dir);
}

TEST(Unroll, NormalizedAndAbsoluteTargets) {
  const fs::path dir = temp_dir("targets");
  const fs::path seq = make_sequence(dir);
  UnrollOptions o = base(seq, dir / "a");
  o.times = parse_target_times("-0.25,0:1:3,1.25");
  o.frames = {1, 2};
  o.contrast = 0.25;
  o.output.write_video = false;
  auto s = run_unroll(o);
  EXPECT_EQ(s["targets"].get<int>(), 10);  // 2 frames x 5 targets
  EXPECT_FALSE(fs::exists(dir / "a" / "gs_video.mp4"));
  o.out_dir = (dir / "b").string();
  o.times = parse_target_times("0.5", "30000,80000");
  EXPECT_THROW(run_unroll(o), Error);  // 30000 us lies in frame 0, which --frames 1,2 leaves out
  o.frames.clear();                    // every frame: each instant goes to the frame that spans it
  s = run_unroll(o);
  ASSERT_EQ(s["targets"].get<int>(), 2);
  EXPECT_DOUBLE_EQ(s["gs_frames"][0]["t_us"].get<double>(), 30000.0);
  fs::remove_all(dir);
}

TEST(Unroll, LearnedModelSAndMOnGpuAndCpuAgree) {
  const fs::path dir = temp_dir("model");
  const fs::path seq = make_sequence(dir);
  UnrollOptions o = base(seq, dir / "vk");
  o.session.model_path = fixture("selfunroll_tiny.safetensors");
  o.times = parse_target_times("0.5");
  o.frames = {1, 2};
  o.mode = UnrollMode::automatic;
  auto vk = run_unroll(o);
  EXPECT_EQ(vk["runs"]["m"].get<int>(), 1);  // frame 1 has a next frame
  EXPECT_EQ(vk["runs"]["s"].get<int>(), 1);  // frame 2 is the last
  o.session.backend = BackendKind::cpu;
  o.session.device.clear();  // a device applies to the Vulkan backend only (refused with cpu)
  o.out_dir = (dir / "cpu").string();
  auto cpu = run_unroll(o);
  for (int i = 0; i < 2; ++i) {
    const cv::Mat a = cv::imread((dir / "vk" / vk["gs_frames"][i]["file"].get<std::string>()).string());
    const cv::Mat b = cv::imread((dir / "cpu" / cpu["gs_frames"][i]["file"].get<std::string>()).string());
    ASSERT_FALSE(a.empty());
    double mx = 0;
    cv::minMaxLoc(cv::abs(a - b), nullptr, &mx);
    EXPECT_LE(mx, 1.0) << "8-bit outputs of the two backends differ by more than rounding";
  }
  o.session.model_path.clear();
  o.session.backend = BackendKind::vulkan;
  o.out_dir = (dir / "needs").string();
  o.mode = UnrollMode::m;
  EXPECT_THROW(run_unroll(o), Error);  // M without a model
  fs::remove_all(dir);
}

TEST(Unroll, BadFoldersGiveClearErrors) {
  const fs::path dir = temp_dir("bad");
  auto expect_error = [&](const UnrollOptions& o, const std::string& needle) {
    try {
      run_unroll(o);
      ADD_FAILURE() << "no error, expected one mentioning '" << needle << "'";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  fs::create_directories(dir / "empty");
  expect_error(base(dir / "empty", dir / "o1"), "empty");
  const fs::path seq = make_sequence(dir);
  // A frame of the wrong size.
  const fs::path wrong = dir / "wrong";
  fs::copy(seq, wrong, fs::copy_options::recursive);
  cv::imwrite((wrong / "rs" / "000001.png").string(), cv::Mat(10, 10, CV_8UC3, cv::Scalar(0)));
  expect_error(base(wrong, dir / "o2"), "000001.png");
  // Times outside the recording.
  UnrollOptions far = base(seq, dir / "o3");
  far.times = parse_target_times("0.5", "9000000");
  expect_error(far, "outside the recording");
  // An event outside the sensor.
  const fs::path outside = dir / "outside";
  fs::copy(seq, outside, fs::copy_options::recursive);
  {
    std::ofstream ev(outside / "events.txt");
    ev << "# t x y p\n100 3 4 1\n200 64 4 0\n";
  }
  UnrollOptions o = base(outside, dir / "o4");
  o.sequence_options.events_file = (outside / "events.txt").string();
  o.contrast = 0.2;
  expect_error(o, "events.txt");
  fs::remove_all(dir);
}

// A user's own recording (the README's "your recording"): RS frames plus the event camera's own
// file, EVT 3.0 (Metavision, OpenEB) or AEDAT 4 (DV), named by meta.json's "events". The same
// events in either file give the same GS frames as the simulator's HDF5.
TEST(Unroll, UserRecordingWithEvt3OrAedat4EventsEqualsTheHdf5One) {
  const fs::path dir = temp_dir("user-recording");
  const fs::path seq = make_sequence(dir, "realistic");
  const EventStream ev = load_sequence(seq.string()).read_events(0, int64_t(1) << 40);
  ASSERT_GT(ev.size(), 1000u);
  const std::map<std::string, std::vector<uint8_t>> files = {
      {"events.raw", evtest::encode_evt3(ev, "% evt 3.0\n% geometry 64x48\n", true)},
      {"events.aedat4", evtest::encode_aedat4(ev, 1, 4000)}};
  std::ifstream meta_in(seq / "meta.json");
  const nlohmann::json meta = nlohmann::json::parse(meta_in);
  auto run = [&](const std::string& name) {
    UnrollOptions o = base(seq, dir / ("out-" + name));
    o.mode = UnrollMode::physics;
    o.contrast = 0.2;
    o.times = parse_target_times("gt");
    o.output.write_video = false;
    return run_unroll(o);
  };
  const auto h5 = run("h5");
  for (const auto& [name, bytes] : files) {
    std::ofstream(seq / name, std::ios::binary).write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
    nlohmann::json m = meta;
    m["events"] = name;
    std::ofstream(seq / "meta.json") << m.dump(1);
    const auto s = run(name);
    EXPECT_EQ(s["events"]["in_frame_windows"], h5["events"]["in_frame_windows"]) << name << ": " << s["events"].dump();
    EXPECT_EQ(s["events"]["file_totals"]["dropped"], 0) << name;
    ASSERT_EQ(s["gs_frames"].size(), h5["gs_frames"].size()) << name;
    for (size_t i = 0; i < h5["gs_frames"].size(); ++i)
      EXPECT_EQ(s["gs_frames"][i]["psnr"], h5["gs_frames"][i]["psnr"]) << name << " GS frame " << i;
  }
  fs::remove_all(dir);
}

// The physics contrast is never a silent guess: without a successor frame it is a fixed 0.2, said
// as such; with successors but no evidence (here: no events at all) it is the default too, warned.
TEST(Unroll, ContrastWithoutASuccessorOrWithoutEvidenceIsSaid) {
  const fs::path dir = temp_dir("c-said");
  const fs::path seq = make_sequence(dir);
  UnrollOptions o = base(seq, dir / "last");
  o.mode = UnrollMode::physics;
  o.frames = {2};
  o.output.write_video = false;
  const auto last = run_unroll(o);
  EXPECT_EQ(last["physics"]["contrast"].get<double>(), 0.2f);
  EXPECT_NE(last["physics"]["contrast_source"].get<std::string>().find("not estimated"), std::string::npos) << last["physics"];
  EXPECT_EQ(last["physics"]["contrast_method"], "default") << last["physics"];
  EXPECT_FALSE(last["physics"].contains("contrast_pairs")) << last["physics"];
  bool said = false;
  for (const auto& w : last["warnings"]) said = said || w.get<std::string>().find("fixed default") != std::string::npos;
  EXPECT_TRUE(said) << last["warnings"];
  // The same sequence with its events: estimated over each chosen frame and its successor.
  o.out_dir = (dir / "estimated").string();
  o.frames = {0, 1};
  const auto est = run_unroll(o);
  EXPECT_EQ(est["physics"]["contrast_method"], "event_count_fit") << est["physics"];
  EXPECT_EQ(est["physics"]["contrast_pairs"], nlohmann::json::parse("[[0, 1], [1, 2]]")) << est["physics"];
  EXPECT_GE(est["physics"]["contrast_pixels"].get<int>(), 200) << est["physics"];
  EXPECT_NE(est["physics"]["contrast_source"].get<std::string>().find("frames 0-1, 1-2"), std::string::npos) << est["physics"];
  // No events at all: no pixel is evidence, so the default, with a warning that says why.
  std::ofstream(seq / "empty.txt") << "";
  std::ifstream meta_in(seq / "meta.json");
  nlohmann::json meta = nlohmann::json::parse(meta_in);
  meta["events"] = "empty.txt";
  std::ofstream(seq / "meta.json") << meta.dump(1);
  o.out_dir = (dir / "none").string();
  const auto none = run_unroll(o);
  EXPECT_NEAR(none["physics"]["contrast"].get<double>(), 0.2, 1e-6);
  EXPECT_EQ(none["physics"]["contrast_method"], "default") << none["physics"];
  EXPECT_NEAR(none["physics"]["log_offset"].get<double>(), 0.0, 1e-12);
  bool warned = false;
  for (const auto& w : none["warnings"]) warned = warned || w.get<std::string>().find("too few pixels") != std::string::npos;
  EXPECT_TRUE(warned) << none["warnings"];
  // A given contrast is neither.
  o.out_dir = (dir / "given").string();
  o.contrast = 0.3;
  const auto given = run_unroll(o);
  EXPECT_EQ(given["physics"]["contrast_source"], "given");
  EXPECT_EQ(given["physics"]["contrast_method"], "given");
  for (const auto& w : given["warnings"]) EXPECT_EQ(w.get<std::string>().find("contrast"), std::string::npos) << w;  // only "no events" ones
  fs::remove_all(dir);
}
