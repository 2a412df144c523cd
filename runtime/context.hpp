// Context: the Vulkan instance, the chosen device, its queue, memory and pipeline cache.
// Everything else takes a Context& explicitly; there are no globals.
#pragma once
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "vkunroll/runtime/fault_injection.hpp"
#include "vkunroll/runtime/vk_error.hpp"

namespace vkunroll {

class Allocator;
class Pipeline;
class Trace;
class PipelineCompiler;
struct ShaderModuleBlob;

struct ContextOptions {
  // Enable VK_LAYER_KHRONOS_validation. Also turned on by VKUNROLL_VALIDATION=1.
  bool validation = false;
  // Device by index, by "uuid:<deviceUUID>" (as `vkunroll devices` shows it; dashes optional, a
  // unique prefix is enough) or by case-insensitive name substring; empty: VKUNROLL_DEVICE, then policy.
  std::string device;
  // Log the chosen device in one line (info, base/log.hpp).
  bool announce = true;
  // Abort the process on a validation message (tests: contexts made inside library code fail
  // loudly). Unset: VKUNROLL_VALIDATION_FATAL=1 turns it on.
  std::optional<bool> validation_fatal;
  // Persist the VkPipelineCache under the user's cache directory.
  bool persistent_pipeline_cache = true;
  // Enforce at least this minUniformBufferOffsetAlignment (bytes; 0: the device's). Tests use it to
  // check on a lenient device (lavapipe: 16) what a strict one (NVIDIA: 64, others up to 256) needs.
  uint64_t min_uniform_offset_alignment = 0;
  // Tests: bind_slice binds the whole tensor of every slice (the shader's element offsets then count
  // from the tensor's start), so a shader that writes outside its slice hits the canary values
  // around the slice inside the binding instead of past its end, where lavapipe drops the write.
  bool whole_tensor_bindings = false;
  // Create the device without its 16-bit storage and fp16 arithmetic features, as on a device that
  // lacks them (tests of the fp16 refusal).
  bool without_fp16 = false;
  // Create the device without VK_NV_cooperative_matrix even where it has it (the conv `coopmat`
  // path then reports itself unsupported), as on a device that lacks it.
  bool without_coopmat = false;
  // Tests: make the Nth submission, allocation, map or pipeline compile fail (runtime/fault_injection.hpp). Unset
  // (site none): VKUNROLL_INJECT_FAULT, e.g. "submit:3:device-lost".
  FaultInjection fault;
  // Bind each dispatch's buffers with VK_KHR_push_descriptor where the device has it (recorded into
  // the command buffer: no descriptor set allocated or updated per dispatch); false: descriptor sets
  // from pools, the portable path (tests run both).
  bool push_descriptors = true;
  // Threads that compile pipelines while commands are recorded (runtime/pipeline_compiler.hpp).
  // Unset: one fewer than the machine's hardware threads (the recording thread compiles too), 1 to 8;
  // 0: each pipeline compiles when it is first asked for, on the asking thread. At most 64.
  std::optional<uint32_t> pipeline_compile_threads;
  // Write a timestamp pair around every recorded command (GPU time per command, per stage, per op)
  // where the queue supports timestamps. The unroll session turns this off unless --profile or
  // --trace asks for the times; a stream with a Profiler, or a context with a Trace, times anyway.
  bool timestamps = true;
  // A submission whose commands equal those of one already recorded replays that command buffer
  // instead of recording again (runtime/command_stream.hpp; with push descriptors only).
  bool command_replay = true;
  // With validation: the layer's synchronization validation too (missing or wrong barriers are
  // reported as SYNC-HAZARD-* messages). Slow; for tests of the stream's barriers.
  bool synchronization_validation = false;
};

// One entry of vkGetPhysicalDeviceCooperativeMatrixPropertiesNV: D (MxN) = A (MxK) B (KxN) + C.
struct CoopMatShape {
  uint32_t m = 0, n = 0, k = 0;
  VkComponentTypeNV a = VK_COMPONENT_TYPE_FLOAT16_NV, b = VK_COMPONENT_TYPE_FLOAT16_NV;
  VkComponentTypeNV c = VK_COMPONENT_TYPE_FLOAT32_NV, d = VK_COMPONENT_TYPE_FLOAT32_NV;
  VkScopeNV scope = VK_SCOPE_SUBGROUP_NV;
  std::string str() const;  // "16x8x16 fp16*fp16+fp32->fp32 subgroup"
};

// Limits and features of a physical device, read once.
struct DeviceInfo {
  uint32_t index = 0;
  std::string name;
  VkPhysicalDeviceType type = VK_PHYSICAL_DEVICE_TYPE_OTHER;
  uint32_t api_version = 0;
  uint32_t vendor_id = 0, device_id = 0;
  std::string driver_name, driver_info;
  uint32_t subgroup_size = 0;
  // Vulkan 1.3 subgroup size control (or VK_EXT_subgroup_size_control), enabled where offered: the
  // widths a compute pipeline may require (Context::pipeline's required_subgroup_size) and whether it
  // may ask for full subgroups. Without control min = max = subgroup_size and the flags are false.
  uint32_t min_subgroup_size = 0, max_subgroup_size = 0;
  bool compute_subgroup_size_control = false;  // subgroupSizeControl, compute in requiredSubgroupSizeStages
  bool compute_full_subgroups = false;         // computeFullSubgroups
  // Why this device refuses subgroups of `width` invocations for a pipeline ("" where it gives them).
  std::string subgroup_width_refusal(uint32_t width) const;
  uint32_t compute_units = 0;  // NVIDIA SMs or AMD compute units where the driver says; 0: unknown
  bool shader_float16 = false;          // fp16 arithmetic in shaders (enabled when present)
  bool push_descriptor = false;         // VK_KHR_push_descriptor (enabled unless ContextOptions says no)
  bool storage_buffer_16bit = false;    // fp16 values in storage buffers (enabled; the fp16 kernels need it)
  // VK_NV_cooperative_matrix with its cooperativeMatrix feature, the shader Vulkan memory model that
  // glslang's cooperative-matrix SPIR-V declares, fp16 arithmetic and 16-bit storage (enabled when all
  // are present, unless ContextOptions::without_coopmat or without_fp16).
  bool coopmat_nv = false;
  // Enabling the Vulkan memory model (for coopmat) makes every shader's device-scope barrier
  // (memoryBarrier(), memoryBarrierBuffer()) need this feature too: enabled with it where offered.
  bool memory_model_device_scope = false;
  bool coopmat_khr_listed = false;           // VK_KHR_cooperative_matrix is listed (information only: unused)
  std::vector<CoopMatShape> coopmat_shapes;  // every shape the device offers (NV query)
  // The shape the conv `coopmat` path uses: fp16 A and B, fp32 C and D, subgroup scope, M 16, N and
  // K 8 or 16 (the largest offered); nullopt without one.
  std::optional<CoopMatShape> coopmat_fp16_shape() const;
  uint64_t max_storage_buffer_range = 0;
  uint32_t max_shared_memory = 0;
  uint32_t max_push_constants = 0;
  uint32_t max_workgroup_invocations = 0;
  uint32_t max_workgroup_count[3] = {0, 0, 0};
  uint64_t min_storage_buffer_offset_alignment = 0;
  uint64_t max_uniform_buffer_range = 0;             // bytes one uniform-buffer binding may span
  uint64_t min_uniform_buffer_offset_alignment = 1;
  uint64_t max_texel_buffer_elements = 0;            // texels one buffer view may span
  uint64_t min_texel_buffer_offset_alignment = 1;    // byte alignment of a buffer view's offset
  float timestamp_period_ns = 0.f;      // ns per timestamp tick
  bool timestamps = false;              // the compute queue writes timestamps
  uint64_t device_local_bytes = 0;
  uint8_t pipeline_cache_uuid[VK_UUID_SIZE] = {};
  uint8_t device_uuid[VK_UUID_SIZE] = {};  // VkPhysicalDeviceIDProperties: the same GPU in every process
  uint32_t driver_version = 0;             // VkPhysicalDeviceProperties::driverVersion (vendor encoding)

