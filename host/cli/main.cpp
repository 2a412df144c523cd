// vkunroll: rolling-shutter + events -> global-shutter video, on any Vulkan GPU.
#include <cstring>
#include <exception>
#include <iostream>

#include "vkunroll/host/cli/commands.hpp"
#include "vkunroll/base/error.hpp"

namespace {

struct Command {
  const char* name;
  int (*run)(const vkunroll::cli::Argv&);
  const char* summary;
};

const Command kCommands[] = {
    {"devices", vkunroll::cli::cmd_devices, "list Vulkan devices and mark the one vkunroll would use"},
    {"simulate", vkunroll::cli::cmd_simulate, "simulate RS frames, GS ground truth and events from a moving scene"},
    {"events", vkunroll::cli::cmd_events, "read an event file: count, time span, rate, sensor size, polarity, drops"},
    {"voxelize", vkunroll::cli::cmd_voxelize, "row-aware event tensors ev1/ev2/ev3 of (frame, target) pairs -> safetensors"},
    {"demo", vkunroll::cli::cmd_demo, "simulate a built-in scene and unroll it (the shipped model and physics)"},
    {"unroll", vkunroll::cli::cmd_unroll, "turn a recording (RS frames + events) into GS frames, video and metrics"},
    {"infer", vkunroll::cli::cmd_infer, "run SelfUnroll-S/-M on raw input tensors, write every intermediate"},
};

void usage(std::ostream& os) {
  os << "vkunroll " << VKUNROLL_VERSION << ": rolling-shutter images + events -> global-shutter video (SelfUnroll on Vulkan)\n\n"
     << "usage: vkunroll <command> [options]   (vkunroll <command> --help for its options)\n\ncommands:\n";
  for (const auto& c : kCommands) {
    os << "  " << c.name;
    for (size_t i = std::strlen(c.name); i < 12; ++i) os << ' ';
    os << c.summary << "\n";
  }
  os << "\nenvironment: VKUNROLL_DEVICE (index or name), VKUNROLL_VALIDATION=1, VKUNROLL_CACHE_DIR\n";
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2 || !std::strcmp(argv[1], "--help") || !std::strcmp(argv[1], "-h") || !std::strcmp(argv[1], "help")) {
    usage(std::cout);
    return argc < 2 ? 2 : 0;
  }
  if (!std::strcmp(argv[1], "--version")) {
    std::cout << "vkunroll " << VKUNROLL_VERSION << "\n";
    return 0;
  }
  for (const auto& c : kCommands) {
    if (std::strcmp(argv[1], c.name) != 0) continue;
    try {
      return c.run(vkunroll::cli::Argv(argv + 2, argv + argc));
    } catch (const std::exception& e) {
      std::cerr << "vkunroll " << c.name << ": error: " << e.what() << "\n";
      return 1;
    }
  }
  std::cerr << "vkunroll: unknown command '" << argv[1] << "'\n\n";
  usage(std::cerr);
  return 2;
}
