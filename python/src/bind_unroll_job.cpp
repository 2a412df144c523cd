// vkunroll.unroll's native half: the library's UnrollJob (host/unroll/unroll_job.hpp) over a
// sequence or arrays, into an array sink. Python only converts arguments (vkunroll/_unroll.py).
#include <optional>
#include <opencv2/core.hpp>

#include "common.hpp"
#include "py_session.hpp"
#include "vkunroll/host/unroll/follow_source.hpp"
#include "vkunroll/host/unroll/unroll_job.hpp"
#include "vkunroll/host/unroll/unroll_output.hpp"

namespace vkunroll::python {

namespace {

using namespace pybind11::literals;

// Python's arguments as the job's options: the CLI's checks and texts (validate_unroll_options).
UnrollOptions job_options(const PySession& ps, const py::dict& a) {
  UnrollOptions o;
  o.sequence = "unroll";  // prefixes the planner's messages
  o.out_dir = "(python)";
  o.session.model_path = ps.model_path;
  o.mode = parse_unroll_mode(a["mode"].cast<std::string>(), "mode");
  const std::string kind = a["kind"].cast<std::string>();
  if (kind == "tau") o.times.kind = TargetTimes::Kind::normalized;
  else if (kind == "us") o.times.kind = TargetTimes::Kind::absolute_us;
  else if (kind == "gt") o.times.kind = TargetTimes::Kind::ground_truth;
  else throw UsageError("times: kind '" + kind + "' (expected tau, us or gt)");
  o.times.values = to_rationals(a["values"].cast<py::sequence>(), kind == "us" ? "times_us" : "times");
  o.frames = a["frames"].cast<std::vector<int>>();
  for (int k : o.frames)
    if (k < 0) throw UsageError("frames: frame index " + std::to_string(k) + " is negative");
  o.channel_order = parse_channel_order(a["channel_order"].cast<std::string>(), "channel_order");
  if (!a["contrast"].is_none()) o.contrast = a["contrast"].cast<double>();
  if (!a["gamma"].is_none()) o.gamma = a["gamma"].cast<double>();
  o.gate_radius = parse_gate_radius(py::str(a["gate_radius"]).cast<std::string>(), "gate_radius");
  o.tile = a["tile"].cast<int64_t>();
  o.halo = a["halo"].cast<int64_t>();
  o.sparse = parse_sparse_policy(a["sparse"].cast<std::string>(), "sparse");
  o.sparse_threshold = a["sparse_threshold"].cast<double>();
  validate_unroll_options(o);
  return o;
}

// Every GS frame kept in memory (clamped to [0, 1], as the CLI's PNGs), scored as the CLI scores.
class ArraySink : public ResultSink {
 public:
  explicit ArraySink(py::object progress) : progress_(std::move(progress)) {}

  void add(const GsResult& r) override {
    cv::Mat image = cv::min(cv::max(r.image, 0.0), 1.0);
    GsFrameRecord rec;
    rec.frame = r.frame;
    rec.t_us = r.target->t_us.to_double();
    rec.tau = r.target->tau;
    score_against_ground_truth(rec, image, r.rs_input, r.ground_truth, "");
    images.push_back(std::move(image));
    records.push_back(rec);
    targets.push_back({r.frame, r.target->t_us, r.target->tau, r.method, r.target->gt});
  }

  void frame_finished(int frame, size_t done, size_t total) override {
    if (progress_.is_none()) return;
    py::gil_scoped_acquire gil;  // the job runs with the GIL released
    progress_(done, total, py::dict("frame"_a = frame));  // an exception it raises stops the job
  }

  struct Target {
    int frame;
    Rational t_us;
    double tau;
    FrameTarget::Method method;
    int gt;
  };
  std::vector<cv::Mat> images;
  std::vector<GsFrameRecord> records;
  std::vector<Target> targets;