  std::string uuid_string() const;            // "6d657361-3232-2e33-2e36-000000000000"
  std::string driver_version_string() const;  // decoded the vendor's way (NVIDIA 10.8.8.6 bits, else Vulkan's)

  std::string type_name() const;        // "discrete", "integrated", "virtual", "cpu", "other"
  std::string api_version_string() const;
};

// Host <-> device traffic and submissions through this context, counted where they happen
// (Tensor uploads and downloads, CommandStream transfers and submits); callers take differences
// around a piece of work (e.g. one GS frame) to report it.
struct DeviceTraffic {
  uint64_t upload_bytes = 0;    // host -> device
  uint64_t download_bytes = 0;  // device -> host
  uint64_t submits = 0;         // queue submissions
  uint64_t waits = 0;           // times the host waited for all submitted work to finish (CommandStream::finish)
  uint64_t dispatches = 0;      // compute dispatches submitted (vkCmdDispatch)
  uint64_t transfers = 0;       // buffer copies and fills submitted (uploads, downloads, zeroing)
  uint64_t replayed_submits = 0;     // submissions that replayed a command buffer recorded before
  uint64_t replayed_commands = 0;    // the commands (dispatches, copies, fills) of those submissions
  uint64_t barriers = 0;             // pipeline barriers submitted between commands
  double gpu_ms = 0;            // sum of the submitted dispatches' device time (timestamps; 0 without)
  // gpu_ms by the stage each command was recorded in (CommandStream::set_stage; "" when none was set).
  std::map<std::string, double> gpu_ms_by_stage;
  // Host wall time spent waiting for the device: submitting, waiting for a free submission slot or
  // for all work (CommandStream::finish), reading back.
  double wait_ms = 0;
  // Host wall time the recording thread spent on pipelines: making their modules and layouts, and
  // waiting for (or running) their compilation when it bound them (Pipeline::handle).
  double pipeline_build_ms = 0;
  DeviceTraffic operator-(const DeviceTraffic& o) const {
    DeviceTraffic d{upload_bytes - o.upload_bytes, download_bytes - o.download_bytes, submits - o.submits, waits - o.waits,
                    dispatches - o.dispatches, transfers - o.transfers, replayed_submits - o.replayed_submits,
                    replayed_commands - o.replayed_commands, barriers - o.barriers, gpu_ms - o.gpu_ms, gpu_ms_by_stage,
                    wait_ms - o.wait_ms, pipeline_build_ms - o.pipeline_build_ms};
    for (const auto& [stage, ms] : o.gpu_ms_by_stage) d.gpu_ms_by_stage[stage] -= ms;
    return d;
  }
};

// Every device the loader sees, with the index `choose_device` would pick by policy.
struct DeviceList {
  std::vector<DeviceInfo> devices;
  uint32_t policy_choice = 0;
};

// Policy: discrete > integrated > virtual > cpu > other; ties keep enumeration order. `selector`: an
// index, "uuid:<hex>" or a name substring; `source` names where it came from in errors (the option
// opt("device"), or "VKUNROLL_DEVICE"). Throws DeviceUnavailableError when nothing matches.
uint32_t choose_device(const std::vector<DeviceInfo>& devices, const std::string& selector,
                       const std::string& source = opt("device"));

class Context {
 public:
  explicit Context(ContextOptions options = {});
  ~Context();
  Context(const Context&) = delete;
  Context& operator=(const Context&) = delete;

