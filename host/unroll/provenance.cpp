#include "vkunroll/host/unroll/provenance.hpp"

#include <unistd.h>

#include <ctime>

#include "vkunroll_build_info.hpp"

namespace vkunroll {

BuildInfo build_info() { return {VKUNROLL_VERSION, VKUNROLL_GIT_REVISION, VKUNROLL_GIT_DIRTY}; }

std::string build_info_line() {
  const BuildInfo b = build_info();
  std::string s = b.version + " (git " + (b.git_revision == "unknown" ? b.git_revision : b.git_revision.substr(0, 12));
  if (b.git_dirty == 1) s += ", modified";
  return s + ")";
}

nlohmann::json device_json(const DeviceInfo& d) {
  char ids[32];
  std::snprintf(ids, sizeof ids, "0x%04x:0x%04x", d.vendor_id, d.device_id);
  return {{"index", d.index},
          {"name", d.name},
          {"type", d.type_name()},
          {"uuid", d.uuid_string()},
          {"vendor_device_id", ids},
          {"vulkan", d.api_version_string()},
          {"driver_name", d.driver_name},
          {"driver_info", d.driver_info},
          {"driver_version", d.driver_version_string()},
          {"driver_version_raw", d.driver_version}};
}

std::string host_name() {
  char buf[256] = {};
  if (::gethostname(buf, sizeof buf - 1) != 0) return "unknown";
  return buf;
}

std::string utc_now() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

}  // namespace vkunroll