 private:
  py::object progress_;
};

py::array_t<double> metric_array(const std::vector<GsFrameRecord>& records, std::optional<double> GsFrameRecord::*field) {
  std::vector<double> v;
  for (const auto& r : records) v.push_back((r.*field).value_or(std::nan("")));
  const auto n = static_cast<py::ssize_t>(v.size());
  return to_numpy(std::move(v), {n});
}

// Runs the job; returns (frames: list of RGB arrays, targets: list of dicts, metrics: dict,
// report: summary.json's JSON text of what the job did).
py::tuple run_job(PySession& ps, FrameSource& source, const py::dict& args, const py::object& progress) {
  const UnrollOptions o = guarded({}, [&] { return job_options(ps, args); });
  ArraySink sink(progress);
  const std::string report = without_gil({}, [&] {
    std::lock_guard<std::mutex> lock(ps.mutex);
    UnrollJob job(o, *ps.session, source);
    ps.to_model = job.physics().to_model;
    job.run(sink);
    nlohmann::json r = job.report();
    spell_options(r, python_keyword);
    return r.dump();
  });
  py::list images, targets;
  for (const cv::Mat& im : sink.images) images.append(bgr_mat_to_rgb(im));
  for (const auto& t : sink.targets)
    targets.append(py::dict("frame"_a = t.frame, "t_us"_a = to_fraction(t.t_us), "tau"_a = t.tau,
                            "method"_a = frame_method_name(t.method), "gt"_a = t.gt));
  py::dict metrics("psnr"_a = metric_array(sink.records, &GsFrameRecord::psnr),
                   "ssim"_a = metric_array(sink.records, &GsFrameRecord::ssim),
                   "rs_psnr"_a = metric_array(sink.records, &GsFrameRecord::rs_psnr),
                   "rs_ssim"_a = metric_array(sink.records, &GsFrameRecord::rs_ssim));
  const nlohmann::json means = metric_means(sink.records);
  for (const auto& [k, v] : means.items())
    metrics[py::str(k)] = k == "count" ? py::object(py::int_(v.get<int>())) : py::object(py::float_(v.get<double>()));
  return py::make_tuple(images, targets, metrics, report);
}

// vkunroll.stream's sink: each frame's GS images handed to Python as soon as the frame is done.
class StreamSink : public ResultSink {
 public:
  explicit StreamSink(py::object on_frame) : on_frame_(std::move(on_frame)) {}
  void add(const GsResult& r) override {
    images_.push_back(cv::min(cv::max(r.image, 0.0), 1.0));
    targets_.push_back({r.frame, r.target->t_us, r.target->tau, r.method, r.target->gt});
    window_ = r.events_window.empty() ? "whole" : r.events_window;
  }
  void frame_finished(int frame, size_t done, size_t total) override {
    py::gil_scoped_acquire gil;
    py::list images, targets;
    for (const cv::Mat& im : images_) images.append(bgr_mat_to_rgb(im));
    for (const auto& t : targets_)
      targets.append(py::dict("frame"_a = t.frame, "t_us"_a = to_fraction(t.t_us), "tau"_a = t.tau,
                              "method"_a = frame_method_name(t.method), "gt"_a = t.gt));
    images_.clear(), targets_.clear();
    on_frame_(py::dict("frame"_a = frame, "images"_a = images, "targets"_a = targets, "done"_a = done, "total"_a = total,
                       "events_window"_a = window_));
  }

