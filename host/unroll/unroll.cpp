#include "vkunroll/host/unroll/unroll.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <memory>
#include <optional>

#include "vkunroll/base/env.hpp"
#include "vkunroll/base/log.hpp"
#include "vkunroll/base/stopwatch.hpp"
#include "vkunroll/host/unroll/provenance.hpp"
#include "vkunroll/host/unroll/sha256.hpp"
#include "vkunroll/host/unroll/image_planes.hpp"
#include "vkunroll/host/unroll/metrics.hpp"
#include "vkunroll/host/unroll/progress.hpp"
#include "vkunroll/host/model/backend.hpp"
#include "vkunroll/host/unroll/device_stage.hpp"
#include "vkunroll/host/unroll/follow_source.hpp"
#include "vkunroll/host/unroll/output_file.hpp"
#include "vkunroll/host/unroll/session.hpp"
#include "vkunroll/host/unroll/unroll_job.hpp"
#include "vkunroll/host/unroll/unroll_output.hpp"
#include "vkunroll/host/unroll/unroll_plan.hpp"

namespace vkunroll {

namespace fs = std::filesystem;

namespace {

// The CLI's sink: every GS frame into the output folder (frames, video, contact sheet, metrics,
// the resume journal), with the progress line.
class FolderSink : public ResultSink {
 public:
  FolderSink(UnrollOutput& output, Progress& progress, const Sequence& seq, bool resume)
      : output_(output), progress_(progress), seq_(seq), resume_(resume) {}

  std::optional<cv::Mat> reusable(int frame, const UnrollTarget& t) override {
    if (!resume_) return std::nullopt;
    GsFrameRecord record;
    std::optional<cv::Mat> image = output_.find_reusable(frame, t.t_us.str(), t.name, &record);
    if (image) reused_records_[key(frame, t)] = record;
    return image;
  }

  void add(const GsResult& r) override {
    const UnrollTarget& t = *r.target;
    const std::string gt_file = t.gt >= 0 ? seq_.ground_truth[size_t(t.gt)].image : std::string();
    if (r.reused) {
      output_.add_reused(reused_records_.at(key(r.frame, t)), r.image, r.rs_input, r.ground_truth);
    } else {
      output_.add(r.frame, t.t_us.to_double(), t.t_us.str(), t.tau, r.image, r.rs_input, r.ground_truth, gt_file, t.name,
                  r.events_window);
    }
    progress_.update(++done_, "frame " + std::to_string(r.frame) + (r.reused ? " (reused)" : frame_times(r)));
  }

 private:
  // The frame's unroll: its wall time, the GPU's (timestamps) and the wait for the device.
  static std::string frame_times(const GsResult& r) {
    char buf[96];
    if (r.frame_gpu_ms > 0)  // timestamps on (--profile, --trace)
      std::snprintf(buf, sizeof buf, " (%.0f ms: GPU %.0f, wait %.0f)", r.frame_ms, r.frame_gpu_ms, r.frame_wait_ms);
    else
      std::snprintf(buf, sizeof buf, " (%.0f ms: wait %.0f)", r.frame_ms, r.frame_wait_ms);
    return buf;
  }
  static std::string key(int frame, const UnrollTarget& t) { return std::to_string(frame) + "|" + t.t_us.str(); }
  UnrollOutput& output_;
  Progress& progress_;
  const Sequence& seq_;
  bool resume_;
  std::map<std::string, GsFrameRecord> reused_records_;
  size_t done_ = 0;
};

// What decides the pixels of a GS frame: frames written under another key are not reused.
std::string resume_key(const UnrollOptions& o, UnrollMode mode, const UnrollSession& session,
                       const PhysicsUnrollParams& prm, const std::string& model_sha256) {
  const BuildInfo b = build_info();
  nlohmann::json opts = unroll_options_json(o);
  for (const char* k : {"out", "frames", "times", "video", "fps", "existing_output", "device", "cpu_threads", "model"}) opts.erase(k);
  nlohmann::json key = {{"vkunroll", b.version}, {"git", b.git_revision}, {"options", opts},
                        {"sequence", fs::absolute(o.sequence).lexically_normal().string()},
                        {"mode", unroll_mode_name(mode)}, {"model_sha256", model_sha256}};
  if (mode == UnrollMode::physics) key["physics"] = {{"contrast", prm.contrast}, {"gamma", prm.gamma}};
  if (session.has_model()) key["rgb"] = session.model_rgb();
  return sha256_hex(key.dump());
}

// Threads this process runs with: OpenCV's pool and lavapipe's rasterizer workers ("llvmpipe-N").
nlohmann::json thread_report(const UnrollOptions& o) {
  int lavapipe = 0;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator("/proc/self/task", ec)) {
    std::ifstream comm(e.path() / "comm");
    std::string name;
    std::getline(comm, name);
    lavapipe += name.rfind("llvmpipe-", 0) == 0;
  }
  const std::optional<std::string> lp = env::text("LP_NUM_THREADS");  // Mesa's, reported as given
  return {{"requested", o.session.cpu_threads}, {"opencv", cv::getNumThreads()},
          {"lavapipe_workers", lavapipe}, {"LP_NUM_THREADS", lp ? nlohmann::json(*lp) : nlohmann::json()}};
}

}  // namespace

