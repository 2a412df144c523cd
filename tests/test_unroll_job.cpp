// The one unroll job (host/unroll/unroll_job.hpp): each frame decoded once and uploaded once for
// all of its targets, and arrays in memory giving what the sequence folder gives.
#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>

#include "vkunroll/host/events/sequence.hpp"
#include "vkunroll/host/sim/recording.hpp"
#include "vkunroll/host/unroll/unroll.hpp"
#include "vkunroll/host/unroll/unroll_job.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
namespace fs = std::filesystem;

namespace {

fs::path temp_dir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("vkunroll-test-job-" + name + "-" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

fs::path make_sequence(const fs::path& dir, int frames) {
  sim::SimulationConfig cfg = sim::simulation_preset("clean");
  cfg.seed = 5;
  cfg.width = 64;
  cfg.height = 48;
  cfg.frames = frames;
  cfg.gt_per_frame = 2;
  const auto seq = sim::simulate(cfg);
  sim::write_sequence(cfg, seq, (dir / "seq").string());
  return dir / "seq";
}

UnrollOptions options(const fs::path& seq, const fs::path& out, const std::string& times, UnrollMode mode) {
  UnrollOptions o;
  o.sequence = seq.string();
  o.out_dir = out.string();
  o.quiet = true;
  o.session.device = "llvmpipe";
  o.session.model_path = std::string(VKUNROLL_SOURCE_DIR) + "/tests/data/selfunroll_tiny.safetensors";
  o.times = parse_target_times(times);
  o.mode = mode;
  o.output.write_video = false;
  return o;
}

struct VectorSink : ResultSink {
  std::vector<cv::Mat> images;
  std::vector<int> frames;
  void add(const GsResult& r) override {
    images.push_back(r.image.clone());
    frames.push_back(r.frame);
  }
};

}  // namespace

TEST(UnrollJob, EachFrameIsDecodedOnceAndUploadedOnceForAllItsTargets) {
  const fs::path dir = temp_dir("once");
  const fs::path seq = make_sequence(dir, 4);
  // choose: 0.5 lies inside each frame's span (S), 1.5 between frames (M where a next frame exists):
  // frames 0-2 have S and M targets, frame 3 (the last) S only.
  const nlohmann::json s = run_unroll(options(seq, dir / "choose", "0.5,1.5", UnrollMode::choose));
  EXPECT_EQ(s["runs"]["s"].get<int>(), 5);
  EXPECT_EQ(s["runs"]["m"].get<int>(), 3);
  const nlohmann::json& reads = s.at("reads");
  EXPECT_EQ(reads["frame_decodes"].get<int>(), 4) << reads.dump();  // frame k+1 decoded as M's f2 is kept as the next f1
  EXPECT_EQ(reads["distinct_frames_decoded"].get<int>(), 4);
  EXPECT_EQ(reads["frames_unrolled"].get<int>(), 4);
  // One upload of rs1 per frame for S and M alike, plus rs2 for the three frames with M targets.
  EXPECT_EQ(reads["image_uploads"].get<int>(), 4 + 3) << reads.dump();
  // The ground truth at every target instant that has one is decoded for that target only.
  EXPECT_LE(reads["ground_truth_decodes"].get<int>(), 8);

  // auto on every frame: M pairs (k, k + 1) still decode each frame once.
  const nlohmann::json a = run_unroll(options(seq, dir / "auto", "0.25", UnrollMode::automatic));
  EXPECT_EQ(a["reads"]["frame_decodes"].get<int>(), 4) << a["reads"].dump();
  EXPECT_EQ(a["reads"]["image_uploads"].get<int>(), 3 * 2 + 1);
  fs::remove_all(dir);
}

TEST(UnrollJob, ArraysInMemoryGiveTheSequencesFrames) {
  const fs::path dir = temp_dir("arrays");
  const fs::path seq_dir = make_sequence(dir, 3);
  const Sequence seq = load_sequence(seq_dir.string());
  UnrollOptions o = options(seq_dir, dir / "unused", "0.25,0.75", UnrollMode::automatic);

  UnrollSession session(o.session);
  SequenceFrameSource from_folder(seq);
  VectorSink a;
  UnrollJob(o, session, from_folder).run(a);

  std::vector<cv::Mat> frames;
  std::vector<RowTiming> timings;
  for (size_t k = 0; k < seq.frames.size(); ++k) {
    frames.push_back(from_folder.decode_frame(int(k)));
    timings.push_back(seq.frames[k].timing);
  }
  const double lo = seq.frames.front().timing.first_start().to_double() - 1e6;
  const double hi = seq.frames.back().timing.last_end().to_double() + 1e6;
  ArrayFrameSource from_arrays(frames, timings, read_window(seq, lo, hi), {}, "test");
  VectorSink b;
  UnrollJob job(o, session, from_arrays);
  job.run(b);
  ASSERT_EQ(a.images.size(), 6u);
  ASSERT_EQ(b.images.size(), a.images.size());
  EXPECT_EQ(a.frames, b.frames);
  for (size_t i = 0; i < a.images.size(); ++i) EXPECT_EQ(cv::norm(a.images[i], b.images[i], cv::NORM_INF), 0.0) << i;
  EXPECT_EQ(job.report()["reads"]["frame_decodes"].get<int>(), 3);

  // Arrays that disagree are refused naming what.
  EXPECT_THROW(ArrayFrameSource({frames[0]}, timings, EventStream{}, {}, "test"), Error);
  fs::remove_all(dir);
}
