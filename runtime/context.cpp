#include "vkunroll/runtime/context.hpp"

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include <unistd.h>

#include "vkunroll/base/env.hpp"
#include "vkunroll/base/log.hpp"
#include "vkunroll/runtime/device_limits_detail.hpp"
#include "vkunroll/runtime/memory.hpp"
#include "vkunroll/runtime/pipeline.hpp"
#include "vkunroll/runtime/pipeline_compiler.hpp"

namespace vkunroll {
namespace {

constexpr const char* kValidationLayer = "VK_LAYER_KHRONOS_validation";

const char* kNoDriverHelp =
    "no Vulkan driver found. On Debian/Ubuntu install the software driver lavapipe with "
    "`apt-get install mesa-vulkan-drivers libvulkan1` and, if the loader still finds none, point it "
    "at the ICD: `export VK_DRIVER_FILES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json` "
    "(and VK_ICD_FILENAMES for loaders older than 1.3.207)";

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

void ensure_volk() {
  static const VkResult loaded = volkInitialize();  // loads libvulkan once per process
  if (loaded != VK_SUCCESS)
    throw VulkanError(loaded, std::string("cannot load the Vulkan loader (libvulkan.so.1): ") +
                                  kNoDriverHelp);
}

bool layer_available(const char* name) {
  uint32_t n = 0;
  vkEnumerateInstanceLayerProperties(&n, nullptr);
  std::vector<VkLayerProperties> layers(n);
  vkEnumerateInstanceLayerProperties(&n, layers.data());
  for (const auto& l : layers)
    if (std::strcmp(l.layerName, name) == 0) return true;
  return false;
}

bool instance_extension_available(const char* name) {
  uint32_t n = 0;
  vkEnumerateInstanceExtensionProperties(nullptr, &n, nullptr);
  std::vector<VkExtensionProperties> exts(n);
  vkEnumerateInstanceExtensionProperties(nullptr, &n, exts.data());
  for (const auto& e : exts)
    if (std::strcmp(e.extensionName, name) == 0) return true;
  return false;
}

bool device_extension_available(VkPhysicalDevice pd, const char* name) {
  uint32_t n = 0;
  vkEnumerateDeviceExtensionProperties(pd, nullptr, &n, nullptr);
  std::vector<VkExtensionProperties> exts(n);
  vkEnumerateDeviceExtensionProperties(pd, nullptr, &n, exts.data());
  for (const auto& e : exts)
    if (std::strcmp(e.extensionName, name) == 0) return true;
  return false;
}

VKAPI_ATTR VkBool32 VKAPI_CALL debug_callback(VkDebugUtilsMessageSeverityFlagBitsEXT severity,
                                              VkDebugUtilsMessageTypeFlagsEXT,
                                              const VkDebugUtilsMessengerCallbackDataEXT* data,
                                              void* user) {
  if (severity >= VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT) {
    std::string msg = std::string(severity >= VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT
                                      ? "validation error: "
                                      : "validation warning: ") +
                      (data->pMessage ? data->pMessage : "");
    static_cast<Context*>(user)->on_validation_message(msg);
  }
  return VK_FALSE;
}

uint32_t queue_family_for_compute(VkPhysicalDevice pd) {
  uint32_t n = 0;
  vkGetPhysicalDeviceQueueFamilyProperties(pd, &n, nullptr);
  std::vector<VkQueueFamilyProperties> fams(n);
  vkGetPhysicalDeviceQueueFamilyProperties(pd, &n, fams.data());
  // Prefer a compute-only family (async compute), else any family with compute.
  for (uint32_t i = 0; i < n; ++i)
    if ((fams[i].queueFlags & VK_QUEUE_COMPUTE_BIT) && !(fams[i].queueFlags & VK_QUEUE_GRAPHICS_BIT))
      return i;
  for (uint32_t i = 0; i < n; ++i)
    if (fams[i].queueFlags & VK_QUEUE_COMPUTE_BIT) return i;
  return UINT32_MAX;
}

// VK_NV_cooperative_matrix: its feature, the Vulkan memory model glslang's cooperative-matrix SPIR-V
// declares, and the list of shapes. Usable only with fp16 arithmetic and 16-bit storage too.
// Shader cores (NVIDIA SMs, AMD compute units) where an extension says; 0 elsewhere. The GPU conv
// family sizes its split-K by it (kernels/igemm.cpp).
uint32_t read_compute_units(VkPhysicalDevice pd) {
  VkPhysicalDeviceProperties2 props2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2};
  VkPhysicalDeviceShaderSMBuiltinsPropertiesNV sm{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SHADER_SM_BUILTINS_PROPERTIES_NV};
  VkPhysicalDeviceShaderCorePropertiesAMD amd{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SHADER_CORE_PROPERTIES_AMD};
  if (device_extension_available(pd, VK_NV_SHADER_SM_BUILTINS_EXTENSION_NAME)) {
    props2.pNext = &sm;
    vkGetPhysicalDeviceProperties2(pd, &props2);
    return sm.shaderSMCount;
  }
  if (device_extension_available(pd, VK_AMD_SHADER_CORE_PROPERTIES_EXTENSION_NAME)) {
    props2.pNext = &amd;
    vkGetPhysicalDeviceProperties2(pd, &props2);
    return amd.shaderEngineCount * amd.shaderArraysPerEngineCount * amd.computeUnitsPerShaderArray;
  }
  return 0;
}

void read_coopmat_info(VkPhysicalDevice pd, bool v12, DeviceInfo& info) {
  info.coopmat_khr_listed = device_extension_available(pd, "VK_KHR_cooperative_matrix");
  if (!device_extension_available(pd, VK_NV_COOPERATIVE_MATRIX_EXTENSION_NAME)) return;
  VkPhysicalDeviceCooperativeMatrixFeaturesNV cm{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_COOPERATIVE_MATRIX_FEATURES_NV};
  VkPhysicalDeviceVulkanMemoryModelFeatures mm{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_MEMORY_MODEL_FEATURES};
  VkPhysicalDeviceFeatures2 feats2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2};
  feats2.pNext = &cm;
  const bool has_mm = v12 || device_extension_available(pd, VK_KHR_VULKAN_MEMORY_MODEL_EXTENSION_NAME);
  if (has_mm) cm.pNext = &mm;
  vkGetPhysicalDeviceFeatures2(pd, &feats2);
  VkPhysicalDeviceCooperativeMatrixPropertiesNV stages{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_COOPERATIVE_MATRIX_PROPERTIES_NV};
  VkPhysicalDeviceProperties2 props2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2};
  props2.pNext = &stages;
  vkGetPhysicalDeviceProperties2(pd, &props2);
  if (vkGetPhysicalDeviceCooperativeMatrixPropertiesNV) {
    uint32_t n = 0;
    vkGetPhysicalDeviceCooperativeMatrixPropertiesNV(pd, &n, nullptr);
    std::vector<VkCooperativeMatrixPropertiesNV> props(n, {VK_STRUCTURE_TYPE_COOPERATIVE_MATRIX_PROPERTIES_NV});
    if (n) vkGetPhysicalDeviceCooperativeMatrixPropertiesNV(pd, &n, props.data());
    for (uint32_t i = 0; i < n; ++i) {
      const auto& p = props[i];
      info.coopmat_shapes.push_back({p.MSize, p.NSize, p.KSize, p.AType, p.BType, p.CType, p.DType, p.scope});
    }
  }
  info.memory_model_device_scope = has_mm && mm.vulkanMemoryModelDeviceScope;
  info.coopmat_nv = cm.cooperativeMatrix && has_mm && mm.vulkanMemoryModel && info.shader_float16 &&
                    info.storage_buffer_16bit && (stages.cooperativeMatrixSupportedStages & VK_SHADER_STAGE_COMPUTE_BIT);
}

