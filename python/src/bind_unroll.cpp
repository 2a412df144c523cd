// UnrollSession for Python (vkunroll._Session: one frame at a time) and the library's unroll job
// (host/unroll/unroll_job.hpp) over a sequence or arrays, into an array sink (bind_unroll_job.cpp).
#include "common.hpp"
#include "py_session.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/host/unroll/default_model.hpp"
#include "vkunroll/host/unroll/session.hpp"
#include "vkunroll/host/unroll/unroll_plan.hpp"

namespace vkunroll::python {

namespace {

py::dict stats_dict(const UnrollSession& s) {
  const SessionStats& st = s.stats();
  py::dict d;
  d["runs_s"] = st.runs_s;
  d["runs_m"] = st.runs_m;
  d["runs_physics"] = st.runs_physics;
  d["frames_unrolled"] = st.frames_unrolled;
  d["image_uploads"] = st.image_uploads;
  d["physics_on_cpu"] = st.physics_on_cpu;
  d["host_path_targets"] = st.host_path_targets;
  d["tiles"] = st.tiles;
  d["tiles_run"] = st.tiles_run;
  d["tile_used"] = st.tile_used;
  d["tiles_per_target"] = st.tiles_per_target;
  d["work_pixels"] = st.work_pixels;
  d["target_active_fraction"] = st.target_active_fraction;
  py::dict ms;
  for (const auto& [stage, v] : st.ms) ms[stage_name(stage)] = v;
  d["ms"] = ms;
  const DeviceTraffic t = s.traffic();
  d["upload_bytes"] = t.upload_bytes;
  d["download_bytes"] = t.download_bytes;
  d["submits"] = t.submits;
  d["dispatches"] = t.dispatches;
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
      ts.push_back({to_rational(t[0], "target t_us"), parse_frame_method(t[1].cast<std::string>(), "target method")});
    }
  });
  in.events = &events;
  return without_gil({}, [&] {
    std::lock_guard<std::mutex> lock(ps.mutex);
    // As run_unroll: the model sees its own encoding; physics targets stay in the sequence's.
    in.rs1 = encode_for_model(in.rs1, ps.to_model);
    if (!in.rs2.empty()) in.rs2 = encode_for_model(in.rs2, ps.to_model);
    std::vector<cv::Mat> out = ps.session->unroll(in, ts);
    decode_model_results(out, ts, ps.to_model);
    return out;
  });
}

// The library's UnrollSession as vkunroll._Session.
void bind_session(py::module_& m) {
  py::class_<PySession, std::shared_ptr<PySession>>(m, "_Session")
      .def(py::init([](const std::string& model_path, const std::string& backend, const std::string& device,
                       const std::string& precision, unsigned cpu_threads, bool profile, const std::string& conv_choice) {
             SessionOptions o = guarded({{model_path}}, [&] {
               SessionOptions so;
               so.backend = parse_backend_kind(backend, "backend");
               so.device = device;
               so.precision = parse_precision(precision, "precision");
               so.model_path = model_path;
               so.cpu_threads = cpu_threads;
               so.profile_ops = profile;
               so.conv_choice = parse_conv_choice(conv_choice, "conv_choice");
               return so;
             });
             auto ps = std::make_shared<PySession>();
             ps->model_path = model_path;
             CallInfo call{{model_path}, o.backend == BackendKind::vulkan};
             ps->session = without_gil(call, [&] { return std::make_unique<UnrollSession>(o); });
             return ps;
           }),
           py::arg("model_path"), py::arg("backend"), py::arg("device"), py::arg("precision"), py::arg("cpu_threads"),
           py::arg("profile") = false, py::arg("conv_choice") = "auto")
      .def_property_readonly("has_model", [](const PySession& s) { return s.session->has_model(); })
      .def_property_readonly("moa", [](const PySession& s) { return s.session->has_model() && s.session->model_config().moa; })
      .def_property_readonly("backend", [](const PySession& s) { return std::string(backend_kind_name(s.session->backend_kind())); })
      .def_property_readonly("device",
                             [](const PySession& s) { return s.session->context() ? s.session->context()->info().name : std::string("cpu"); })
      .def_property_readonly("model_summary",
                             [](const PySession& s) { return s.session->has_model() ? s.session->model_config().summary() : std::string(); })
      .def_property("model_rgb", [](const PySession& s) { return s.session->model_rgb(); },
                    [](PySession& s, bool rgb) { s.session->set_model_rgb(rgb); })
      .def("stats", [](const PySession& s) { return stats_dict(*s.session); })
      .def(
          "unroll_frame",
          [](PySession& ps, const F32Array& rs1, const RowTiming& timing1, const py::object& rs2, const py::object& timing2,
             const I64Array& t, const U16Array& x, const U16Array& y, const I8Array& p, const py::list& targets) {
            const EventStream ev = guarded({}, [&] {
              if (rs1.ndim() != 3 || rs1.shape(2) != 3) throw UsageError("unroll: rs1 must be an H x W x 3 float image");
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
      return std::make_pair(c.path, spell_fields(c.source, python_keyword));
    });
  }, py::arg("mode"), py::arg("given"));

  bind_unroll_job(m);
}

}  // namespace vkunroll::python
