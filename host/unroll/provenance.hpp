// Where a result came from, for summary.json: vkunroll's version and git revision (generated at
// build time; "unknown" in a build from a tarball), the device and its driver, the host.
#pragma once
#include <string>

#include <nlohmann/json.hpp>

#include "vkunroll/runtime/context.hpp"

namespace vkunroll {

struct BuildInfo {
  std::string version;       // VKUNROLL_VERSION, e.g. "0.1.0"
  std::string git_revision;  // full commit hash, or "unknown"
  int git_dirty = -1;        // 1: built with uncommitted changes to tracked files, 0: clean, -1: unknown
};
BuildInfo build_info();
std::string build_info_line();  // "0.1.0 (git 89215ba1c2d3, modified)"

// Name, type, UUID, driver (name, info, version), Vulkan version, vendor and device ids.
nlohmann::json device_json(const DeviceInfo& d);

std::string host_name();
std::string utc_now();  // "2026-11-27T12:34:56Z"

}  // namespace vkunroll
