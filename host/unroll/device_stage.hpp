// Device failures (a lost device, exhausted memory, a submit that timed out) say where in the job
// they happened: the error is thrown again with the stage in front, its VkResult and kind kept, so
// the CLI still exits 75 or 69 (host/cli/exit_codes.cpp). Other errors pass unchanged.
#pragma once
#include <string>

#include "vkunroll/base/error.hpp"
#include "vkunroll/runtime/vk_error.hpp"

namespace vkunroll {

template <class F>
auto in_device_stage(const std::string& stage, F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const VulkanError& e) {
    throw VulkanError(e.result(), stage + ": " + e.text());
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::temporary && e.kind() != ErrorKind::device_unavailable) throw;
    throw Error(stage + ": " + e.text(), e.kind());
  }
}

}  // namespace vkunroll