  // Lists devices without creating a logical device (for `vkunroll devices`).
  static DeviceList enumerate(bool validation = false);

  const DeviceInfo& info() const { return info_; }
  // Whether dispatches push their descriptors (the device has VK_KHR_push_descriptor, the options allow it).
  bool uses_push_descriptors() const { return push_descriptors_; }
  const ContextOptions& options() const { return options_; }
  VkInstance instance() const { return instance_; }
  VkPhysicalDevice physical_device() const { return physical_; }
  VkDevice device() const { return device_; }
  VkQueue queue() const { return queue_; }
  uint32_t queue_family() const { return queue_family_; }
  VkPipelineCache pipeline_cache() const { return pipeline_cache_; }
  // Where the pipeline cache is persisted (empty: not persisted). Saved through a temporary file
  // unique to this process, then renamed: concurrent runs never write one file.
  const std::string& pipeline_cache_path() const { return pipeline_cache_path_; }
  // The user's cache directory for vkunroll (VKUNROLL_CACHE_DIR, else $XDG_CACHE_HOME/vkunroll, else
  // ~/.cache/vkunroll; empty without any): the pipeline cache and the measured conv algorithm choices.
  static std::string cache_directory();
  Allocator& allocator() { return *allocator_; }
  PipelineCompiler& pipeline_compiler() { return *compiler_; }
  bool validation_enabled() const { return validation_; }
  DeviceTraffic& traffic() { return traffic_; }
  // The test-only fault plan's counter: submissions, allocations and maps ask it before the call.
  FaultInjector& faults() { return faults_; }
  const FaultInjector& faults() const { return faults_; }
  const DeviceTraffic& traffic() const { return traffic_; }
  // Whether streams write timestamps around their commands now: the queue supports them and
  // ContextOptions::timestamps (or set_timestamps) asks for them, or a trace is attached.
  bool timestamps() const { return info_.timestamps && (timestamps_ || trace_); }
  void set_timestamps(bool on) { timestamps_ = on; }
  // Whether streams replay command buffers of repeated submissions (ContextOptions::command_replay).
  bool command_replay() const { return command_replay_ && push_descriptors_; }
  void set_command_replay(bool on) { command_replay_ = on; }
  // The timeline streams add their GPU spans (and the session its stages) to; nullptr: none. Not owned.
  Trace* trace() const { return trace_; }
  void set_trace(Trace* t) { trace_ = t; }