namespace {

// summary.json beyond the frames and outputs (UnrollOutput::finish adds those): the job's report,
// the sequence, the model file, where it ran, and the provenance.
nlohmann::json summary_extra(const UnrollOptions& o, const UnrollJob& job, const UnrollSession& session, const Sequence& seq,
                             const std::string& model_sha256, double total_ms) {
  nlohmann::json extra = job.report(total_ms);
  extra["sequence"] = {{"path", o.sequence}, {"layout", sequence_layout_name(seq.layout)},
                       {"width", seq.width}, {"height", seq.height}, {"frames_in_sequence", seq.frames.size()},
                       {"notes", seq.notes}};
  if (session.has_model()) {
    extra["model"] = {{"path", o.session.model_path}, {"sha256", model_sha256},
                      {"bytes", fs::file_size(o.session.model_path)}, {"config", session.model_config().summary()},
                      {"channel_order", session.model_rgb() ? "rgb" : "bgr"}};
    if (!o.model_source.empty()) extra["model"]["source"] = o.model_source;
  }
  extra["backend"] = backend_kind_name(session.backend_kind());
  extra["precision"] = precision_name(o.session.precision);
  if (const Context* ctx = session.context()) {
    extra["device"] = ctx->info().name;
    // What a fault sweep iterates over (runtime/fault_injection.hpp): the run's device calls.
    using Site = FaultInjection::Site;
    extra["device_calls"] = {{"submits", ctx->faults().calls(Site::submit)},
                             {"allocations", ctx->faults().calls(Site::allocation)}, {"maps", ctx->faults().calls(Site::map)},
                             {"pipelines", ctx->faults().calls(Site::pipeline)}};
  }
  extra["conv_algorithms"] = session.conv_choice_report();
  extra["memory_forced_submits"] = session.memory_forced_submits();
  extra["peak_device_bytes"] = session.peak_device_bytes();
  const BuildInfo b = build_info();
  extra["provenance"] = {{"vkunroll_version", b.version},
                         {"git_revision", b.git_revision},
                         {"git_dirty", b.git_dirty < 0 ? nlohmann::json() : nlohmann::json(b.git_dirty == 1)},
                         {"command_line", o.command_line},
                         {"working_directory", fs::current_path().string()},
                         {"host", host_name()},
                         {"options", unroll_options_json(o)},
                         {"backend", backend_kind_name(session.backend_kind())},
                         {"device", session.context() ? device_json(session.context()->info()) : nlohmann::json()},
                         {"precision", precision_name(o.session.precision)},
                         {"threads", thread_report(o)}};
  if (session.has_model())
    extra["provenance"]["model"] = {{"path", fs::absolute(o.session.model_path).string()}, {"sha256", model_sha256},
                                    {"config", session.model_config().summary()}};
  return extra;
}

void report(const UnrollOptions& o, const nlohmann::json& summary, const UnrollSession& session) {
  const nlohmann::json& traffic = summary["device_traffic_per_gs_frame"];
  auto stages = [](const nlohmann::json& ms) {
    std::string s;
    for (const auto& [name, v] : ms.items()) s += (s.empty() ? "" : ", ") + name + " " + std::to_string(std::lround(v.get<double>()));
    return s;
  };
  std::ostringstream line;
  line << "unroll: " << summary["frames"] << " frame(s), " << summary["targets"] << " GS frame(s), mode "
            << summary["mode"].get<std::string>() << ", " << summary["ms_per_gs_frame_total"].get<double>()
            << " ms per GS frame (by stage, ms: " << stages(summary["ms_per_gs_frame"]) << "; "
            << (summary["gpu_ms_per_gs_frame"].is_null()
                    ? "GPU time not measured: " + opt("profile") + " or " + opt("trace")
                    : "GPU ms " + std::to_string(summary["gpu_ms_per_gs_frame"].get<double>()) + " inside the wait: " +
                          stages(summary["gpu_ms_per_gs_frame_by_stage"]))
            << "), per GS frame " << traffic["upload_bytes"].get<double>() / 1e6 << " MB up, " << traffic["download_bytes"].get<double>() / 1e6
            << " MB down, " << traffic["submits"].get<double>() << " submits, " << traffic["dispatches"].get<double>()
            << " dispatches; peak device memory "
            << (session.peak_device_bytes() >> 20) << " MiB";
  log_info(line.str());
  if (summary.contains("resume")) {
    std::ostringstream resume;
    resume << "unroll: resume: " << summary["resume"]["reused"] << " GS frame(s) reused, " << summary["resume"]["computed"] << " computed";
    log_info(resume.str());
  }
  if (summary.contains("metrics")) {
    std::ostringstream metrics;
    metrics << "unroll: vs ground truth (" << summary["metrics"]["count"] << " frames): PSNR " << summary["metrics"]["mean_psnr"]
            << " dB, SSIM " << summary["metrics"]["mean_ssim"] << "; RS input: PSNR " << summary["metrics"]["rs_mean_psnr"]
            << " dB, SSIM " << summary["metrics"]["rs_mean_ssim"];
    log_info(metrics.str());
  }
  log_info("unroll: wrote " + o.out_dir);
}

// 10x slow motion of the recording, unless the options name a rate.
UnrollOutputOptions output_options(const UnrollOptions& o, const Sequence& seq, const UnrollJob& job) {
  UnrollOutputOptions out = o.output;
  if (!out.video_fps && seq.frames.size() > 1) {
    const double period = frame_mid(seq.frames[1]) - frame_mid(seq.frames[0]);
    const double per_frame = static_cast<double>(job.total_targets()) / double(job.frames().size());
    if (period > 0) out.video_fps = std::clamp(per_frame * 1e6 / period / 10.0, 1.0, 60.0);
  }
  return out;
}

// --follow: frames are waited for (not checked up front) and the events come from the stream.
SequenceOptions follow_sequence_options(const UnrollOptions& o) {
  SequenceOptions so = o.sequence_options;
  if (!o.follow.enabled) return so;
  so.check_frame_sizes = false;
  so.events_file = o.follow.events == "-" ? std::string("/dev/stdin") : o.follow.events;
  return so;
}

// summary.json's "follow" (follow_summary) and, in the log, why a stopped stream stopped.
nlohmann::json follow_report(const FollowFrameSource& source, const FollowSink& sink, const std::optional<StreamStopped>& stop,
                             size_t planned, nlohmann::json& warnings) {
  std::vector<std::string> said;
  nlohmann::json j = follow_summary(source, sink, stop ? &*stop : nullptr, planned, said);
  for (const auto& w : said) warnings.push_back(w);
  if (stop && stop->kind == StreamStopped::Kind::requested)
    log_warning("unroll: stopped: " + stop->text() + "; " + j["gs_frames"].dump() + " of " + std::to_string(planned) +
                " GS frame(s) written");
  return j;
}

}  // namespace

