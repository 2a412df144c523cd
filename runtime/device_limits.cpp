// The test-only override of a device's limits (ContextOptions::lowered_limits, VKUNROLL_TEST_LIMITS):
// a lavapipe that reports what a smaller real device would, so that every choice made from
// DeviceInfo (conv algorithm, tiling, each algorithm's fits(), pipelines' limit check) is exercised
// where it must pick something smaller or refuse by name.
#include <algorithm>
#include <charconv>
#include <sstream>

#include "vkunroll/base/env.hpp"
#include "vkunroll/runtime/device_limits_detail.hpp"

namespace vkunroll {
namespace {
constexpr const char* kKeys = "subgroup, shared, invocations, storage_range, fp16 (0), timestamps (0)";

uint64_t number(const std::string& key, const std::string& v) {
  uint64_t n = 0;
  const auto [end, ec] = std::from_chars(v.data(), v.data() + v.size(), n);
  if (ec != std::errc() || end != v.data() + v.size() || n == 0)
    throw UsageError(std::string(kTestLimitsVariable) + ": " + key + "=" + v + ": expected a positive whole number");
  return n;
}

template <typename T>
void lower(T& field, uint64_t to, const std::string& key, const char* limit) {
  if (to > field)
    throw UsageError(std::string(kTestLimitsVariable) + ": " + key + "=" + std::to_string(to) + " is above the device's " + limit +
                " " + std::to_string(field) + ": the override only lowers a limit");
  field = static_cast<T>(to);
}
}  // namespace

std::string lower_device_limits_from_env(DeviceInfo& info, bool* without_fp16) {
  const auto text = env::text(kTestLimitsVariable);
  if (!text) return {};
  std::istringstream in(*text);
  std::string item;
  while (std::getline(in, item, ',')) {
    if (item.empty()) continue;
    const size_t eq = item.find('=');
    if (eq == std::string::npos)
      throw UsageError(std::string(kTestLimitsVariable) + ": '" + item + "': expected key=value with a key among " + kKeys);
    const std::string key = item.substr(0, eq), v = item.substr(eq + 1);
    if (key == "fp16" || key == "timestamps") {
      if (v != "0") throw UsageError(std::string(kTestLimitsVariable) + ": " + key + "=" + v + ": expected 0 (the override only takes a feature away)");
      if (key == "fp16") *without_fp16 = true;
      else info.timestamps = false;
    } else if (key == "subgroup") {
      const uint64_t n = number(key, v);
      if (n & (n - 1)) throw UsageError(std::string(kTestLimitsVariable) + ": subgroup=" + v + ": expected a power of two");
      lower(info.subgroup_size, n, key, "subgroupSize");
      // The widths a pipeline may ask for (subgroup size control) shrink with it.
      info.max_subgroup_size = std::min<uint32_t>(info.max_subgroup_size, static_cast<uint32_t>(n));
      info.min_subgroup_size = std::min<uint32_t>(info.min_subgroup_size, static_cast<uint32_t>(n));
    } else if (key == "shared") {
      lower(info.max_shared_memory, number(key, v), key, "maxComputeSharedMemorySize");
    } else if (key == "invocations") {
      lower(info.max_workgroup_invocations, number(key, v), key, "maxComputeWorkGroupInvocations");
    } else if (key == "storage_range") {
      lower(info.max_storage_buffer_range, number(key, v), key, "maxStorageBufferRange");
    } else {
      throw UsageError(std::string(kTestLimitsVariable) + ": unknown key '" + key + "': expected one of " + kKeys);
    }
  }
  return *text;
}

}  // namespace vkunroll
