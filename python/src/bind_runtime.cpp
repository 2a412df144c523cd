// devices() and Context: the Vulkan devices the loader sees, and one opened device shared by the
// Python objects that run on it (Model, event tensors, physics).
#include "common.hpp"
#include "vkunroll/host/model/make_backend.hpp"
#include "vkunroll/kernels/event_tensor.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll::python {

SharedContext::SharedContext(std::unique_ptr<Context> c) : ctx(std::move(c)) {}
SharedContext::~SharedContext() {
  // The builder and the backend hold device memory: released before the device.
  builder_.reset();
  backend_.reset();
}

EventTensorBuilder& SharedContext::builder() {
  if (!builder_) builder_ = std::make_unique<EventTensorBuilder>(*ctx);
  return *builder_;
}

Backend& SharedContext::backend() {
  if (!backend_) backend_ = make_backend({}, ctx.get()).backend;
  return *backend_;
}

namespace {

py::dict device_dict(const DeviceInfo& d) {
  py::dict limits;
  limits["max_storage_buffer_range"] = d.max_storage_buffer_range;
  limits["max_uniform_buffer_range"] = d.max_uniform_buffer_range;
  limits["max_shared_memory"] = d.max_shared_memory;
  limits["max_push_constants"] = d.max_push_constants;
  limits["max_workgroup_invocations"] = d.max_workgroup_invocations;
  limits["max_workgroup_count"] = py::make_tuple(d.max_workgroup_count[0], d.max_workgroup_count[1], d.max_workgroup_count[2]);
  limits["max_texel_buffer_elements"] = d.max_texel_buffer_elements;
  limits["min_storage_buffer_offset_alignment"] = d.min_storage_buffer_offset_alignment;
  limits["min_uniform_buffer_offset_alignment"] = d.min_uniform_buffer_offset_alignment;
  limits["timestamp_period_ns"] = d.timestamp_period_ns;
  py::dict out;
  out["index"] = d.index;
  out["name"] = d.name;
  out["type"] = d.type_name();
  out["api_version"] = d.api_version_string();
  out["driver"] = d.driver_name;
  out["driver_info"] = d.driver_info;
  out["vendor_id"] = d.vendor_id;
  out["device_id"] = d.device_id;
  out["subgroup_size"] = d.subgroup_size;
  out["fp16"] = d.shader_float16 && d.storage_buffer_16bit;
  out["shader_float16"] = d.shader_float16;
  out["storage_buffer_16bit"] = d.storage_buffer_16bit;
  out["timestamps"] = d.timestamps;
  out["device_local_bytes"] = d.device_local_bytes;
  out["limits"] = limits;
  return out;
}

}  // namespace

void bind_runtime(py::module_& m) {
  m.def(
      "_devices",
      [](bool validation) {
        const DeviceList list = without_gil({{}, true}, [&] { return Context::enumerate(validation); });
        py::list out;
        for (const DeviceInfo& d : list.devices) {
          py::dict e = device_dict(d);
          e["default"] = d.index == list.policy_choice;
          out.append(e);
        }
        return out;
      },
      py::arg("validation") = false, "Every Vulkan device the loader sees (see vkunroll.devices).");

  py::class_<SharedContext, ContextPtr>(m, "_Context")
      .def(py::init([](const std::string& device, bool validation) {
             ContextOptions o;
             o.device = device;
             o.validation = validation;
             auto ctx = without_gil({{}, true}, [&] { return std::make_unique<Context>(o); });
             return std::make_shared<SharedContext>(std::move(ctx));
           }),
           py::arg("device") = "", py::arg("validation") = false)
      .def_property_readonly("info", [](const SharedContext& c) { return device_dict(c.ctx->info()); })
      .def_property_readonly("validation", [](const SharedContext& c) { return c.ctx->validation_enabled(); })
      .def("validation_messages", [](const SharedContext& c) { return c.ctx->validation_messages(); })
      .def("traffic", [](const SharedContext& c) {
        const DeviceTraffic& t = c.ctx->traffic();
        py::dict d;
        d["upload_bytes"] = t.upload_bytes;
        d["download_bytes"] = t.download_bytes;
        d["submits"] = t.submits;
        d["dispatches"] = t.dispatches;
        d["gpu_ms"] = t.gpu_ms;
        return d;
      });
}

}  // namespace vkunroll::python
