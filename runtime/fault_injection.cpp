#include "vkunroll/runtime/fault_injection.hpp"

#include <charconv>

#include "vkunroll/base/error.hpp"

namespace vkunroll {

FaultInjection parse_fault_injection(const std::string& text, const std::string& what) {
  const auto refuse = [&] {
    return UsageError(what + "='" + text + "': expected SITE:N:RESULT, SITE submit, allocation, map or pipeline, N >= 1, " +
                      "RESULT device-lost or out-of-device-memory (e.g. submit:3:device-lost)");
  };
  const size_t a = text.find(':'), b = a == std::string::npos ? a : text.find(':', a + 1);
  if (b == std::string::npos) throw refuse();
  const std::string site = text.substr(0, a), n = text.substr(a + 1, b - a - 1), result = text.substr(b + 1);
  FaultInjection f;
  if (site == "submit") f.site = FaultInjection::Site::submit;
  else if (site == "allocation") f.site = FaultInjection::Site::allocation;
  else if (site == "map") f.site = FaultInjection::Site::map;
  else if (site == "pipeline") f.site = FaultInjection::Site::pipeline;
  else throw refuse();
  const auto [end, ec] = std::from_chars(n.data(), n.data() + n.size(), f.nth);
  if (ec != std::errc() || end != n.data() + n.size() || f.nth < 1) throw refuse();
  if (result == "device-lost") f.result = VK_ERROR_DEVICE_LOST;
  else if (result == "out-of-device-memory") f.result = VK_ERROR_OUT_OF_DEVICE_MEMORY;
  else throw refuse();
  return f;
}

}  // namespace vkunroll
