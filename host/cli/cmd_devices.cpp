#include <iomanip>
#include <iostream>

#include "vkunroll/host/cli/args.hpp"
#include "vkunroll/host/cli/commands.hpp"
#include "vkunroll/runtime/context.hpp"

namespace vkunroll::cli {

int cmd_devices(const Argv& argv) {
  Args args("devices", argv, {"device"});
  if (args.help()) {
    std::cout << "usage: vkunroll devices [--device INDEX|NAME]\n\n"
                 "Lists every Vulkan device with its type, API version, driver, subgroup size, fp16 support,\n"
                 "max storage buffer range and shared memory. '*' marks the device vkunroll would use\n"
                 "(--device, else VKUNROLL_DEVICE, else discrete > integrated > virtual > cpu).\n";
    return 0;
  }
  const DeviceList list = Context::enumerate();
  uint32_t chosen = list.policy_choice;
  if (auto sel = args.get("device")) chosen = choose_device(list.devices, *sel);
  for (const auto& d : list.devices) {
    std::cout << (d.index == chosen ? "* " : "  ") << "[" << d.index << "] " << d.name << "\n"
              << "      type " << d.type_name() << ", Vulkan " << d.api_version_string() << ", driver "
              << (d.driver_name.empty() ? "?" : d.driver_name) << (d.driver_info.empty() ? "" : " " + d.driver_info) << "\n"
              << "      subgroup " << d.subgroup_size << ", fp16 arithmetic " << (d.shader_float16 ? "yes" : "no")
              << ", 16-bit storage " << (d.storage_buffer_16bit ? "yes" : "no") << "\n"
              << "      max storage buffer range " << (d.max_storage_buffer_range >> 20) << " MiB, shared memory "
              << (d.max_shared_memory >> 10) << " KiB, push constants " << d.max_push_constants << " B, timestamps "
              << (d.timestamps ? "yes" : "no") << "\n";
  }
  std::cout << "vkunroll would use [" << chosen << "] " << list.devices[chosen].name << "\n";
  return 0;
}

}  // namespace vkunroll::cli
