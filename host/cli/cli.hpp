// The `vkunroll` command line, on CLI11: each subcommand declares its options once (the help is
// generated from the same declarations) and parses them into the library's typed options.
// Shared option groups (sequence timing, device) live in common.cpp; exit codes in exit_codes.hpp.
#pragma once
#include <exception>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include <CLI/CLI.hpp>

#include "vkunroll/base/error.hpp"

#include "vkunroll/host/events/sequence.hpp"

namespace vkunroll::cli {

// A declared subcommand and what runs it once its options are parsed (returns the exit code).
struct Command {
  CLI::App* app = nullptr;
  std::function<int()> run;
};

Command add_devices(CLI::App& parent);
Command add_simulate(CLI::App& parent);
Command add_events(CLI::App& parent);
Command add_bag_sequence(CLI::App& parent);
Command add_voxelize(CLI::App& parent);
Command add_demo(CLI::App& parent);
Command add_unroll(CLI::App& parent);
Command add_infer(CLI::App& parent);
Command add_tune(CLI::App& parent);

// The help layout: "usage: vkunroll unroll SEQUENCE --out DIR [options]" (required options named).
class Formatter : public CLI::Formatter {
 public:
  Formatter();
  std::string make_usage(const CLI::App* app, std::string name) const override;
  std::string usage(const CLI::App* app) const { return make_usage(app, app->get_name()); }
};

// The sequence timing options, the same names for unroll and voxelize (group "Sequence timing").
struct SequenceTimingArgs {
  std::string layout, line_delay, exposure, readout, t0s, frame_period, on_bad = "error", events, events_topic;
  bool gev_half_row = false;
};
void add_sequence_timing(CLI::App* app, SequenceTimingArgs& a);
// Parsed and validated; errors are UsageError naming the option.
SequenceOptions sequence_options(const SequenceTimingArgs& a);

// Where to run (group "Device"): --device INDEX|NAME|uuid:UUID and --threads N.
struct DeviceArgs {
  std::string device;
  unsigned threads = 0;  // 0: the machine's
};
void add_device_options(CLI::App* app, DeviceArgs& a);
// Bounds the process's threads before any Vulkan instance exists: LP_NUM_THREADS (lavapipe's
// rasterizer workers) and OpenCV's pool (the CPU backend's convolutions, image encoding).
void apply_threads(unsigned threads);

// "WIDTHxHEIGHT", each 2 to 32767; UsageError naming `what` (the option) otherwise.
void parse_size(const std::string& s, const std::string& what, int& w, int& h);

// Validators with messages that name the range.
CLI::Validator finite_at_least(double lo, bool open = false);  // x >= lo (x > lo when open), finite
CLI::Validator finite_range(double lo, double hi);             // lo <= x <= hi, finite
CLI::Validator int_range(long long lo, long long hi);
CLI::Validator non_empty();  // refuses "" (an empty value is an error, never "the default")

// Declares the output option `id` of the output table (host/unroll/output_paths.hpp) on `app`: its
// spelling and help from the table, an empty value refused while parsing (a usage error before any
// work). std::logic_error for an id that is not one of `app`'s CLI entries.
CLI::Option* add_output_option(CLI::App* app, std::string_view id, std::string& value);

// An output file that is written under a temporary name and renamed over `path`: refused
// (UsageError naming `option`) when `path` exists and is not a regular file (a folder, a device
// such as /dev/full, a FIFO), which the rename would replace.
void check_output_file(const std::string& path, const std::string& option);

// An output folder: refused (UsageError naming `option`) when `path`, or a folder above it, exists
// and is not a folder (the run could not create it; the option is at fault, not the disk).
void check_output_folder(const std::string& path, const std::string& option);

// The flag that spells a library field in messages (base/error.hpp opt()): times_us -> --times-us,
// sequence -> SEQUENCE, speed_scale -> --speed, ...
std::string flag_for(std::string_view field);
// An exception's message as the CLI shows it: a library error's options spelled as flags.
std::string cli_message(const std::exception& e);

// Numbers in messages: inf, -inf, nan by name; integers without an exponent.
std::string number_text(double v);

// The process's argv, for provenance (set by main).
const std::vector<std::string>& command_line();
void set_command_line(int argc, char** argv);

}  // namespace vkunroll::cli
