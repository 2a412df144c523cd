// Vulkan errors: every failing Vulkan call becomes a VulkanError naming the VkResult and the call
// site. This is the one header that brings in volk (and with it the Vulkan declarations).
#pragma once
#include <string>

#include <volk.h>

#include "vkunroll/base/error.hpp"

namespace vkunroll {

class VulkanError : public Error {
 public:
  VulkanError(VkResult result, const std::string& what) : Error(what), result_(result) {}
  VkResult result() const { return result_; }

 private:
  VkResult result_;
};

// "VK_ERROR_DEVICE_LOST" for VK_ERROR_DEVICE_LOST, "VkResult(-13)" for an unknown value.
const char* vk_result_name(VkResult result);

[[noreturn]] void throw_vk_error(VkResult result, const char* call, const char* file, int line,
                                 const std::string& context = {});

}  // namespace vkunroll

// Checks a Vulkan call; on failure throws VulkanError with the result's name and the call site.
#define VK_CHECK(call)                                                         \
  do {                                                                         \
    VkResult vkunroll_result_ = (call);                                        \
    if (vkunroll_result_ != VK_SUCCESS)                                        \
      ::vkunroll::throw_vk_error(vkunroll_result_, #call, __FILE__, __LINE__); \
  } while (0)