// Subgroup size control: core where the device and the instance (make_instance asks the loader's
// version, at most 1.3) are Vulkan 1.3, else VK_EXT_subgroup_size_control.
bool subgroup_size_control_core(uint32_t api_version) {
  uint32_t loader = VK_API_VERSION_1_0;
  if (vkEnumerateInstanceVersion) vkEnumerateInstanceVersion(&loader);
  return api_version >= VK_API_VERSION_1_3 && loader >= VK_API_VERSION_1_3;
}
bool has_subgroup_size_control(VkPhysicalDevice pd, uint32_t api_version) {
  return subgroup_size_control_core(api_version) ||
         device_extension_available(pd, VK_EXT_SUBGROUP_SIZE_CONTROL_EXTENSION_NAME);
}

void read_subgroup_size_control(VkPhysicalDevice pd, DeviceInfo& info) {
  info.min_subgroup_size = info.max_subgroup_size = info.subgroup_size;
  if (!has_subgroup_size_control(pd, info.api_version)) return;
  VkPhysicalDeviceSubgroupSizeControlFeatures f{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_SIZE_CONTROL_FEATURES};
  VkPhysicalDeviceFeatures2 feats2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2};
  feats2.pNext = &f;
  vkGetPhysicalDeviceFeatures2(pd, &feats2);
  VkPhysicalDeviceSubgroupSizeControlProperties p{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_SIZE_CONTROL_PROPERTIES};
  VkPhysicalDeviceProperties2 props2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2};
  props2.pNext = &p;
  vkGetPhysicalDeviceProperties2(pd, &props2);
  if (p.minSubgroupSize && p.maxSubgroupSize) info.min_subgroup_size = p.minSubgroupSize, info.max_subgroup_size = p.maxSubgroupSize;
  info.compute_subgroup_size_control =
      f.subgroupSizeControl && (p.requiredSubgroupSizeStages & VK_SHADER_STAGE_COMPUTE_BIT);
  info.compute_full_subgroups = f.computeFullSubgroups;
}

