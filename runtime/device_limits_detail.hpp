// The test-only override of a device's limits (VKUNROLL_TEST_LIMITS; docs/testing.md, "Devices and
// limits"): private to the runtime's sources.
#pragma once
#include <string>

#include "vkunroll/runtime/context.hpp"

namespace vkunroll {

// The variable's text, e.g. "subgroup=4,shared=16384,invocations=128,storage_range=134217728,fp16=0,timestamps=0".
constexpr const char* kTestLimitsVariable = "VKUNROLL_TEST_LIMITS";

// `info` with VKUNROLL_TEST_LIMITS's limits lowered (unset: unchanged); sets *without_fp16 for
// "fp16=0". A value above the device's own, an unknown key or a malformed value is an Error naming
// the variable and the key: the override only makes a device smaller. Returns what it lowered.
std::string lower_device_limits_from_env(DeviceInfo& info, bool* without_fp16);

}  // namespace vkunroll
