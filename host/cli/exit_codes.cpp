#include "vkunroll/host/cli/exit_codes.hpp"

#include <new>

#include "vkunroll/base/error.hpp"
#include "vkunroll/runtime/vk_error.hpp"

namespace vkunroll::cli {

namespace {

int code_of(VkResult r, std::string* category) {
  switch (r) {
    case VK_ERROR_DEVICE_LOST:
    case VK_TIMEOUT:
      *category = "device lost or timed out (retry)";
      return kExitTempFail;
    case VK_ERROR_OUT_OF_DEVICE_MEMORY:
    case VK_ERROR_OUT_OF_HOST_MEMORY:
    case VK_ERROR_OUT_OF_POOL_MEMORY:
    case VK_ERROR_FRAGMENTED_POOL:
    case VK_ERROR_FRAGMENTATION:
      *category = "device memory exhausted (retry, or lower --tile)";
      return kExitTempFail;
    case VK_ERROR_INCOMPATIBLE_DRIVER:
    case VK_ERROR_INITIALIZATION_FAILED:
    case VK_ERROR_LAYER_NOT_PRESENT:
    case VK_ERROR_EXTENSION_NOT_PRESENT:
    case VK_ERROR_FEATURE_NOT_PRESENT:
      *category = "no usable device";
      return kExitUnavailable;
    default:
      *category = "Vulkan error";
      return kExitSoftware;
  }
}

int code_of(ErrorKind k, std::string* category) {
  switch (k) {
    case ErrorKind::usage: *category = "usage"; return kExitUsage;
    case ErrorKind::data: *category = "bad input data"; return kExitData;
    case ErrorKind::input_missing: *category = "missing input"; return kExitNoInput;
    case ErrorKind::device_unavailable: *category = "no usable device"; return kExitUnavailable;
    case ErrorKind::internal: *category = "internal error (a vkunroll bug: please report it)"; return kExitSoftware;
    case ErrorKind::io: *category = "I/O error"; return kExitIo;
    case ErrorKind::temporary: *category = "temporary failure (retry)"; return kExitTempFail;
    case ErrorKind::unspecified: break;
  }
  *category = "bad input data";
  return kExitData;
}

}  // namespace

int exit_code_for(const std::exception& e, std::string* category) {
  std::string unused;
  if (!category) category = &unused;
  if (const auto* v = dynamic_cast<const VulkanError*>(&e)) return code_of(v->result(), category);
  if (const auto* v = dynamic_cast<const Error*>(&e)) return code_of(v->kind(), category);
  if (dynamic_cast<const std::bad_alloc*>(&e)) {
    *category = "out of memory";
    return kExitOsError;
  }
  *category = "internal error";
  return kExitSoftware;
}

}  // namespace vkunroll::cli