const char* component_name(VkComponentTypeNV t) {
  switch (t) {
    case VK_COMPONENT_TYPE_FLOAT16_NV: return "fp16";
    case VK_COMPONENT_TYPE_FLOAT32_NV: return "fp32";
    case VK_COMPONENT_TYPE_FLOAT64_NV: return "fp64";
    case VK_COMPONENT_TYPE_SINT8_NV: return "s8";
    case VK_COMPONENT_TYPE_UINT8_NV: return "u8";
    case VK_COMPONENT_TYPE_SINT32_NV: return "s32";
    case VK_COMPONENT_TYPE_UINT32_NV: return "u32";
    default: return "other";
  }
}

DeviceInfo read_device_info(VkPhysicalDevice pd, uint32_t index) {
  DeviceInfo info;
  info.index = index;
  VkPhysicalDeviceProperties props{};
  vkGetPhysicalDeviceProperties(pd, &props);
  info.name = props.deviceName;
  info.type = props.deviceType;
  info.api_version = props.apiVersion;
  info.vendor_id = props.vendorID;
  info.device_id = props.deviceID;
  info.max_storage_buffer_range = props.limits.maxStorageBufferRange;
  info.max_shared_memory = props.limits.maxComputeSharedMemorySize;
  info.max_push_constants = props.limits.maxPushConstantsSize;
  info.max_workgroup_invocations = props.limits.maxComputeWorkGroupInvocations;
  for (int i = 0; i < 3; ++i) info.max_workgroup_count[i] = props.limits.maxComputeWorkGroupCount[i];
  info.min_storage_buffer_offset_alignment = props.limits.minStorageBufferOffsetAlignment;
  info.max_uniform_buffer_range = props.limits.maxUniformBufferRange;
  info.min_uniform_buffer_offset_alignment = std::max<uint64_t>(1, props.limits.minUniformBufferOffsetAlignment);
  info.max_texel_buffer_elements = props.limits.maxTexelBufferElements;
  info.min_texel_buffer_offset_alignment = std::max<uint64_t>(1, props.limits.minTexelBufferOffsetAlignment);
  info.timestamp_period_ns = props.limits.timestampPeriod;
  info.driver_version = props.driverVersion;
  std::memcpy(info.pipeline_cache_uuid, props.pipelineCacheUUID, VK_UUID_SIZE);

  const bool v12 = VK_API_VERSION_MINOR(props.apiVersion) >= 2 || VK_API_VERSION_MAJOR(props.apiVersion) > 1;
  VkPhysicalDeviceIDProperties ids{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ID_PROPERTIES};  // core in 1.1
  VkPhysicalDeviceSubgroupProperties subgroup{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_PROPERTIES};
  VkPhysicalDeviceDriverProperties driver{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_DRIVER_PROPERTIES};
  VkPhysicalDeviceProperties2 props2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2};
  props2.pNext = &ids;
  ids.pNext = &subgroup;
  if (v12 || device_extension_available(pd, VK_KHR_DRIVER_PROPERTIES_EXTENSION_NAME)) subgroup.pNext = &driver;
  vkGetPhysicalDeviceProperties2(pd, &props2);
  std::memcpy(info.device_uuid, ids.deviceUUID, VK_UUID_SIZE);
  info.subgroup_size = subgroup.subgroupSize;
  if (subgroup.pNext) {
    info.driver_name = driver.driverName;
    info.driver_info = driver.driverInfo;
  }

  VkPhysicalDevice16BitStorageFeatures storage16{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_16BIT_STORAGE_FEATURES};
  VkPhysicalDeviceShaderFloat16Int8Features f16{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SHADER_FLOAT16_INT8_FEATURES};
  VkPhysicalDeviceFeatures2 feats2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2};
  feats2.pNext = &storage16;
  if (v12 || device_extension_available(pd, VK_KHR_SHADER_FLOAT16_INT8_EXTENSION_NAME)) storage16.pNext = &f16;
  vkGetPhysicalDeviceFeatures2(pd, &feats2);
  info.storage_buffer_16bit = storage16.storageBuffer16BitAccess;
  info.push_descriptor = device_extension_available(pd, VK_KHR_PUSH_DESCRIPTOR_EXTENSION_NAME);
  info.shader_float16 = storage16.pNext && f16.shaderFloat16;
  read_coopmat_info(pd, v12, info);
  read_subgroup_size_control(pd, info);
  info.compute_units = read_compute_units(pd);

  const uint32_t qf = queue_family_for_compute(pd);
  if (qf != UINT32_MAX) {
    uint32_t n = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(pd, &n, nullptr);
    std::vector<VkQueueFamilyProperties> fams(n);
    vkGetPhysicalDeviceQueueFamilyProperties(pd, &n, fams.data());
    info.timestamps = fams[qf].timestampValidBits > 0 && info.timestamp_period_ns > 0;
  }
  VkPhysicalDeviceMemoryProperties mem{};
  vkGetPhysicalDeviceMemoryProperties(pd, &mem);
  for (uint32_t i = 0; i < mem.memoryHeapCount; ++i)
    if (mem.memoryHeaps[i].flags & VK_MEMORY_HEAP_DEVICE_LOCAL_BIT)
      info.device_local_bytes = std::max<uint64_t>(info.device_local_bytes, mem.memoryHeaps[i].size);
  return info;
}

