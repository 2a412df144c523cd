// The subcommands of the `vkunroll` CLI: one file each, listed in main.cpp.
#pragma once
#include <string>
#include <vector>

namespace vkunroll::cli {

using Argv = std::vector<std::string>;

int cmd_devices(const Argv& args);
int cmd_simulate(const Argv& args);
int cmd_events(const Argv& args);
int cmd_voxelize(const Argv& args);
int cmd_infer(const Argv& args);
int cmd_unroll(const Argv& args);
int cmd_demo(const Argv& args);

}  // namespace vkunroll::cli
