// Test-only device faults: the Nth queue submission, memory allocation, memory map or pipeline
// compile of a context fails with a chosen VkResult, as a lost or exhausted device would make it
// fail, so that tests can sweep N over a whole run and check that every failure is named,
// classified and leaves nothing that claims success (tests/python/test_device_faults.py). Off
// unless asked for.
#pragma once
#include <array>
#include <cstdint>
#include <string>

#include <volk.h>

namespace vkunroll {

struct FaultInjection {
  enum class Site { none, submit, allocation, map, pipeline };
  Site site = Site::none;
  uint64_t nth = 0;  // 1-based: the nth call at `site` fails
  VkResult result = VK_ERROR_DEVICE_LOST;
};

// "submit:3:device-lost", "allocation:1:out-of-device-memory", "map:2:device-lost",
// "pipeline:4:out-of-device-memory" (what VKUNROLL_INJECT_FAULT takes); a UsageError naming `what`
// otherwise.
FaultInjection parse_fault_injection(const std::string& text, const std::string& what);

// Counts the calls at each site; the one asked for fails.
class FaultInjector {
 public:
  explicit FaultInjector(FaultInjection plan = {}) : plan_(plan) {}
  // VK_SUCCESS, or the planned result when this call at `site` is the planned one.
  VkResult next(FaultInjection::Site site) {
    const uint64_t n = ++calls_[static_cast<size_t>(site)];
    return site == plan_.site && n == plan_.nth ? plan_.result : VK_SUCCESS;
  }
  uint64_t calls(FaultInjection::Site site) const { return calls_[static_cast<size_t>(site)]; }
  bool armed() const { return plan_.site != FaultInjection::Site::none; }

 private:
  FaultInjection plan_;
  std::array<uint64_t, 5> calls_{};
};

}  // namespace vkunroll
