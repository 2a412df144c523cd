// Errors: every failing Vulkan call becomes a VulkanError naming the VkResult and the call site.
#pragma once
#include <stdexcept>
#include <string>

#include <volk.h>

namespace vkunroll {

// Base of every error vkunroll throws: the message always says what and where.
class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what) : std::runtime_error(what) {}
};

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
