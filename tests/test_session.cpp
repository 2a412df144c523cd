// UnrollSession: the device-resident frame pipeline equals the host path it replaced, and its
// host <-> device traffic per GS frame is what the design says (one RS upload, the events, the GS
// image down, a submission per group of targets).
#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <set>
#include <opencv2/imgcodecs.hpp>

#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/model/tiling.hpp"
#include "vkunroll/host/sim/recording.hpp"
#include "vkunroll/host/unroll/image_planes.hpp"
#include "vkunroll/host/unroll/metrics.hpp"
#include "vkunroll/host/unroll/session.hpp"
#include "vkunroll/host/unroll/default_model.hpp"
#include "vkunroll/host/unroll/unroll.hpp"
#include "vkunroll/kernels/physics_unroll.hpp"
#include "vk_test_env.hpp"

using namespace vkunroll;
namespace fs = std::filesystem;

namespace {
fs::path temp_dir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("vkunroll-test-session-" + name + "-" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

fs::path make_sequence(const fs::path& dir, int width, int height, int frames) {
  sim::SimulationConfig cfg = sim::simulation_preset("realistic");
  cfg.seed = 5;
  cfg.width = width;
  cfg.height = height;
  cfg.frames = frames;
  cfg.gt_per_frame = 1;
  cfg.line_delay_us = 25900.0 / height;
  const auto seq = sim::simulate(cfg);
  sim::write_sequence(cfg, seq, (dir / "seq").string());
  return dir / "seq";
}

std::string fixture(const std::string& name) { return std::string(VKUNROLL_SOURCE_DIR) + "/tests/data/" + name; }

double max_abs(const cv::Mat& a, const cv::Mat& b) {
  double m = 0;
  const cv::Mat d = cv::abs(a - b);
  cv::minMaxLoc(d.reshape(1), nullptr, &m);
  return m;
}

// The path unroll took before the session: event tensors on the host, Model::run / run_tiled on host arrays.
cv::Mat host_path(Model& model, const FrameInput& in, const Rational& t, bool m, const TileOptions* tiles,
                  const PhysicsUnrollParams& prm = {}) {
  const int H = in.rs1.rows, W = in.rs1.cols;
  std::vector<EventTensorPair> pairs{{in.timing1, t, std::nullopt}};
  if (m) pairs.push_back({in.timing2, t, std::nullopt});
  EventTensorSpec spec;
  spec.bins = model.config().N;
  EventTensors et = build_event_tensors_ref(*in.events, pairs, spec);
  const int64_t B = m ? 2 : 1;
  const Shape es{B, 2 * spec.bins, H, W};
  ModelInputs mi;
  std::vector<float> rs = image_planes(in.rs1, true);
  if (m) {
    const std::vector<float> rs2 = image_planes(in.rs2, true);
    rs.insert(rs.end(), rs2.begin(), rs2.end());
  }
  mi.rs = HostTensor(Shape{B, 3, H, W}, rs);
  mi.ev1 = HostTensor(es, std::move(et.ev1));
  mi.ev2 = HostTensor(es, std::move(et.ev2));
  mi.ev3 = HostTensor(es, std::move(et.ev3));
  if (model.config().physics_input) {  // the variant's input: the physics unroller's reference
    mi.phys = HostTensor(Shape{B, 3, H, W});
    for (int64_t i = 0; i < B; ++i) {
      const RowTiming& tm = i ? in.timing2 : in.timing1;
      const auto lists = gather_pixel_events(*in.events, t.to_double(), tm.start_times_us(), tm.end_times_us(), 0, 0, W, H);
      const auto gs = physics_unroll_ref(image_planes(i ? in.rs2 : in.rs1, true), 3, lists, prm);
      std::copy(gs.begin(), gs.end(), mi.phys.data.begin() + i * 3 * H * W);
    }
  }
  RunOptions ro;
  ro.mode = m ? Mode::m : Mode::s;
  ro.outputs = {m ? ModelOutput::out : ModelOutput::fused};
  const HostTensor out = tiles ? run_tiled(model, mi, ro, *tiles).outputs.at(ro.outputs[0]) : model.run(mi, ro).at(ro.outputs[0]);
  return planes_image(out.data.data(), H, W, true);
}

FrameInput frame_input(const Sequence& seq, int k, const EventStream& ev) {
  FrameInput in;
  in.rs1 = to_unit_float(cv::imread(seq.frames[k].image, cv::IMREAD_COLOR));
  in.rs2 = to_unit_float(cv::imread(seq.frames[k + 1].image, cv::IMREAD_COLOR));
  in.timing1 = seq.frames[k].timing;
  in.timing2 = seq.frames[k + 1].timing;
  in.events = &ev;
  return in;
}
}  // namespace

// The frame time's breakdown (summary.json): the stages add up to the total; the wait for the
// device is its own stage, so upload and download hold host work only; GPU time (timestamps) is
// split by stage, adds up to gpu_ms and lies inside the wait.
static void expect_honest_time_breakdown(const nlohmann::json& s, bool model) {
  const double total = s.at("ms_per_gs_frame_total").get<double>();
  double stages = 0;
  for (const auto& [name, v] : s.at("ms_per_gs_frame").items()) {
    EXPECT_GE(v.get<double>(), 0.0) << name;
    stages += v.get<double>();
  }
  EXPECT_NEAR(stages, total, 1e-6 * total + 1e-9) << s.at("ms_per_gs_frame").dump();
  const auto& ms = s.at("ms_per_gs_frame");
  for (const char* k : {"setup", "read", "write", "upload", "download", "wait", "other"}) EXPECT_TRUE(ms.contains(k)) << k << " " << ms.dump();
  const double wait = ms.at("wait").get<double>(), gpu = s.at("gpu_ms_per_gs_frame").get<double>();
  EXPECT_GT(gpu, 0.0);
  EXPECT_LE(gpu, wait * 1.02 + 0.5) << "GPU work runs while the host waits";
  // Before, the wait for the whole network was counted as the download's "transfer".
  EXPECT_LT(ms.at("download").get<double>() + ms.at("upload").get<double>(), 0.5 * wait) << ms.dump();
  EXPECT_NEAR(s.at("host_ms_per_gs_frame").get<double>() + wait, total, 1e-6 * total + 1e-9);
  double by_stage = 0;
  for (const auto& [name, v] : s.at("gpu_ms_per_gs_frame_by_stage").items()) by_stage += v.get<double>();
  EXPECT_NEAR(by_stage, gpu, 1e-6 * gpu + 1e-9);
  const auto& g = s.at("gpu_ms_per_gs_frame_by_stage");
  for (const char* k : model ? std::vector<const char*>{"upload", "event_tensors", "model.eic_t", "model.eic_s", "model.fusion", "download"}
                             : std::vector<const char*>{"upload", "physics", "download"})
    EXPECT_TRUE(g.contains(k)) << k << " " << g.dump();
  EXPECT_FALSE(g.contains("other")) << "every command is recorded in a named stage: " << g.dump();
  const double share = s.at("gpu_share_of_frame_time").get<double>();
  EXPECT_GT(share, 0.0);
  EXPECT_LE(share, 1.0);
}

TEST(Session, DeviceResidentFrameEqualsTheHostPath) {
  const fs::path dir = temp_dir("parity");
  const Sequence seq = load_sequence(make_sequence(dir, 64, 48, 3).string(), {});
  const EventStream ev = seq.read_events(-100000, 400000);
  const FrameInput in = frame_input(seq, 1, ev);
  const RowTiming& t1 = in.timing1;
  const std::vector<FrameTarget> targets{{t1.target_time(Rational(1, 2)), FrameTarget::Method::s},
                                         {t1.target_time(Rational(-1, 4)), FrameTarget::Method::s},
                                         {t1.target_time(Rational(3, 2)), FrameTarget::Method::m}};
  SessionOptions so;
  so.model_path = fixture("selfunroll_tiny.safetensors");
  so.device = "llvmpipe";
  so.announce = false;
  UnrollSession session(so);
  VulkanBackend reference_backend(vktest::context());
  Model reference(reference_backend, session.weights());
  TileOptions dense;  // untiled, every pixel through the network
  TileOptions sparse;
  sparse.tile = 32, sparse.halo = 32, sparse.sparse = SparsePolicy::exact;
  for (const TileOptions* tiles : {&dense, &sparse}) {
    session.set_tiling(*tiles);
    (void)session.unroll(in, targets);  // warm-up: the convs upload their weight packings on first use
    const DeviceTraffic before = session.traffic();
    const std::vector<cv::Mat> got = session.unroll(in, targets);
    const DeviceTraffic d = session.traffic() - before;
    ASSERT_EQ(got.size(), targets.size());
    for (size_t j = 0; j < targets.size(); ++j) {
      const bool m = targets[j].method == FrameTarget::Method::m;
      const cv::Mat want = host_path(reference, in, targets[j].t_us, m, tiles == &sparse ? tiles : nullptr);
      EXPECT_LE(max_abs(got[j], want), 2e-5) << "target " << j << (tiles == &sparse ? " (sparse tiles)" : " (dense)");
    }
    // S and M: one wait for the device each (their uploads and network go up as separate
    // submissions, runtime/command_stream.hpp); down: the three GS images at fp32 and nothing else.
    EXPECT_EQ(d.waits, 2u);
    EXPECT_EQ(d.download_bytes, uint64_t(3) * 3 * 48 * 64 * 4);
    // Up: per group the RS frame(s) and the window's events with their per-row records (at most
    // 8 bytes an event; records and ranges (N + 8) words per job and row), never the tensors.
    const uint64_t N = session.model_config().N, images = uint64_t(2) * 3 * 48 * 64 * 4;  // rs1, rs2 once for S and M
    const uint64_t per_build = 8 * ev.size() + uint64_t(3 * 4) * 48 * (N + 8) * 4;
    EXPECT_LE(d.upload_bytes, images + 2 * per_build) << d.upload_bytes << " bytes up";
  }
  fs::remove_all(dir);
}

// Event tensors beyond one binding (HD frames on lavapipe's 128 MiB) take the host path: built on
// the device, downloaded, cut into tiles on the host. It gives the device path's images and says so.
TEST(Session, HostPathForTensorsBeyondOneBindingEqualsTheDevicePath) {
  const fs::path dir = temp_dir("host-path");
  const Sequence seq = load_sequence(make_sequence(dir, 160, 120, 3).string(), {});
  const EventStream ev = seq.read_events(-100000, 400000);
  const FrameInput in = frame_input(seq, 1, ev);
  const std::vector<FrameTarget> targets{{in.timing1.target_time(Rational(1, 2)), FrameTarget::Method::s},
                                         {in.timing1.target_time(Rational(3, 2)), FrameTarget::Method::m}};
  SessionOptions so;
  so.model_path = fixture("selfunroll_tiny.safetensors");
  so.device = "llvmpipe";
  so.announce = false;
  UnrollSession session(so);
  TileOptions tiles;
  tiles.tile = 32, tiles.halo = 32;
  session.set_tiling(tiles);
  const std::vector<cv::Mat> device = session.unroll(in, targets);
  ASSERT_EQ(session.stats().host_path_targets, 0u);
  // One S target's tensors (ev1..ev3, [3, 2N, H, W] fp32) no longer fit one binding.
  tiles.max_buffer_bytes = uint64_t(3) * 2 * session.model_config().N * 120 * 160 * 4 - 1;
  session.set_tiling(tiles);
  ASSERT_LT(session.binding_limit(), session.backend().max_buffer_bytes());
  const std::vector<cv::Mat> host = session.unroll(in, targets);
  EXPECT_EQ(session.stats().host_path_targets, 2u);
  ASSERT_EQ(host.size(), device.size());
  for (size_t j = 0; j < host.size(); ++j) EXPECT_LE(max_abs(host[j], device[j]), 2e-5) << "target " << j;
  fs::remove_all(dir);
}

// The bound, end to end with the shipped model at the DAVIS346 size: the bytes downloaded
// per GS frame are at most twice the output image at fp32, and the event tensors never cross.
TEST(Session, ShippedModelTrafficPerGsFrameAt346x260) {
  const fs::path model = fs::path(VKUNROLL_SOURCE_DIR) / "models" / kDefaultModelFile;
  ASSERT_TRUE(fs::exists(model)) << model << " is not in the checkout (models/ is part of the repository)";
  const fs::path dir = temp_dir("traffic");
  const fs::path seq = make_sequence(dir, 346, 260, 2);
  for (const SparsePolicy sparse : {SparsePolicy::off, SparsePolicy::exact}) {
    UnrollOptions o;
    o.sequence = seq.string();
    o.out_dir = (dir / (sparse == SparsePolicy::off ? "dense" : "sparse")).string();
    o.quiet = true;
    o.session.device = "llvmpipe";
    o.session.model_path = model.string();
    o.mode = UnrollMode::s;
    o.times = parse_target_times("0.25,0.75");
    o.frames = {0};
    o.sparse = sparse;
    o.output.write_video = false;
    o.session.profile_ops = true;  // GPU times need the timestamps
    const auto s = run_unroll(o);
    const auto& t = s.at("device_traffic_per_gs_frame");
    const double image = 3.0 * 260 * 346 * 4;
    EXPECT_LE(t.at("download_bytes").get<double>(), 2 * image) << t.dump();
    EXPECT_GT(t.at("download_bytes").get<double>(), 0.99 * image) << t.dump();
    // ev1, ev2, ev3 of one target: what the host path uploaded per GS frame on top of the image.
    const double tensors = 3.0 * 2 * load_weights(model.string()).config.N * 260 * 346 * 4;
    EXPECT_LT(t.at("upload_bytes").get<double>(), tensors) << t.dump();
    EXPECT_LE(t.at("waits").get<double>(), 1.0) << t.dump();  // both targets in one batch, one wait for it
    EXPECT_EQ(s.at("memory_forced_submits").get<int>(), 0) << t.dump();
    expect_honest_time_breakdown(s, true);
  }
  fs::remove_all(dir);
}

// Physics only: the frame's upload, the physics kernel and the download are each their own stage.
TEST(Session, PhysicsTimeBreakdownAddsUp) {
  const fs::path dir = temp_dir("breakdown");
  UnrollOptions o;
  o.sequence = make_sequence(dir, 64, 48, 2).string();
  o.out_dir = (dir / "out").string();
  o.quiet = true;
  o.session.device = "llvmpipe";
  o.mode = UnrollMode::physics;
  o.times = parse_target_times("0.25,0.75");
  o.output.write_video = false;
  o.session.profile_ops = true;  // GPU times need the timestamps
  expect_honest_time_breakdown(run_unroll(o), false);
  fs::remove_all(dir);
}

// --profile: each kernel's GPU time per GS frame; the ops add up to the GPU time, as the stages do,
// and name what ran (the physics kernel, the transfers). Without it the table is absent.
TEST(Session, ProfileOpsAddUpToTheGpuTime) {
  const fs::path dir = temp_dir("profile");
  UnrollOptions o;
  o.sequence = make_sequence(dir, 64, 48, 2).string();
  o.quiet = true;
  o.session.device = "llvmpipe";
  o.mode = UnrollMode::physics;
  o.times = parse_target_times("0.25,0.75");
  o.output.write_video = false;
  o.out_dir = (dir / "plain").string();
  const auto plain = run_unroll(o);
  EXPECT_FALSE(plain.contains("gpu_ms_per_gs_frame_by_op"));
  // Without --profile or --trace the device writes no timestamps: no GPU times, said so.
  EXPECT_FALSE(plain.at("gpu_timestamps").get<bool>());
  EXPECT_TRUE(plain.at("gpu_ms_per_gs_frame").is_null());
  EXPECT_TRUE(plain.at("gpu_ms_per_gs_frame_by_stage").is_null());
  o.out_dir = (dir / "profiled").string();
  o.session.profile_ops = true;
  const auto s = run_unroll(o);
  const auto& ops = s.at("gpu_ms_per_gs_frame_by_op");
  double sum = 0;
  for (const auto& [name, v] : ops.items()) {
    EXPECT_GT(v.at("calls").get<double>(), 0.0) << name;
    sum += v.at("ms").get<double>();
  }
  const double gpu = s.at("gpu_ms_per_gs_frame").get<double>();
  EXPECT_NEAR(sum, gpu, 1e-6 * gpu + 1e-9) << ops.dump();
  for (const char* k : {"physics_unroll", "upload", "download"}) EXPECT_TRUE(ops.contains(k)) << k << " " << ops.dump();
  EXPECT_DOUBLE_EQ(ops.at("physics_unroll").at("calls").get<double>(), 1.0) << "one physics dispatch per GS frame";
  fs::remove_all(dir);
}

// --trace FILE.json end to end (the model, S and M): Chrome trace events with a track of the
// session's host stages and the GPU's dispatches (each conv named with its shape and algorithm);
// per op, the GPU spans add up to --profile's per-op times (summary.json's are per GS frame).
TEST(Session, TraceFileHasHostStagesAndGpuSpansThatAddUpToTheProfile) {
  const fs::path dir = temp_dir("trace");
  UnrollOptions o;
  o.sequence = make_sequence(dir, 64, 48, 2).string();
  o.out_dir = (dir / "out").string();
  o.trace_path = (dir / "trace.json").string();
  o.quiet = true;
  o.session.device = "llvmpipe";
  o.session.model_path = fixture("selfunroll_tiny.safetensors");
  o.session.profile_ops = true;
  o.times = parse_target_times("0.25,0.75");
  o.output.write_video = false;
  const auto s = run_unroll(o);
  const double targets = s.at("targets").get<double>();
  std::ifstream f(o.trace_path);
  const nlohmann::json j = nlohmann::json::parse(f);
  std::map<int, std::string> track;
  std::map<std::string, double> gpu_ms;
  std::set<std::string> stages;
  bool conv_detail = false;
  for (const auto& e : j.at("traceEvents")) {
    if (e.at("ph") == "M") {
      if (e.at("name") == "thread_name") track[e.at("tid").get<int>()] = e.at("args").at("name").get<std::string>();
      continue;
    }
    const std::string& t = track.at(e.at("tid").get<int>());
    if (t == "host stages") stages.insert(e.at("name").get<std::string>());
    if (t.rfind("GPU", 0) != 0) continue;
    gpu_ms[e.at("args").at("op").get<std::string>()] += e.at("dur").get<double>() * 1e-3;
    conv_detail = conv_detail || e.at("args").value("detail", "").find("->") != std::string::npos;
  }
  for (const char* k : {"upload", "event_tensors", "model", "download"}) EXPECT_TRUE(stages.count(k)) << k;
  EXPECT_TRUE(conv_detail) << "convs carry their shapes and algorithm";
  const auto& ops = s.at("gpu_ms_per_gs_frame_by_op");
  EXPECT_EQ(gpu_ms.size(), ops.size());
  for (const auto& [op, v] : ops.items())
    EXPECT_NEAR(gpu_ms[op], v.at("ms").get<double>() * targets, 1e-6 * v.at("calls").get<double>() * targets + 1e-6) << op;
  EXPECT_EQ(s.at("trace").at("file").get<std::string>(), o.trace_path);
  fs::remove_all(dir);
}

// The physics-informed variant: its physics input is computed on the device per (frame, target)
// and equals the CPU reference's, so the whole frame equals the host path's.
TEST(Session, PhysicsVariantFrameEqualsTheHostPath) {
  const fs::path dir = temp_dir("variant");
  const Sequence seq = load_sequence(make_sequence(dir, 64, 48, 3).string(), {});
  const EventStream ev = seq.read_events(-100000, 400000);
  const FrameInput in = frame_input(seq, 1, ev);
  const std::vector<FrameTarget> targets{{in.timing1.target_time(Rational(1, 3)), FrameTarget::Method::s},
                                         {in.timing1.target_time(Rational(3, 2)), FrameTarget::Method::m}};
  SessionOptions so;
  so.model_path = fixture("selfunroll_tiny_physics.safetensors");
  so.device = "llvmpipe";
  so.announce = false;
  UnrollSession session(so);
  ASSERT_TRUE(session.model_config().physics_input);
  PhysicsUnrollParams prm;
  prm.contrast = 0.25f;
  prm.gamma = static_cast<float>(session.model_config().gamma.value_or(1.0));
  session.set_physics(prm);
  TileOptions dense;
  session.set_tiling(dense);
  const std::vector<cv::Mat> got = session.unroll(in, targets);
  VulkanBackend reference_backend(vktest::context());
  Model reference(reference_backend, session.weights());
  for (size_t j = 0; j < targets.size(); ++j) {
    const cv::Mat want = host_path(reference, in, targets[j].t_us, targets[j].method == FrameTarget::Method::m, nullptr, prm);
    EXPECT_LE(max_abs(got[j], want), 1e-4) << "target " << j;
  }
  fs::remove_all(dir);
}

// --precision fp16 end to end: the variant model (network, physics input, tiles) and a physics-only
// target in an fp16 session stay within the model's measured fp16 error of the fp32 session's frames.
TEST(Session, Fp16FramesAreCloseToFp32) {
  const fs::path dir = temp_dir("fp16");
  const Sequence seq = load_sequence(make_sequence(dir, 64, 48, 3).string(), {});
  const EventStream ev = seq.read_events(-100000, 400000);
  const FrameInput in = frame_input(seq, 1, ev);
  const std::vector<FrameTarget> targets{{in.timing1.target_time(Rational(1, 3)), FrameTarget::Method::s},
                                         {in.timing1.target_time(Rational(3, 2)), FrameTarget::Method::m},
                                         {in.timing1.target_time(Rational(1, 2)), FrameTarget::Method::physics}};
  std::vector<cv::Mat> frames[2];
  for (const Precision p : {Precision::fp32, Precision::fp16}) {
    SessionOptions so;
    so.model_path = fixture("selfunroll_tiny_physics.safetensors");
    so.device = "llvmpipe";
    so.announce = false;
    so.precision = p;
    UnrollSession session(so);
    PhysicsUnrollParams prm;
    prm.contrast = 0.25f;
    session.set_physics(prm);
    TileOptions sparse;
    sparse.tile = 32, sparse.halo = 32, sparse.sparse = SparsePolicy::exact;
    session.set_tiling(sparse);
    frames[p == Precision::fp16] = session.unroll(in, targets);
  }
  for (size_t j = 0; j < targets.size(); ++j) {
    const double err = max_abs(frames[0][j], frames[1][j]);
    EXPECT_LE(err, 0.01) << "target " << j;  // 1%: the fp16 model tests' bound (tests/test_model_fp16.cpp)
    EXPECT_GT(err, 0.0) << "target " << j << ": fp16 equal to fp32 bit for bit means fp16 did not run";
  }
  fs::remove_all(dir);
}

TEST(Session, Fp16OnTheCpuBackendIsRefused) {
  SessionOptions so;
  so.backend = BackendKind::cpu;
  so.precision = Precision::fp16;
  EXPECT_THROW(UnrollSession session(so), Error);
}