int type_rank(VkPhysicalDeviceType t) {
  switch (t) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU: return 0;
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU: return 1;
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU: return 2;
    case VK_PHYSICAL_DEVICE_TYPE_CPU: return 3;
    default: return 4;
  }
}

VkInstance make_instance(bool validation, bool* messenger_ok, bool sync_validation = false) {
  ensure_volk();
  uint32_t loader_version = VK_API_VERSION_1_0;
  if (vkEnumerateInstanceVersion) vkEnumerateInstanceVersion(&loader_version);
  if (loader_version < VK_API_VERSION_1_1)
    throw DeviceUnavailableError("the Vulkan loader is older than 1.1; vkunroll needs Vulkan 1.1 or newer");
  VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
  app.pApplicationName = "vkunroll";
  app.applicationVersion = VK_MAKE_VERSION(0, 1, 0);
  app.pEngineName = "vkunroll";
  app.apiVersion = std::min<uint32_t>(loader_version, VK_API_VERSION_1_3);

  std::vector<const char*> layers, exts;
  if (validation) {
    if (!layer_available(kValidationLayer))
      throw DeviceUnavailableError(std::string("validation was requested but ") + kValidationLayer +
                  " is not installed (apt-get install vulkan-validationlayers)");
    layers.push_back(kValidationLayer);
  }
  *messenger_ok = validation && instance_extension_available(VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
  if (*messenger_ok) exts.push_back(VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
  const bool portability = instance_extension_available(VK_KHR_PORTABILITY_ENUMERATION_EXTENSION_NAME);
  if (portability) exts.push_back(VK_KHR_PORTABILITY_ENUMERATION_EXTENSION_NAME);

  VkInstanceCreateInfo ci{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
  ci.pApplicationInfo = &app;
  ci.enabledLayerCount = static_cast<uint32_t>(layers.size());
  ci.ppEnabledLayerNames = layers.data();
  ci.enabledExtensionCount = static_cast<uint32_t>(exts.size());
  ci.ppEnabledExtensionNames = exts.data();
  if (portability) ci.flags |= VK_INSTANCE_CREATE_ENUMERATE_PORTABILITY_BIT_KHR;
  // The layer reads this (it exposes VK_EXT_validation_features itself): hazards between commands.
  const VkValidationFeatureEnableEXT sync = VK_VALIDATION_FEATURE_ENABLE_SYNCHRONIZATION_VALIDATION_EXT;
  VkValidationFeaturesEXT features{VK_STRUCTURE_TYPE_VALIDATION_FEATURES_EXT};
  features.enabledValidationFeatureCount = 1;
  features.pEnabledValidationFeatures = &sync;
  if (validation && sync_validation) ci.pNext = &features;
  VkInstance instance = VK_NULL_HANDLE;
  VkResult r = vkCreateInstance(&ci, nullptr, &instance);
  if (r == VK_ERROR_INCOMPATIBLE_DRIVER) throw VulkanError(r, std::string("vkCreateInstance: ") + kNoDriverHelp);
  if (r != VK_SUCCESS) throw_vk_error(r, "vkCreateInstance", __FILE__, __LINE__);
  volkLoadInstance(instance);
  return instance;
}

std::vector<VkPhysicalDevice> physical_devices(VkInstance instance) {
  uint32_t n = 0;
  VK_CHECK(vkEnumeratePhysicalDevices(instance, &n, nullptr));
  std::vector<VkPhysicalDevice> pds(n);
  VK_CHECK(vkEnumeratePhysicalDevices(instance, &n, pds.data()));
  if (n == 0) throw VulkanError(VK_ERROR_INCOMPATIBLE_DRIVER, kNoDriverHelp);
  return pds;
}

std::filesystem::path cache_dir() {
  if (const auto d = env::text("VKUNROLL_CACHE_DIR")) return *d;
  if (const auto d = env::text("XDG_CACHE_HOME")) return std::filesystem::path(*d) / "vkunroll";
  if (const auto h = env::text("HOME")) return std::filesystem::path(*h) / ".cache" / "vkunroll";
  return {};
}

// ContextOptions::pipeline_compile_threads, checked. Unset: one fewer than the hardware threads
// (the recording thread compiles too while it waits; measured on 2 cores: 1 worker 1.56-1.66x
// faster first frames than 2 workers' 1.39-1.44x), 1 to 8.
uint32_t compile_threads(std::optional<uint32_t> requested) {
  if (requested && *requested > 64)
    throw UsageError("ContextOptions::pipeline_compile_threads " + std::to_string(*requested) + ": expected 0 to 64");
  const uint32_t hardware = std::thread::hardware_concurrency();
  return requested.value_or(std::clamp(hardware > 1 ? hardware - 1 : 1u, 1u, 8u));
}

}  // namespace

std::string Context::cache_directory() { return cache_dir().string(); }

std::string DeviceInfo::subgroup_width_refusal(uint32_t width) const {
  const std::string offers = min_subgroup_size == max_subgroup_size
                                 ? "only " + std::to_string(min_subgroup_size)
                                 : std::to_string(min_subgroup_size) + " to " + std::to_string(max_subgroup_size);
  std::string why;
  if (width == 0 || (width & (width - 1)) != 0) why = "not a power of two";
  else if (!compute_subgroup_size_control) why = "no subgroup size control for compute shaders; its subgroups are " + offers;
  else if (!compute_full_subgroups) why = "no full subgroups for compute shaders (computeFullSubgroups)";
  else if (width < min_subgroup_size || width > max_subgroup_size) why = "it offers subgroups of " + offers;
  return why.empty() ? "" : "device '" + name + "' cannot run subgroups of " + std::to_string(width) + " invocations: " + why;
}

std::string DeviceInfo::type_name() const {
  switch (type) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU: return "discrete";
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU: return "integrated";
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU: return "virtual";
    case VK_PHYSICAL_DEVICE_TYPE_CPU: return "cpu";
    default: return "other";
  }
}

std::string CoopMatShape::str() const {
  std::ostringstream os;
  os << m << "x" << n << "x" << k << " " << component_name(a) << "*" << component_name(b) << "+" << component_name(c)
     << "->" << component_name(d) << " "
     << (scope == VK_SCOPE_SUBGROUP_NV ? "subgroup" : scope == VK_SCOPE_WORKGROUP_NV ? "workgroup" : "other");
  return os.str();
}

std::optional<CoopMatShape> DeviceInfo::coopmat_fp16_shape() const {
  if (!coopmat_nv) return std::nullopt;
  std::optional<CoopMatShape> best;
  for (const CoopMatShape& s : coopmat_shapes) {
    const bool types = s.a == VK_COMPONENT_TYPE_FLOAT16_NV && s.b == VK_COMPONENT_TYPE_FLOAT16_NV &&
                       s.c == VK_COMPONENT_TYPE_FLOAT32_NV && s.d == VK_COMPONENT_TYPE_FLOAT32_NV;
    const bool size = s.m == 16 && (s.n == 8 || s.n == 16) && (s.k == 8 || s.k == 16);
    if (!types || !size || s.scope != VK_SCOPE_SUBGROUP_NV) continue;
    if (!best || s.n * s.k > best->n * best->k) best = s;
  }
  return best;
}

std::string DeviceInfo::api_version_string() const {
  std::ostringstream os;
  os << VK_API_VERSION_MAJOR(api_version) << "." << VK_API_VERSION_MINOR(api_version) << "."
     << VK_API_VERSION_PATCH(api_version);
  return os.str();
}

std::string DeviceInfo::uuid_string() const {
  std::ostringstream os;
  for (uint32_t i = 0; i < VK_UUID_SIZE; ++i) {
    if (i == 4 || i == 6 || i == 8 || i == 10) os << '-';
    os << std::hex << (device_uuid[i] >> 4) << (device_uuid[i] & 15);
  }
  return os.str();
}

std::string DeviceInfo::driver_version_string() const {
  const uint32_t v = driver_version;
  std::ostringstream os;
  if (vendor_id == 0x10DE)  // NVIDIA: 10.8.8.6 bits
    os << (v >> 22) << "." << ((v >> 14) & 0xff) << "." << ((v >> 6) & 0xff) << "." << (v & 0x3f);
  else
    os << VK_API_VERSION_MAJOR(v) << "." << VK_API_VERSION_MINOR(v) << "." << VK_API_VERSION_PATCH(v);
  return os.str();
}

uint32_t choose_device(const std::vector<DeviceInfo>& devices, const std::string& selector, const std::string& source) {
  if (devices.empty()) throw DeviceUnavailableError(kNoDriverHelp);
  auto list = [&] {
    std::ostringstream os;
    for (const auto& d : devices) os << "\n  [" << d.index << "] " << d.name << " (" << d.type_name() << ", uuid:" << d.uuid_string() << ")";
    return os.str();
  };
  if (!selector.empty()) {
    const std::string said = source + " '" + selector + "'";
    if (lower(selector).rfind("uuid:", 0) == 0) {
      std::string want;
      for (char c : lower(selector.substr(5)))
        if (c != '-') want.push_back(c);
      const bool hex = !want.empty() && want.size() <= 32 && std::all_of(want.begin(), want.end(), [](unsigned char c) { return std::isxdigit(c); });
      if (!hex) throw DeviceUnavailableError(said + ": expected uuid: followed by up to 32 hex digits (dashes optional); devices are:" + list());
      std::vector<uint32_t> hits;
      for (const auto& d : devices) {
        std::string have;
        for (char c : d.uuid_string())
          if (c != '-') have.push_back(c);
        if (have.rfind(want, 0) == 0) hits.push_back(d.index);
      }
      if (hits.size() == 1) return hits.front();
      throw DeviceUnavailableError(said + (hits.empty() ? ": no device has that UUID" : ": more than one device's UUID starts so") +
                                   "; devices are:" + list());
    }
    const bool numeric = std::all_of(selector.begin(), selector.end(), [](unsigned char c) { return std::isdigit(c); });
    if (numeric) {
      const unsigned long idx = selector.size() > 9 ? devices.size() : std::stoul(selector);
      if (idx >= devices.size()) throw DeviceUnavailableError(said + ": no device with that index; devices are:" + list());
      return static_cast<uint32_t>(idx);
    }
    for (const auto& d : devices)
      if (lower(d.name).find(lower(selector)) != std::string::npos) return d.index;
    throw DeviceUnavailableError(said + ": no device name contains it; devices are:" + list());
  }
  uint32_t best = 0;
  for (const auto& d : devices)
    if (type_rank(d.type) < type_rank(devices[best].type)) best = d.index;
  return best;
}

DeviceList Context::enumerate(bool validation) {
  bool messenger = false;
  VkInstance instance = make_instance(validation, &messenger);
  DeviceList list;
  try {
    auto pds = physical_devices(instance);
    for (uint32_t i = 0; i < pds.size(); ++i) list.devices.push_back(read_device_info(pds[i], i));
    list.policy_choice = choose_device(list.devices, env::text("VKUNROLL_DEVICE").value_or(""), "VKUNROLL_DEVICE");
  } catch (...) {
    vkDestroyInstance(instance, nullptr);
    throw;
  }
  vkDestroyInstance(instance, nullptr);
  return list;
}

Context::Context(ContextOptions options) : options_(std::move(options)) {
  const uint32_t threads = compile_threads(options_.pipeline_compile_threads);  // checked before any Vulkan object
  validation_ = options_.validation || env::flag("VKUNROLL_VALIDATION");
  validation_fatal_ = options_.validation_fatal.value_or(env::flag("VKUNROLL_VALIDATION_FATAL"));
  FaultInjection fault = options_.fault;
  if (fault.site == FaultInjection::Site::none)
    if (const auto text = env::text("VKUNROLL_INJECT_FAULT")) fault = parse_fault_injection(*text, "VKUNROLL_INJECT_FAULT");
  faults_ = FaultInjector(fault);
  timestamps_ = options_.timestamps;
  command_replay_ = options_.command_replay;
  create_instance(validation_);
  try {
    create_device();
    allocator_ = std::make_unique<Allocator>(*this);
    load_pipeline_cache();
    compiler_ = std::make_unique<PipelineCompiler>(threads);
  } catch (...) {
    release();
    throw;
  }
}

Context::~Context() { release(); }

void Context::release() {
  pipelines_.clear();  // each cancels its build or waits for it
  compiler_.reset();
  allocator_.reset();
  if (device_) {
    vkDeviceWaitIdle(device_);
    if (pipeline_cache_) {
      save_pipeline_cache();
      vkDestroyPipelineCache(device_, pipeline_cache_, nullptr);
      pipeline_cache_ = VK_NULL_HANDLE;
    }
    vkDestroyDevice(device_, nullptr);
    device_ = VK_NULL_HANDLE;
  }
  if (messenger_) {
    // This instance's own entry: the process-wide one follows the last instance volk loaded.
    if (auto destroy = reinterpret_cast<PFN_vkDestroyDebugUtilsMessengerEXT>(
            vkGetInstanceProcAddr(instance_, "vkDestroyDebugUtilsMessengerEXT")))
      destroy(instance_, messenger_, nullptr);
    messenger_ = VK_NULL_HANDLE;
  }
  if (instance_) {
    vkDestroyInstance(instance_, nullptr);
    instance_ = VK_NULL_HANDLE;
  }
}

void Context::create_instance(bool validation) {
  bool messenger_ok = false;
  instance_ = make_instance(validation, &messenger_ok, options_.synchronization_validation);
  if (messenger_ok) {
    VkDebugUtilsMessengerCreateInfoEXT ci{VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT};
    ci.messageSeverity = VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
    ci.messageType = VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT |
                     VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT;
    ci.pfnUserCallback = debug_callback;
    ci.pUserData = this;
    auto create = reinterpret_cast<PFN_vkCreateDebugUtilsMessengerEXT>(
        vkGetInstanceProcAddr(instance_, "vkCreateDebugUtilsMessengerEXT"));
    if (!create) throw DeviceUnavailableError("the validation layer is enabled but vkCreateDebugUtilsMessengerEXT is missing");
    VK_CHECK(create(instance_, &ci, nullptr, &messenger_));
  }
}

void Context::create_device() {
  auto pds = physical_devices(instance_);
  std::vector<DeviceInfo> infos;
  for (uint32_t i = 0; i < pds.size(); ++i) infos.push_back(read_device_info(pds[i], i));
  std::string selector = options_.device, source = opt("device");
  if (selector.empty())
    if (const auto from_env = env::text("VKUNROLL_DEVICE")) selector = *from_env, source = "VKUNROLL_DEVICE";
  const uint32_t chosen = choose_device(infos, selector, source);
  physical_ = pds[chosen];
  info_ = infos[chosen];
  info_.min_uniform_buffer_offset_alignment =
      std::max<uint64_t>(info_.min_uniform_buffer_offset_alignment, options_.min_uniform_offset_alignment);
  bool lowered_fp16 = false;  // tests: a smaller device (VKUNROLL_TEST_LIMITS)
  lower_device_limits_from_env(info_, &lowered_fp16);
  options_.without_fp16 = options_.without_fp16 || lowered_fp16;
  if (options_.without_fp16) info_.shader_float16 = info_.storage_buffer_16bit = false;
  if (options_.without_fp16 || options_.without_coopmat) info_.coopmat_nv = false;
  queue_family_ = queue_family_for_compute(physical_);
  if (queue_family_ == UINT32_MAX) throw DeviceUnavailableError("device '" + info_.name + "' has no compute queue");

  const float priority = 1.f;
  VkDeviceQueueCreateInfo qci{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
  qci.queueFamilyIndex = queue_family_;
  qci.queueCount = 1;
  qci.pQueuePriorities = &priority;

  // Enable the 16-bit features the device has; fp16 kernels check info() before using them.
  const bool v12 = VK_API_VERSION_MINOR(info_.api_version) >= 2 || VK_API_VERSION_MAJOR(info_.api_version) > 1;
  std::vector<const char*> exts;
  VkPhysicalDevice16BitStorageFeatures storage16{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_16BIT_STORAGE_FEATURES};
  storage16.storageBuffer16BitAccess = info_.storage_buffer_16bit;
  VkPhysicalDeviceShaderFloat16Int8Features f16{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SHADER_FLOAT16_INT8_FEATURES};
  f16.shaderFloat16 = info_.shader_float16;
  VkPhysicalDeviceFeatures2 feats{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2};
  feats.pNext = &storage16;
  if (info_.shader_float16) {
    storage16.pNext = &f16;
    if (!v12) exts.push_back(VK_KHR_SHADER_FLOAT16_INT8_EXTENSION_NAME);
  }
  // Cooperative matrices (conv `coopmat`): the extension, its feature and the Vulkan memory model.
  VkPhysicalDeviceCooperativeMatrixFeaturesNV coopmat{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_COOPERATIVE_MATRIX_FEATURES_NV};
  VkPhysicalDeviceVulkanMemoryModelFeatures memory_model{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_MEMORY_MODEL_FEATURES};
  if (info_.coopmat_nv) {
    coopmat.cooperativeMatrix = VK_TRUE;
    memory_model.vulkanMemoryModel = VK_TRUE;
    memory_model.vulkanMemoryModelDeviceScope = info_.memory_model_device_scope;
    coopmat.pNext = &memory_model;
    memory_model.pNext = feats.pNext;
    feats.pNext = &coopmat;
    exts.push_back(VK_NV_COOPERATIVE_MATRIX_EXTENSION_NAME);
    if (!v12) exts.push_back(VK_KHR_VULKAN_MEMORY_MODEL_EXTENSION_NAME);
  }
  VkPhysicalDeviceSubgroupSizeControlFeatures subgroup_control{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_SIZE_CONTROL_FEATURES};
  if (info_.compute_subgroup_size_control || info_.compute_full_subgroups) {
    subgroup_control.subgroupSizeControl = info_.compute_subgroup_size_control;
    subgroup_control.computeFullSubgroups = info_.compute_full_subgroups;
    subgroup_control.pNext = feats.pNext;
    feats.pNext = &subgroup_control;
    if (!subgroup_size_control_core(info_.api_version)) exts.push_back(VK_EXT_SUBGROUP_SIZE_CONTROL_EXTENSION_NAME);
  }
  VkPhysicalDeviceFeatures supported{};
  vkGetPhysicalDeviceFeatures(physical_, &supported);
  feats.features.shaderInt64 = supported.shaderInt64;
  feats.features.shaderInt16 = supported.shaderInt16;
  if (device_extension_available(physical_, "VK_KHR_portability_subset")) exts.push_back("VK_KHR_portability_subset");
  // The loader's trampoline for vkCmdPushDescriptorSetKHR (volkLoadInstance) must exist too.
  push_descriptors_ = options_.push_descriptors && info_.push_descriptor && vkCmdPushDescriptorSetKHR != nullptr;
  if (push_descriptors_) exts.push_back(VK_KHR_PUSH_DESCRIPTOR_EXTENSION_NAME);

  VkDeviceCreateInfo dci{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO};
  dci.pNext = &feats;
  dci.queueCreateInfoCount = 1;
  dci.pQueueCreateInfos = &qci;
  dci.enabledExtensionCount = static_cast<uint32_t>(exts.size());
  dci.ppEnabledExtensionNames = exts.data();
  VK_CHECK(vkCreateDevice(physical_, &dci, nullptr, &device_));
  // No volkLoadDevice: it would point the process-wide device functions at this device's driver
  // (or layer) entries, and every other Context's calls would then go through them (a crash with
  // one validated and one plain context). The loader's trampolines, set by volkLoadInstance,
  // dispatch on the handle and serve any number of contexts.
  vkGetDeviceQueue(device_, queue_family_, 0, &queue_);
  if (options_.announce)
    log_info("vkunroll: device [" + std::to_string(info_.index) + "] " + info_.name + " (" + info_.type_name() + ", Vulkan " +
             info_.api_version_string() + (info_.driver_info.empty() ? "" : ", " + info_.driver_info) + ", uuid:" +
             info_.uuid_string() + (validation_ ? ", validation on" : "") + ")");
}

void Context::load_pipeline_cache() {
  std::vector<char> blob;
  if (options_.persistent_pipeline_cache && !env::flag("VKUNROLL_NO_PIPELINE_CACHE")) {
    const auto dir = cache_dir();
    if (!dir.empty()) {
      std::ostringstream name;
      name << "pipelines-" << std::hex << info_.vendor_id << "-" << info_.device_id << "-";
      for (uint8_t b : info_.pipeline_cache_uuid) name << std::hex << int(b);
      name << ".bin";
      pipeline_cache_path_ = (dir / name.str()).string();
      std::ifstream in(pipeline_cache_path_, std::ios::binary);
      if (in) blob.assign(std::istreambuf_iterator<char>(in), {});
    }
  }
  VkPipelineCacheCreateInfo ci{VK_STRUCTURE_TYPE_PIPELINE_CACHE_CREATE_INFO};
  ci.initialDataSize = blob.size();
  ci.pInitialData = blob.empty() ? nullptr : blob.data();
  // A stale or foreign blob is ignored by the driver (header check); retry empty if it is rejected.
  if (vkCreatePipelineCache(device_, &ci, nullptr, &pipeline_cache_) != VK_SUCCESS) {
    ci.initialDataSize = 0;
    ci.pInitialData = nullptr;
    VK_CHECK(vkCreatePipelineCache(device_, &ci, nullptr, &pipeline_cache_));
  }
  pipeline_cache_loaded_bytes_ = blob.size();
}

void Context::save_pipeline_cache() {
  if (pipeline_cache_path_.empty()) return;
  size_t size = 0;
  if (vkGetPipelineCacheData(device_, pipeline_cache_, &size, nullptr) != VK_SUCCESS || size == 0) return;
  if (size == pipeline_cache_loaded_bytes_) return;  // nothing new compiled
  std::vector<char> blob(size);
  if (vkGetPipelineCacheData(device_, pipeline_cache_, &size, blob.data()) != VK_SUCCESS) return;
  std::error_code ec;
  std::filesystem::create_directories(std::filesystem::path(pipeline_cache_path_).parent_path(), ec);
  // Unique per process (and per save): concurrent runs sharing the cache directory never write,
  // truncate or rename each other's temporary file; the last rename wins, whole.
  static std::atomic<unsigned> saves{0};
  const std::string tmp = pipeline_cache_path_ + ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(saves++);
  {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) return;  // an unwritable cache directory only costs compile time next run
    out.write(blob.data(), static_cast<std::streamsize>(size));
    out.close();
    if (!out) {  // a short write (disk full): never rename a torn cache into place
      std::filesystem::remove(tmp, ec);
      return;
    }
  }
  std::filesystem::rename(tmp, pipeline_cache_path_, ec);
  if (ec) std::filesystem::remove(tmp, ec);
}

const Pipeline& Context::pipeline(const ShaderModuleBlob& shader, const std::vector<uint32_t>& spec,
                                  uint32_t push_constant_bytes, uint32_t required_subgroup_size) {
  std::ostringstream key;
  key << shader.name << "|" << push_constant_bytes << "|" << required_subgroup_size;
  for (uint32_t v : spec) key << "," << v;
  auto it = pipelines_.find(key.str());
  if (it == pipelines_.end())
    it = pipelines_
             .emplace(key.str(),
                      std::make_unique<Pipeline>(*this, shader, spec, push_constant_bytes, required_subgroup_size))
             .first;
  return *it->second;
}

std::vector<std::string> Context::validation_messages() const {
  std::lock_guard<std::mutex> lock(messages_mutex_);
  return messages_;
}

void Context::clear_validation_messages() {
  std::lock_guard<std::mutex> lock(messages_mutex_);
  messages_.clear();
}

void Context::on_validation_message(const std::string& message) {
  log_message(message.rfind("validation error", 0) == 0 ? LogLevel::error : LogLevel::warning, "vkunroll: " + message);
  if (validation_fatal_) {
    log_error("vkunroll: aborting on a validation message (VKUNROLL_VALIDATION_FATAL)");
    std::abort();
  }
  std::lock_guard<std::mutex> lock(messages_mutex_);
  messages_.push_back(message);
}

}  // namespace vkunroll