namespace {

// --trace under the output rule of every writer (output_paths.hpp): never an input of the run, the
// --out folder or inside it, a link, a device or a file vkunroll did not write; its folder exists
// and takes a file. `seq`: the loaded sequence (its event files may lie outside its folder).
void check_trace_path(const UnrollOptions& o, const Sequence* seq) {
  std::vector<std::pair<std::string, std::string>> inputs = {{opt("sequence"), o.sequence},
                                                             {opt("events") + " file", o.sequence_options.events_file.value_or("")},
                                                             {opt("model") + " file", o.session.model_path}};
  if (seq)
    for (const auto& f : seq->event_files) inputs.emplace_back("event file", f);
  const std::string& path = o.trace_path;
  check_output_file_rule(path, output_path("unroll.trace"), o.output.existing, inputs);
  std::error_code ec;
  const fs::path trace = fs::weakly_canonical(fs::absolute(path), ec), out = fs::weakly_canonical(fs::absolute(o.out_dir), ec);
  if (!ec && (trace == out || (trace.string().rfind(out.string() + "/", 0) == 0)))
    throw OptionError("trace", path, "apart from the output",
                      opt("trace") + " " + path + ": " + (trace == out ? "is" : "lies inside") + " the " + opt("out") +
                          " folder, which is replaced whole when the run commits: write the trace outside it");
  const fs::path dir = fs::absolute(path).parent_path();
  if (!fs::is_directory(dir)) throw OptionError("trace", path, "the folder " + dir.string() + " does not exist");
  // The file is written after the run: a name no file system takes is refused before it.
  if (fs::path(path).filename().string().size() > 200) throw OptionError("trace", path.substr(0, 40) + "...", "a file name of at most 200 bytes");
  check_output_folder_writable(path, "trace");
}

}  // namespace

