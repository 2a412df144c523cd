// The one way a Backend is made, for every front end (`vkunroll infer`, the unroll session, Python):
// the Vulkan backend on a device context (opened here unless the caller shares one), its conv
// algorithm choice read from the device's table, or the CPU reference backend.
//
//   OpenedBackend b = make_backend({.kind = BackendKind::vulkan, .precision = Precision::fp16});
//   Model model(*b.backend, weights);   // b.context: the device it runs on
#pragma once
#include <memory>
#include <string>
#include <vector>

#include "vkunroll/base/precision.hpp"
#include "vkunroll/host/model/backend.hpp"
#include "vkunroll/host/model/conv_choice.hpp"

namespace vkunroll {

class Context;
class Profiler;

enum class BackendKind { vulkan, cpu };
// "vulkan" | "cpu"; the OptionError names the field `what`.
BackendKind parse_backend_kind(const std::string& s, const std::string& what);
const char* backend_kind_name(BackendKind b);
// The one refusal of fp16 on the CPU backend (make_backend, validate_unroll_options, `vkunroll infer`).
OptionError fp16_needs_vulkan();

struct BackendOptions {
  BackendKind kind = BackendKind::vulkan;
  // fp16: weights and buffers in float16 (Vulkan only; the CPU backend computes the fp32 reference).
  Precision precision = Precision::fp32;
  // Vulkan, when make_backend opens the device: INDEX, uuid:UUID or a name substring; empty:
  // VKUNROLL_DEVICE, then the policy (runtime/context.hpp).
  std::string device;
  bool announce = true;      // log the device chosen (info)
  unsigned cpu_threads = 0;  // CPU: convolution threads (0: the machine's, at most 8)
  // Vulkan: the conv algorithm per shape; other than heuristic and gpu, from the device's measured
  // table in the cache directory with the committed table of its device model merged in (warnings logged).
  ConvChoice conv_choice = ConvChoice::heuristic;
  std::vector<std::string> committed_conv_tables;  // folders of committed tables (host/unroll: conv_table_dirs())
  Profiler* profiler = nullptr;  // Vulkan: every dispatch's GPU time per op; outlives the backend
};

// A backend and the device context it opened. Members go in reverse order: the backend (which
// holds device memory) before its context.
struct OpenedBackend {
  std::unique_ptr<Context> context;  // null: the CPU backend, or a context the caller shares
  std::unique_ptr<Backend> backend;
  DeviceConvTable conv_table;  // the table read: its cache file, the committed table merged in (empty: none read)
  ~OpenedBackend();
  OpenedBackend();
  OpenedBackend(OpenedBackend&&) noexcept;
  OpenedBackend& operator=(OpenedBackend&&) noexcept;
};

// Refuses fp16 on the CPU backend (OptionError of `precision`); opens the device for a Vulkan
// backend unless `shared` (a context the caller owns, which outlives the backend) is given.
OpenedBackend make_backend(const BackendOptions& options, Context* shared = nullptr);

}  // namespace vkunroll