 private:
  py::object on_frame_;
  std::string window_ = "whole";
  std::vector<cv::Mat> images_;
  std::vector<ArraySink::Target> targets_;
};

// The --follow job over a live sequence folder: frames to on_frame as they complete; returns the
// job's report with "follow" (complete or stopped, latency, the stream's counts) as JSON text.
std::string run_stream(PySession& ps, const Sequence& seq, const py::dict& args, FollowOptions follow, py::object on_frame,
                       py::object should_stop) {
  follow.enabled = true;
  const UnrollOptions o = guarded({}, [&] {
    UnrollOptions checked = job_options(ps, args);
    checked.follow = follow;
    validate_unroll_options(checked);  // the CLI's texts for idle_s and max_events
    return checked;
  });
  follow.stop_requested = [should_stop] {
    py::gil_scoped_acquire gil;
    return should_stop().cast<bool>();
  };
  StreamSink inner(std::move(on_frame));
  return without_gil({}, [&] {
    std::lock_guard<std::mutex> lock(ps.mutex);
    FollowFrameSource source(seq, follow);
    std::optional<UnrollJob> job;
    try {
      job.emplace(o, *ps.session, source);
    } catch (const StreamStopped& e) {
      throw DataError("stream: the stream stopped before the job was planned: " + e.text());
    }
    ps.to_model = job->physics().to_model;
    FollowSink sink(inner, source, *job);
    std::optional<StreamStopped> stopped;
    try {
      job->run(sink);
    } catch (const StreamStopped& e) {
      stopped = e;
    }
    nlohmann::json report = job->report();
    std::vector<std::string> warnings;
    report["follow"] = follow_summary(source, sink, stopped ? &*stopped : nullptr, job->total_targets(), warnings);
    for (const auto& w : warnings) report["warnings"].push_back(w);
    spell_options(report, python_keyword);
    return report.dump();
  });
}

}  // namespace

void bind_unroll_job(py::module_& m) {
  m.def(
      "_unroll_sequence",
      [](PySession& ps, const Sequence& seq, const py::dict& args, const py::object& progress) {
        SequenceFrameSource source(seq);
        return run_job(ps, source, args, progress);
      },
      py::arg("session"), py::arg("sequence"), py::arg("args"), py::arg("progress"));
  m.def(
      "_unroll_arrays",
      [](PySession& ps, const std::vector<F32Array>& frames, const std::vector<RowTiming>& timings, const I64Array& t,
         const U16Array& x, const U16Array& y, const I8Array& p, const py::sequence& gt_times,
         const std::vector<F32Array>& gt_images, const py::dict& args, const py::object& progress) {
        std::unique_ptr<ArrayFrameSource> source = guarded({}, [&] {
          std::vector<cv::Mat> bgr;
          for (size_t k = 0; k < frames.size(); ++k) bgr.push_back(rgb_to_bgr_mat(frames[k], "unroll: frame " + std::to_string(k)));
          if (bgr.empty()) throw UsageError("unroll: no frames");
          const std::vector<Rational> times = to_rationals(gt_times, "ground truth");
          if (times.size() != gt_images.size()) throw UsageError("unroll: ground truth needs one image per instant");
          std::vector<std::pair<Rational, cv::Mat>> gt;
          for (size_t j = 0; j < times.size(); ++j)
            gt.emplace_back(times[j], rgb_to_bgr_mat(gt_images[j], "unroll: ground truth " + std::to_string(j)));
          EventStream ev = to_event_stream(t, x, y, p, bgr[0].cols, bgr[0].rows);
          return std::make_unique<ArrayFrameSource>(std::move(bgr), timings, std::move(ev), std::move(gt), "unroll");
        });
        return run_job(ps, *source, args, progress);
      },
      py::arg("session"), py::arg("frames"), py::arg("timings"), py::arg("t"), py::arg("x"), py::arg("y"), py::arg("p"),
      py::arg("gt_times"), py::arg("gt_images"), py::arg("args"), py::arg("progress"));
  m.def(
      "_stream_sequence",
      [](PySession& ps, const Sequence& seq, const py::dict& args, const std::string& events, double idle_s, size_t max_events,
         py::object on_frame, py::object should_stop) {
        FollowOptions f;
        f.events = events;
        f.idle_s = idle_s;
        f.max_events = max_events;
        return run_stream(ps, seq, args, f, std::move(on_frame), std::move(should_stop));
      },
      py::arg("session"), py::arg("sequence"), py::arg("args"), py::arg("events"), py::arg("idle_s"), py::arg("max_events"),
      py::arg("on_frame"), py::arg("should_stop"));
}

}  // namespace vkunroll::python