nlohmann::json run_unroll(const UnrollOptions& o) {
  const Stopwatch since_start;
  validate_unroll_options(o);  // a refused option does not wait for the sequence to load
  check_unroll_inputs(o);
  SessionOptions session_options = o.session;
  session_options.announce = session_options.announce && !o.quiet;
  session_options.trace = session_options.trace || !o.trace_path.empty();
  if (!o.trace_path.empty()) check_trace_path(o, nullptr);  // refused now, not after the run
  if (o.mode == UnrollMode::physics) session_options.model_path.clear();
  // The model and the device before the sequence: their errors come first.
  UnrollSession session = in_device_stage("setting up the device and the model", [&] { return UnrollSession(session_options); });
  const double setup_ms = since_start.ms();
  const Stopwatch loading;
  const Sequence seq = load_sequence(o.sequence, follow_sequence_options(o));
  const double load_ms = loading.ms();
  std::vector<std::pair<std::string, std::string>> event_files;  // meta.json may name files outside the folder
  for (const auto& f : seq.event_files) event_files.emplace_back("event file", f);
  check_output_apart(o.out_dir, "out", event_files);
  if (!o.trace_path.empty()) check_trace_path(o, &seq);
  std::optional<InterruptFlag> interrupt;  // --follow: SIGINT stops the stream cleanly
  if (o.follow.enabled) interrupt.emplace();
  std::unique_ptr<FrameSource> source;
  FollowFrameSource* follow = nullptr;
  if (o.follow.enabled) source = std::make_unique<FollowFrameSource>(seq, o.follow), follow = static_cast<FollowFrameSource*>(source.get());
  else source = std::make_unique<SequenceFrameSource>(seq);
  std::optional<UnrollJob> planned;
  try {
    planned.emplace(o, session, *source);
  } catch (const StreamStopped& e) {
    throw DataError(opt("follow") + ": the stream stopped before the job was planned (nothing written): " + e.text());
  }
  UnrollJob& job = *planned;
  job.add_stage_ms(Stage::setup, setup_ms);  // the device, the model and the shaders
  job.add_stage_ms(Stage::read, load_ms);    // the sequence's load

  const std::string model_sha = session.has_model() ? sha256_file(o.session.model_path) : std::string();
  UnrollOutputOptions out_options = output_options(o, seq, job);
  out_options.resume_key = resume_key(o, job.mode(), session, job.physics().params, model_sha);
  UnrollOutput output(o.out_dir, out_options);
  Progress progress("unroll", job.total_targets(), Progress::automatic(o.quiet));
  FolderSink sink(output, progress, seq, o.output.existing == ExistingOutput::resume);
  std::optional<FollowSink> follow_sink;
  if (follow) {
    follow_sink.emplace(sink, *follow, job);
    if (!o.quiet) log_info("unroll: following " + o.follow.events + "; GS frames appear in " + output.staging().string());
  }
  std::optional<StreamStopped> stopped;
  try {
    job.run(follow_sink ? static_cast<ResultSink&>(*follow_sink) : sink);
  } catch (const StreamStopped& e) {
    stopped = e;
  }
  progress.finish();

  nlohmann::json extra = summary_extra(o, job, session, seq, model_sha, since_start.ms());  // the whole run, as the frames' time
  if (output.replaces_existing())
    extra["notes"].push_back("replaced the earlier output in " + output.dir().string() + " (" +
                             existing_output_name(o.output.existing) + ")");
  if (follow) extra["follow"] = follow_report(*follow, *follow_sink, stopped, job.total_targets(), extra["warnings"]);
  extra["provenance"]["finished_utc"] = utc_now();
  if (const Trace* trace = session.trace(); trace && !o.trace_path.empty()) {  // before the output claims success
    check_trace_path(o, &seq);  // a file that appeared during the run is not replaced either
    try {
      trace->write(o.trace_path);
    } catch (const Error& e) {
      throw OptionError("trace", o.trace_path, e.text(), opt("trace") + " " + e.text(), ErrorKind::io);
    }
    extra["trace"] = {{"file", o.trace_path}, {"spans", trace->spans()}};
  }
  spell_options(extra, o.option_spelling);
  for (const auto& w : extra["warnings"]) log_warning("unroll: warning: " + w.get<std::string>());  // even under --quiet
  nlohmann::json summary = output.finish(extra);
  if (!o.quiet) report(o, summary, session);
  return summary;
}

}  // namespace vkunroll