  // Pipelines are created once per (shader, specialization, push size, subgroup width) and kept here.
  // (The module's name identifies it: one name, one module.) required_subgroup_size > 0: a shader
  // that assumes subgroups of that width asks for it, with full subgroups (its workgroup's x size a
  // multiple of it); a device that cannot give it refuses with DeviceUnavailableError naming itself
  // and the width.
  const Pipeline& pipeline(const ShaderModuleBlob& shader, const std::vector<uint32_t>& spec = {},
                           uint32_t push_constant_bytes = 0, uint32_t required_subgroup_size = 0);

  // Messages the validation layer reported (warnings and errors) since creation / last clear.
  std::vector<std::string> validation_messages() const;
  void clear_validation_messages();

  // Called by the debug messenger; public only for the C callback.
  void on_validation_message(const std::string& message);

 private:
  void create_instance(bool validation);
  void create_device();
  void load_pipeline_cache();
  void save_pipeline_cache();
  void release();

  ContextOptions options_;
  bool validation_ = false;
  bool validation_fatal_ = false;
  VkInstance instance_ = VK_NULL_HANDLE;
  VkDebugUtilsMessengerEXT messenger_ = VK_NULL_HANDLE;
  VkPhysicalDevice physical_ = VK_NULL_HANDLE;
  VkDevice device_ = VK_NULL_HANDLE;
  VkQueue queue_ = VK_NULL_HANDLE;
  uint32_t queue_family_ = 0;
  bool push_descriptors_ = false;
  VkPipelineCache pipeline_cache_ = VK_NULL_HANDLE;
  std::string pipeline_cache_path_;
  size_t pipeline_cache_loaded_bytes_ = 0;
  DeviceInfo info_;
  DeviceTraffic traffic_;
  FaultInjector faults_;
  bool timestamps_ = true, command_replay_ = true;
  Trace* trace_ = nullptr;
  std::unique_ptr<Allocator> allocator_;
  std::unique_ptr<PipelineCompiler> compiler_;  // outlives pipelines_: each cancels or waits for its build first
  std::map<std::string, std::unique_ptr<Pipeline>> pipelines_;
  mutable std::mutex messages_mutex_;
  std::vector<std::string> messages_;
};

}  // namespace vkunroll
