// Model: SelfUnroll-S/-M weights on a VulkanBackend (a shared context) or the CpuBackend, run on raw
// tensors exactly as `vkunroll infer` runs them (Model::run).
#include "common.hpp"
#include "vkunroll/host/model/make_backend.hpp"
#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/model/weights.hpp"
#include "vkunroll/host/unroll/unroll_options.hpp"

namespace vkunroll::python {

namespace {

struct PyModel {
  std::string path;
  ContextPtr ctx;                     // null on the CPU backend
  std::unique_ptr<Backend> backend;   // a VulkanBackend on ctx, or a CpuBackend
  std::unique_ptr<Weights> weights;
  std::unique_ptr<Model> model;
  std::mutex cpu_mutex;               // the CPU backend's buffers: one run at a time

  ~PyModel() {
    // The backend's device buffers go before the context (which the shared pointer may release).
    model.reset();
    backend.reset();
  }
  std::mutex& mutex() { return ctx ? ctx->mutex : cpu_mutex; }
};

py::dict config_dict(const Weights& w) {
  const ModelConfig& c = w.config;
  auto unet = [](const UnetConfig& u) {
    py::dict d;
    d["base"] = u.base;
    d["depth"] = u.depth;
    return d;
  };
  py::dict d;
  d["D"] = c.D;
  d["C"] = c.C;
  d["G"] = c.G;
  d["G0"] = c.G0;
  d["N"] = c.N;
  d["bins"] = c.N;
  d["upnet_width"] = c.upnet_width;
  d["flownet"] = unet(c.flownet);
  d["fusion_net"] = unet(c.fusion_net);
  d["attfusion_net"] = unet(c.attfusion_net);
  d["rdb_slope"] = c.rdb_slope;
  d["unet_slope"] = c.unet_slope;
  d["moa"] = c.moa;
  d["physics_input"] = c.physics_input;
  d["physics_contrast"] = c.physics_contrast;
  d["physics_gate"] = c.physics_gate;  // the variant's event gate radius; -1: no gate
  d["gamma"] = c.gamma ? py::object(py::float_(*c.gamma)) : py::object(py::none());
  d["channel_order"] = c.channel_order;
  d["description"] = c.description;
  d["parameters"] = parameter_count(c);
  d["summary"] = c.summary();
  d["notes"] = w.notes;
  return d;
}

HostTensor host_tensor(const F32Array& a, const char* name) {
  if (a.ndim() != 4) throw UsageError(std::string("Model.run: ") + name + " must have 4 dimensions (B, C, H, W), got " + std::to_string(a.ndim()));
  HostTensor t;
  t.shape = Shape{a.shape(0), a.shape(1), a.shape(2), a.shape(3)};
  t.data.assign(a.data(), a.data() + a.size());
  return t;
}

}  // namespace

void bind_model(py::module_& m) {
  py::class_<PyModel, std::shared_ptr<PyModel>>(m, "_Model")
      .def(py::init([](const std::string& path, const ContextPtr& ctx, const std::string& backend, unsigned threads,
                       const std::string& precision_str, int gate_radius) {
             auto pm = std::make_shared<PyModel>();
             pm->path = path;
             BackendKind kind = BackendKind::vulkan;
             const Precision precision = guarded({{path}}, [&] {
               kind = parse_backend_kind(backend, "backend");
               if (kind == BackendKind::vulkan && !ctx) throw UsageError("Model.load: the vulkan backend needs a context");
               const Precision p = parse_precision(precision_str, "precision");
               if (p == Precision::fp16 && kind == BackendKind::cpu) throw fp16_needs_vulkan();
               if (gate_radius < -1 || gate_radius > kMaxGateRadius)
                 throw UsageError("gate_radius " + std::to_string(gate_radius) + ": expected None or 0.." +
                                  std::to_string(kMaxGateRadius));
               return p;
             });
             without_gil({{path}}, [&] {
               pm->weights = std::make_unique<Weights>(load_weights(path));
               if (gate_radius >= 0) {  // as `unroll --gate-radius N`: the variant's event gate at this radius
                 if (pm->weights->config.physics_gate < 0)
                   throw UsageError(path + ": gate_radius " + std::to_string(gate_radius) + " given, but this model has no event gate");
                 pm->weights->config.physics_gate = gate_radius;
               }
               std::unique_lock<std::mutex> lock;  // the shared device: one user at a time
               if (kind == BackendKind::vulkan) pm->ctx = ctx, lock = std::unique_lock<std::mutex>(ctx->mutex);
               pm->backend = make_backend({.kind = kind, .precision = precision, .cpu_threads = threads},
                                          kind == BackendKind::vulkan ? ctx->ctx.get() : nullptr)
                                 .backend;
               pm->model = std::make_unique<Model>(*pm->backend, *pm->weights);
             });
             return pm;
           }),
           py::arg("path"), py::arg("context"), py::arg("backend"), py::arg("threads"), py::arg("precision"),
           py::arg("gate_radius"))
      .def_readonly("path", &PyModel::path)
      .def_property_readonly("config", [](const PyModel& pm) { return config_dict(*pm.weights); })
      .def_property_readonly("backend", [](const PyModel& pm) { return pm.backend->name(); })
      .def_property_readonly("precision", [](const PyModel& pm) { return std::string(precision_name(pm.backend->precision())); })
      .def(
          "run",
          [](PyModel& pm, const F32Array& rs, const F32Array& ev1, const F32Array& ev2, const F32Array& ev3,
             const py::object& phys, const std::string& mode, const std::string& precision, const std::vector<std::string>& outputs, int max_items, float force_m) {
            ModelInputs in;
            RunOptions opt;
            guarded({}, [&] {
              if (mode != "s" && mode != "m") throw UsageError("Model.run: mode '" + mode + "' (expected s or m)");
              opt.mode = mode == "m" ? Mode::m : Mode::s;
              for (const std::string& name : outputs) opt.outputs.push_back(parse_output(name));
              opt.max_items = max_items;
              opt.force_m = force_m;
              if (!precision.empty()) opt.precision = parse_precision(precision, "precision");
              in = {host_tensor(rs, "rs"), host_tensor(ev1, "ev1"), host_tensor(ev2, "ev2"), host_tensor(ev3, "ev3"), {}};
              if (!phys.is_none()) in.phys = host_tensor(phys.cast<F32Array>(), "phys");
            });
            auto out = without_gil({}, [&] {
              std::lock_guard<std::mutex> lock(pm.mutex());
              return pm.model->run(in, opt);
            });
            py::dict d;
            for (auto& [o, t] : out) {
              const std::vector<py::ssize_t> shape = {t.shape.n, t.shape.c, t.shape.h, t.shape.w};
              d[py::str(output_name(o))] = to_numpy(std::move(t.data), shape);
            }
            return d;
          },
          py::arg("rs"), py::arg("ev1"), py::arg("ev2"), py::arg("ev3"), py::arg("phys"), py::arg("mode"), py::arg("precision"), py::arg("outputs"),
          py::arg("max_items"), py::arg("force_m"));
}

}  // namespace vkunroll::python
