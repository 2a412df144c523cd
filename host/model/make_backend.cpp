#include "vkunroll/host/model/make_backend.hpp"

#include <vector>

#include "vkunroll/base/error.hpp"
#include "vkunroll/base/log.hpp"
#include "vkunroll/host/model/backend_cpu.hpp"
#include "vkunroll/host/model/backend_vulkan.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll {

BackendKind parse_backend_kind(const std::string& s, const std::string& what) {
  if (s == "vulkan") return BackendKind::vulkan;
  if (s == "cpu") return BackendKind::cpu;
  throw OptionError(what, "'" + s + "'", "expected vulkan or cpu", opt(what) + " '" + s + "' (expected vulkan or cpu)");
}

const char* backend_kind_name(BackendKind b) { return b == BackendKind::cpu ? "cpu" : "vulkan"; }

OptionError fp16_needs_vulkan() {
  return OptionError("precision", "fp16", "needs the vulkan backend",
                     opt("precision") + " fp16 needs " + opt("backend") + " vulkan (the CPU backend computes the fp32 reference)");
}

OpenedBackend::OpenedBackend() = default;
OpenedBackend::~OpenedBackend() = default;
OpenedBackend::OpenedBackend(OpenedBackend&&) noexcept = default;
OpenedBackend& OpenedBackend::operator=(OpenedBackend&&) noexcept = default;

OpenedBackend make_backend(const BackendOptions& o, Context* shared) {
  OpenedBackend out;
  if (o.kind == BackendKind::cpu) {
    if (o.precision == Precision::fp16) throw fp16_needs_vulkan();
    out.backend = std::make_unique<CpuBackend>(o.cpu_threads);
    return out;
  }
  if (!shared) {
    ContextOptions co;
    co.device = o.device;
    co.announce = o.announce;
    out.context = std::make_unique<Context>(co);
  }
  Context& ctx = shared ? *shared : *out.context;
  auto vulkan = std::make_unique<VulkanBackend>(ctx, o.profiler, kPoolFlushBytes, o.precision);
  auto table = std::make_shared<ConvChoiceTable>();
  if (o.conv_choice != ConvChoice::heuristic && o.conv_choice != ConvChoice::gpu) {
    std::vector<std::string> warnings;
    out.conv_table = load_device_conv_table(ctx, o.committed_conv_tables, &warnings);
    for (const auto& w : warnings) log_warning("vkunroll: warning: " + w);
    table = out.conv_table.table;
  }
  vulkan->set_conv_choice(table, o.conv_choice);
  out.backend = std::move(vulkan);
  return out;
}

}  // namespace vkunroll
