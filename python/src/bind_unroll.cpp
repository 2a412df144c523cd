// The unroll job for Python: UnrollSession frame by frame, with run_unroll's planning
// (host/unroll/unroll_plan.hpp). The Python layer (vkunroll/_unroll.py) drives the frames.
#include "common.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/host/unroll/default_model.hpp"
#include "vkunroll/host/unroll/session.hpp"
#include "vkunroll/host/unroll/unroll.hpp"
#include "vkunroll/host/unroll/unroll_plan.hpp"

namespace vkunroll::python {

namespace {

struct PySession {
  std::unique_ptr<UnrollSession> session;
  std::mutex mutex;  // one frame at a time (the session's buffers and device queue)
  // Frames go into the model as v^to_model, its results come back as v^(1/to_model) (plan_physics).
  double to_model = 1.0;
};

const char* method_name(FrameTarget::Method m) {
  switch (m) {
    case FrameTarget::Method::s: return "s";
    case FrameTarget::Method::m: return "m";
    case FrameTarget::Method::physics: return "physics";
  }
  return "?";
}

FrameTarget::Method parse_method(const std::string& s) {
  if (s == "s") return FrameTarget::Method::s;
  if (s == "m") return FrameTarget::Method::m;
  if (s == "physics") return FrameTarget::Method::physics;
  throw Error("unroll: target method '" + s + "' (expected s, m or physics)");
}

// A Sequence that holds only timing (and ground-truth instants): what the planner reads.
Sequence timing_sequence(const std::vector<RowTiming>& timings, const std::vector<Rational>& gt_times) {
  Sequence seq;
  for (const RowTiming& t : timings) seq.frames.push_back({"", t});
  for (const Rational& t : gt_times) seq.ground_truth.push_back({"", t});
  if (!timings.empty()) seq.height = timings.front().rows;
  return seq;
}

// The checks run_unroll makes before any work (validate_unroll_options), on the Python arguments.
void validate(const std::string& mode, bool has_model, int64_t tile, int64_t halo, const std::string& sparse,
              double threshold, const py::object& contrast, const py::object& gamma, TargetTimes::Kind kind,
              size_t n_values) {
  UnrollOptions o;
  o.sequence = o.out_dir = "(python)";
  o.mode = parse_unroll_mode(mode, "mode");
  if (has_model) o.session.model_path = "(model)";
  o.tile = tile;
  o.halo = halo;
  o.sparse = parse_sparse_policy(sparse, "sparse");
  o.sparse_threshold = threshold;
  if (!contrast.is_none()) o.contrast = contrast.cast<double>();
  if (!gamma.is_none()) o.gamma = gamma.cast<double>();
  o.times.kind = kind;
  o.times.values.assign(n_values, Rational(0));
  validate_unroll_options(o);
}

py::list plan(const std::vector<RowTiming>& timings, const std::vector<Rational>& gt_times, const std::vector<int>& requested,
              const TargetTimes& times, UnrollMode mode, bool moa, std::map<std::string, int>& notes) {
  const Sequence seq = timing_sequence(timings, gt_times);
  if (seq.frames.empty()) throw Error("unroll: the sequence has no frames");
  const std::vector<int> frames = chosen_frames(seq, requested);
  const auto targets = plan_targets(seq, frames, times, "unroll");
  py::list out;
  for (int k : frames) {
    auto it = targets.find(k);
    if (it == targets.end()) continue;
    const SequenceFrame& f1 = seq.frames[k];
    const bool has_next = k + 1 < static_cast<int>(seq.frames.size());
    std::vector<FrameTarget> methods;
    for (const UnrollTarget& t : it->second) {
      const double tv = t.t_us.to_double();
      const bool inside = tv >= f1.timing.first_start().to_double() && tv <= f1.timing.last_end().to_double();
      methods.push_back({t.t_us, target_method(mode, moa, has_next, inside, k, notes)});
    }
    const bool any_m = std::any_of(methods.begin(), methods.end(), [](const FrameTarget& t) { return t.method == FrameTarget::Method::m; });
    const auto [lo, hi] = frame_window(f1, any_m ? &seq.frames[k + 1] : nullptr, it->second, methods);
    py::list ts;
    for (size_t j = 0; j < methods.size(); ++j) {
      py::dict d;
      d["t_us"] = to_fraction(it->second[j].t_us);
      d["tau"] = it->second[j].tau;
      d["gt"] = it->second[j].gt;
      d["method"] = method_name(methods[j].method);
      ts.append(d);
    }
    py::dict f;
    f["frame"] = k;
    f["next"] = any_m ? k + 1 : -1;
    f["targets"] = ts;
    f["window_us"] = py::make_tuple(lo, hi);
    out.append(f);
  }
  return out;
}

py::dict stats_dict(const UnrollSession& s) {
  const SessionStats& st = s.stats();
  py::dict d;
  d["runs_s"] = st.runs_s;
  d["runs_m"] = st.runs_m;
  d["runs_physics"] = st.runs_physics;
  d["physics_on_cpu"] = st.physics_on_cpu;
  d["host_path_targets"] = st.host_path_targets;
  d["tiles"] = st.tiles;
  d["tiles_run"] = st.tiles_run;
  d["tile_used"] = st.tile_used;
  d["tiles_per_target"] = st.tiles_per_target;
  d["work_pixels"] = st.work_pixels;
  d["target_active_fraction"] = st.target_active_fraction;
  d["ms"] = st.ms;
  const DeviceTraffic t = s.traffic();
  d["upload_bytes"] = t.upload_bytes;
  d["download_bytes"] = t.download_bytes;
  d["submits"] = t.submits;
  d["gpu_ms"] = t.gpu_ms;
  d["memory_forced_submits"] = s.memory_forced_submits();
  d["peak_device_bytes"] = s.peak_device_bytes();
  return d;
}

std::vector<cv::Mat> unroll_frame(PySession& ps, const F32Array& rs1, const RowTiming& timing1, const py::object& rs2,
                                  const py::object& timing2, const EventStream& events, const py::list& targets) {
  FrameInput in;
  std::vector<FrameTarget> ts;
  guarded({}, [&] {
    in.rs1 = rgb_to_bgr_mat(rs1, "unroll: rs1");
    in.timing1 = timing1;
    if (!rs2.is_none()) {
      in.rs2 = rgb_to_bgr_mat(rs2.cast<F32Array>(), "unroll: rs2");
      in.timing2 = timing2.cast<RowTiming>();
    }
    for (size_t j = 0; j < targets.size(); ++j) {
      const py::tuple t = targets[j].cast<py::tuple>();
      ts.push_back({to_rational(t[0], "target t_us"), parse_method(t[1].cast<std::string>())});
    }
  });
  in.events = &events;
  return without_gil({}, [&] {
    std::lock_guard<std::mutex> lock(ps.mutex);
    // As run_unroll: the model sees its own encoding; physics targets stay in the sequence's.
    in.rs1 = encode_for_model(in.rs1, ps.to_model);
    if (!in.rs2.empty()) in.rs2 = encode_for_model(in.rs2, ps.to_model);
    std::vector<cv::Mat> out = ps.session->unroll(in, ts);
    for (size_t j = 0; j < out.size(); ++j)
      if (ts[j].method != FrameTarget::Method::physics) out[j] = encode_for_model(out[j], 1.0 / ps.to_model);
    return out;
  });
}

// The library's UnrollSession as vkunroll._Session.
void bind_session(py::module_& m) {
  py::class_<PySession, std::shared_ptr<PySession>>(m, "_Session")
      .def(py::init([](const std::string& model_path, const std::string& backend, const std::string& device,
                       const std::string& precision, unsigned cpu_threads) {
             SessionOptions o = guarded({{model_path}}, [&] {
               SessionOptions so;
               so.backend = parse_backend_kind(backend, "backend");
               so.device = device;
               so.precision = parse_precision(precision, "precision");
               so.model_path = model_path;
               so.cpu_threads = cpu_threads;
               return so;
             });
             auto ps = std::make_shared<PySession>();
             CallInfo call{{model_path}, o.backend == BackendKind::vulkan};
             ps->session = without_gil(call, [&] { return std::make_unique<UnrollSession>(o); });
             return ps;
           }),
           py::arg("model_path"), py::arg("backend"), py::arg("device"), py::arg("precision"), py::arg("cpu_threads"))
      .def_property_readonly("has_model", [](const PySession& s) { return s.session->has_model(); })
      .def_property_readonly("moa", [](const PySession& s) { return s.session->has_model() && s.session->model_config().moa; })
      .def_property_readonly("backend", [](const PySession& s) { return std::string(backend_kind_name(s.session->backend_kind())); })
      .def_property_readonly("device",
                             [](const PySession& s) { return s.session->context() ? s.session->context()->info().name : std::string("cpu"); })
      .def_property_readonly("model_summary",
                             [](const PySession& s) { return s.session->has_model() ? s.session->model_config().summary() : std::string(); })
      .def_property("model_rgb", [](const PySession& s) { return s.session->model_rgb(); },
                    [](PySession& s, bool rgb) { s.session->set_model_rgb(rgb); })
      .def("set_tiling",
           [](PySession& s, int64_t tile, int64_t halo, const std::string& sparse, double threshold) {
             TileOptions t;
             t.sparse = guarded({}, [&] { return parse_sparse_policy(sparse, "sparse"); });
             const bool on = t.sparse != SparsePolicy::off;
             t.tile = tile > 0 ? tile : (on ? kTileAlign : 0);
             t.halo = halo >= 0 ? halo : (on ? kTileAlign : 2 * kTileAlign);
             t.threshold = threshold;
             s.session->set_tiling(t);
           })
      .def(
          "plan_physics",
          [](PySession& ps, const std::string& mode, double seq_gamma, const py::object& contrast, const py::function& estimate) {
            const PhysicsPlan p = guarded({}, [&] {
              std::optional<double> c;
              if (!contrast.is_none()) c = contrast.cast<double>();
              return plan_physics(parse_unroll_mode(mode, "mode"), *ps.session, seq_gamma, c,
                                  [&](double gamma) {
                                    const auto t = estimate(gamma).cast<std::tuple<double, std::string, std::string>>();
                                    return ContrastEstimate{std::get<0>(t), std::get<1>(t), std::get<2>(t)};
                                  });
            });
            ps.session->set_physics(p.params);
            ps.to_model = p.to_model;
            py::dict d;
            d["uses_physics"] = p.uses_physics;
            d["variant"] = p.variant;
            d["contrast"] = p.params.contrast;
            d["gamma"] = p.params.gamma;
            d["contrast_source"] = p.contrast_source;
            d["contrast_warning"] = p.contrast_warning;
            d["seq_gamma"] = p.seq_gamma;
            d["to_model"] = p.to_model;
            return d;
          },
          py::arg("mode"), py::arg("seq_gamma"), py::arg("contrast"), py::arg("estimate"))
      .def("stats", [](const PySession& s) { return stats_dict(*s.session); })
      .def(
          "unroll_frame",
          [](PySession& ps, const F32Array& rs1, const RowTiming& timing1, const py::object& rs2, const py::object& timing2,
             const I64Array& t, const U16Array& x, const U16Array& y, const I8Array& p, const py::list& targets) {
            const EventStream ev = guarded({}, [&] {
              if (rs1.ndim() != 3 || rs1.shape(2) != 3) throw Error("unroll: rs1 must be an H x W x 3 float image");
              return to_event_stream(t, x, y, p, static_cast<int>(rs1.shape(1)), static_cast<int>(rs1.shape(0)));
            });
            const std::vector<cv::Mat> out = unroll_frame(ps, rs1, timing1, rs2, timing2, ev, targets);
            py::list images;
            for (const cv::Mat& im : out) images.append(bgr_mat_to_rgb(im));
            return images;
          },
          py::arg("rs1"), py::arg("timing1"), py::arg("rs2"), py::arg("timing2"), py::arg("t"), py::arg("x"), py::arg("y"),
          py::arg("p"), py::arg("targets"));
}

}  // namespace

void bind_unroll(py::module_& m) {
  bind_session(m);

  // The shipped default model, by the CLI's rule (host/unroll/default_model.hpp).
  m.def("default_model", [] {
    return guarded({}, [] {
      const DefaultModelSearch d = find_default_model();
      return d.path.empty() ? std::optional<std::string>() : std::optional<std::string>(d.path);
    });
  }, "The shipped default model's path (VKUNROLL_MODEL, the install prefix, the source tree), or None.");
  m.def("_choose_model", [](const std::string& mode, const std::string& given) {
    return without_gil({}, [&] {
      const ModelChoice c = choose_model(parse_unroll_mode(mode, "mode"), given);
      return std::make_pair(c.path, c.source);
    });
  }, py::arg("mode"), py::arg("given"));

  m.def(
      "_plan",
      [](const std::vector<RowTiming>& timings, const py::sequence& gt_times, const std::vector<int>& frames,
         const std::string& kind, const py::sequence& values, const std::string& mode, bool has_model, bool moa,
         int64_t tile, int64_t halo, const std::string& sparse, double threshold, const py::object& contrast,
         const py::object& gamma) {
        return guarded({}, [&] {
          TargetTimes times;
          if (kind == "tau") times.kind = TargetTimes::Kind::normalized;
          else if (kind == "us") times.kind = TargetTimes::Kind::absolute_us;
          else if (kind == "gt") times.kind = TargetTimes::Kind::ground_truth;
          else throw Error("unroll: times kind '" + kind + "'");
          times.values = to_rationals(values, kind == "us" ? "times_us" : "times");
          validate(mode, has_model, tile, halo, sparse, threshold, contrast, gamma, times.kind, times.values.size());
          for (int k : frames)
            if (k < 0) throw Error("frames: frame index " + std::to_string(k) + " is negative");
          UnrollMode um = parse_unroll_mode(mode, "mode");
          if (um == UnrollMode::automatic && !has_model) um = UnrollMode::physics;
          if (um == UnrollMode::m && !moa)
            throw Error("mode m: the model has no MOA weights (attfusion_net), so it runs SelfUnroll-S only; use mode='s'");
          std::map<std::string, int> notes;
          py::list frames_plan = plan(timings, to_rationals(gt_times, "ground truth"), frames, times, um, moa, notes);
          py::list note_list;
          for (const auto& [n, c] : notes) note_list.append(n + (c > 1 ? " (x" + std::to_string(c) + ")" : ""));
          return py::make_tuple(frames_plan, std::string(unroll_mode_name(um)), note_list);
        });
      },
      py::arg("timings"), py::arg("gt_times"), py::arg("frames"), py::arg("kind"), py::arg("values"), py::arg("mode"),
      py::arg("has_model"), py::arg("moa"), py::arg("tile"), py::arg("halo"), py::arg("sparse"), py::arg("threshold"),
      py::arg("contrast"), py::arg("gamma"));

  m.def("_estimate_contrast_sequence", [](const Sequence& seq, const std::vector<int>& frames, double gamma) {
    return without_gil({}, [&] {
      std::vector<int> fs = frames;
      if (fs.empty())
        for (int k = 0; k < static_cast<int>(seq.frames.size()); ++k) fs.push_back(k);
      const ContrastEstimate e = estimate_contrast(seq, fs, gamma);
      return std::make_tuple(e.contrast, e.source, e.warning);
    });
  });

  m.def("_estimate_contrast_arrays",
        [](const std::vector<RowTiming>& timings, const std::vector<int>& frames, double gamma, const std::vector<F32Array>& images,
           const I64Array& t, const U16Array& x, const U16Array& y, const I8Array& p) {
          std::vector<cv::Mat> bgr;
          EventStream ev;
          guarded({}, [&] {
            for (size_t k = 0; k < images.size(); ++k) bgr.push_back(rgb_to_bgr_mat(images[k], "frame " + std::to_string(k)));
            if (bgr.empty()) throw Error("unroll: no frames");
            ev = to_event_stream(t, x, y, p, bgr[0].cols, bgr[0].rows);
          });
          return without_gil({}, [&] {
            auto window = [&](double lo, double hi) {
              EventStream w;
              w.width = ev.width;
              w.height = ev.height;
              const auto b = std::lower_bound(ev.t.begin(), ev.t.end(), static_cast<int64_t>(std::floor(lo)));
              const auto e = std::upper_bound(ev.t.begin(), ev.t.end(), static_cast<int64_t>(std::ceil(hi)));
              const size_t i0 = b - ev.t.begin(), i1 = e - ev.t.begin();
              w.t.assign(ev.t.begin() + i0, ev.t.begin() + i1);
              w.x.assign(ev.x.begin() + i0, ev.x.begin() + i1);
              w.y.assign(ev.y.begin() + i0, ev.y.begin() + i1);
              w.p.assign(ev.p.begin() + i0, ev.p.begin() + i1);
              return w;
            };
            std::vector<int> fs = frames;
            if (fs.empty())
              for (int k = 0; k < static_cast<int>(timings.size()); ++k) fs.push_back(k);
            const ContrastEstimate e =
                estimate_contrast(timings, fs, gamma, bgr[0].cols, bgr[0].rows, [&](int k) { return bgr.at(k); }, window);
            return std::make_tuple(e.contrast, e.source, e.warning);
          });
        });
}

}  // namespace vkunroll::python
