#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "vkunroll/base/env.hpp"
#include "vkunroll/host/cli/cli.hpp"
#include "vkunroll/host/unroll/provenance.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll::cli {

namespace {

struct DevicesArgs {
  std::string device;
  bool json = false;
};

int run_devices(const DevicesArgs& a) {
  // The list makes no device, so nothing else reads these: a value they do not take is refused here too.
  (void)env::flag("VKUNROLL_VALIDATION");
  (void)env::flag("VKUNROLL_VALIDATION_FATAL");
  const DeviceList list = Context::enumerate();
  uint32_t chosen = list.policy_choice;
  if (!a.device.empty()) chosen = choose_device(list.devices, a.device, "--device");
  if (a.json) {
    nlohmann::json out = {{"chosen", chosen}, {"devices", nlohmann::json::array()}};
    for (const auto& d : list.devices) {
      nlohmann::json j = device_json(d);
      j["subgroup_size"] = d.subgroup_size;
      j["shader_float16"] = d.shader_float16;
      j["storage_buffer_16bit"] = d.storage_buffer_16bit;
      j["max_storage_buffer_range"] = d.max_storage_buffer_range;
      j["max_shared_memory"] = d.max_shared_memory;
      j["device_local_bytes"] = d.device_local_bytes;
      j["timestamps"] = d.timestamps;
      j["cooperative_matrix_nv"] = d.coopmat_nv;
      j["cooperative_matrix_khr_listed"] = d.coopmat_khr_listed;
      j["cooperative_matrix_shapes"] = nlohmann::json::array();
      for (const CoopMatShape& s : d.coopmat_shapes) j["cooperative_matrix_shapes"].push_back(s.str());
      out["devices"].push_back(j);
    }
    std::cout << out.dump(2) << "\n";
    return 0;
  }
  for (const auto& d : list.devices) {
    std::cout << (d.index == chosen ? "* " : "  ") << "[" << d.index << "] " << d.name << "\n"
              << "      uuid:" << d.uuid_string() << "\n"
              << "      type " << d.type_name() << ", Vulkan " << d.api_version_string() << ", driver "
              << (d.driver_name.empty() ? "?" : d.driver_name) << (d.driver_info.empty() ? "" : " " + d.driver_info)
              << " (version " << d.driver_version_string() << ")\n"
              << "      subgroup " << d.subgroup_size << ", fp16 arithmetic " << (d.shader_float16 ? "yes" : "no")
              << ", 16-bit storage " << (d.storage_buffer_16bit ? "yes" : "no") << "\n"
              << "      max storage buffer range " << (d.max_storage_buffer_range >> 20) << " MiB, shared memory "
              << (d.max_shared_memory >> 10) << " KiB, push constants " << d.max_push_constants << " B, timestamps "
              << (d.timestamps ? "yes" : "no") << "\n";
    const auto cm = d.coopmat_fp16_shape();
    std::cout << "      cooperative matrix (VK_NV_cooperative_matrix) " << (d.coopmat_nv ? "yes" : "no")
              << (cm ? ", conv coopmat uses " + cm->str() : "") << (d.coopmat_khr_listed ? "; VK_KHR_cooperative_matrix listed" : "")
              << "\n";
    for (const CoopMatShape& s : d.coopmat_shapes) std::cout << "        " << s.str() << "\n";
  }
  std::cout << "vkunroll would use [" << chosen << "] " << list.devices[chosen].name << "\n";
  return 0;
}

}  // namespace

Command add_devices(CLI::App& parent) {
  auto a = std::make_shared<DevicesArgs>();
  CLI::App* c = parent.add_subcommand("devices", "list Vulkan devices and mark the one vkunroll would use");
  c->description(
      "Lists every Vulkan device with its UUID, type, API version, driver, subgroup size, fp16 support, max\n"
      "storage buffer range and shared memory. '*' marks the device vkunroll would use (--device, else\n"
      "VKUNROLL_DEVICE, else discrete > integrated > virtual > cpu). Jobs on multi-GPU nodes choose theirs\n"
      "with --device uuid:UUID (Vulkan ignores CUDA_VISIBLE_DEVICES).");
  c->add_option("--device", a->device, "INDEX, uuid:UUID or a name substring: mark this one")->type_name("D");
  c->add_flag("--json", a->json, "print the list as JSON (what summary.json records of the device, and limits)");
  return {c, [a] { return run_devices(*a); }};
}

}  // namespace vkunroll::cli
