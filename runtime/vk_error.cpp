#include "vkunroll/runtime/vk_error.hpp"

#include <filesystem>
#include <sstream>

namespace vkunroll {

const char* vk_result_name(VkResult result) {
  switch (result) {
#define VKUNROLL_CASE(x) \
  case x:                \
    return #x;
    VKUNROLL_CASE(VK_SUCCESS)
    VKUNROLL_CASE(VK_NOT_READY)
    VKUNROLL_CASE(VK_TIMEOUT)
    VKUNROLL_CASE(VK_EVENT_SET)
    VKUNROLL_CASE(VK_EVENT_RESET)
    VKUNROLL_CASE(VK_INCOMPLETE)
    VKUNROLL_CASE(VK_ERROR_OUT_OF_HOST_MEMORY)
    VKUNROLL_CASE(VK_ERROR_OUT_OF_DEVICE_MEMORY)
    VKUNROLL_CASE(VK_ERROR_INITIALIZATION_FAILED)
    VKUNROLL_CASE(VK_ERROR_DEVICE_LOST)
    VKUNROLL_CASE(VK_ERROR_MEMORY_MAP_FAILED)
    VKUNROLL_CASE(VK_ERROR_LAYER_NOT_PRESENT)
    VKUNROLL_CASE(VK_ERROR_EXTENSION_NOT_PRESENT)
    VKUNROLL_CASE(VK_ERROR_FEATURE_NOT_PRESENT)
    VKUNROLL_CASE(VK_ERROR_INCOMPATIBLE_DRIVER)
    VKUNROLL_CASE(VK_ERROR_TOO_MANY_OBJECTS)
    VKUNROLL_CASE(VK_ERROR_FORMAT_NOT_SUPPORTED)
    VKUNROLL_CASE(VK_ERROR_FRAGMENTED_POOL)
    VKUNROLL_CASE(VK_ERROR_UNKNOWN)
    VKUNROLL_CASE(VK_ERROR_OUT_OF_POOL_MEMORY)
    VKUNROLL_CASE(VK_ERROR_INVALID_EXTERNAL_HANDLE)
    VKUNROLL_CASE(VK_ERROR_FRAGMENTATION)
    VKUNROLL_CASE(VK_ERROR_INVALID_OPAQUE_CAPTURE_ADDRESS)
    VKUNROLL_CASE(VK_PIPELINE_COMPILE_REQUIRED)
#undef VKUNROLL_CASE
    default:
      break;
  }
  thread_local char buf[32];
  std::snprintf(buf, sizeof buf, "VkResult(%d)", static_cast<int>(result));
  return buf;
}

void throw_vk_error(VkResult result, const char* call, const char* file, int line,
                    const std::string& context) {
  std::ostringstream os;
  os << vk_result_name(result) << " from " << call << " at "
     << std::filesystem::path(file).filename().string() << ":" << line;
  if (!context.empty()) os << " (" << context << ")";
  throw VulkanError(result, os.str());
}

}  // namespace vkunroll
