// vkunroll: rolling-shutter + events -> global-shutter video, on any Vulkan GPU.
#include <csignal>
#include <cstring>
#include <exception>
#include <iostream>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include "vkunroll/base/log.hpp"
#include "vkunroll/host/cli/cli.hpp"
#include "vkunroll/host/cli/exit_codes.hpp"
#include "vkunroll/host/unroll/provenance.hpp"

namespace {

const char* kFooter =
    "Run 'vkunroll <command> --help' for a command's options.\n\n"
    "Environment: VKUNROLL_DEVICE (index, uuid:UUID or name), VKUNROLL_VALIDATION=1, VKUNROLL_VALIDATION_FATAL=1,\n"
    "VKUNROLL_CACHE_DIR, VKUNROLL_NO_PIPELINE_CACHE=1, VKUNROLL_FENCE_TIMEOUT_S, VKUNROLL_MODEL, VK_DRIVER_FILES\n"
    "(values: docs/usage.md, \"Environment\").\n\n"
    "Exit codes (sysexits): 0 success; 2 usage (refused option, existing output without --overwrite);\n"
    "65 bad input data; 66 missing input; 69 no usable device; 70 internal error; 71 out of memory;\n"
    "74 I/O error writing outputs; 75 temporary failure, retry (device lost, timeout, device memory,\n"
    "output busy). See docs/reliability.md.";

// A message must not repeat the "vkunroll unroll: error:" prefix it is printed under.
std::string without_prefix(std::string msg, const std::string& command) {
  for (const std::string& p : {"vkunroll " + command + ": ", command + ": ", std::string("vkunroll: ")})
    if (!command.empty() && msg.rfind(p, 0) == 0) msg = msg.substr(p.size());
  return msg;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace vkunroll::cli;
  // A file-size limit (ulimit -f) fails the write (EFBIG, exit 74) instead of killing the process.
  std::signal(SIGXFSZ, SIG_IGN);
#if defined(__GLIBC__)
  // Keep freed host blocks up to 32 MB in the heap instead of handing them back to the kernel: each
  // GS frame allocates and frees its planes, PNG buffers and event windows again, and on this
  // project's 2-core VMs a fresh page costs ~11 us to fault in (3 ms per MB; docs/measurements.md).
  mallopt(M_MMAP_THRESHOLD, 32 << 20);
  mallopt(M_TRIM_THRESHOLD, 1 << 30);
#endif
  set_command_line(argc, argv);
  // The library's messages on stderr, its options spelled as flags (a command's --quiet keeps its
  // own lines out; warnings and errors always show).
  vkunroll::set_log_sink([](vkunroll::LogLevel level, std::string_view message) {
    const std::string text = vkunroll::spell_fields(message, flag_for);
    if (level == vkunroll::LogLevel::progress) std::cerr << text << std::flush;  // a progress line has its own line end
    else std::cerr << text << "\n";
  });
  CLI::App app{"vkunroll " + vkunroll::build_info_line() +
                   ": rolling-shutter images + events -> global-shutter video (SelfUnroll on Vulkan)",
               "vkunroll"};
  auto formatter = std::make_shared<Formatter>();
  app.formatter(formatter);
  app.footer(kFooter);
  app.set_version_flag("--version", "vkunroll " + vkunroll::build_info_line());
  app.require_subcommand(1, 1);
  app.fallthrough(false);
  std::vector<Command> commands = {add_devices(app), add_simulate(app), add_events(app), add_voxelize(app),
                                   add_demo(app),    add_unroll(app),   add_infer(app),
                                   add_tune(app),    add_bag_sequence(app)};
  for (auto& c : commands) c.app->formatter(formatter);
  if (argc == 2 && !std::strcmp(argv[1], "help")) {
    std::cout << app.help();
    return kExitOk;
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) return app.exit(e);  // --help, --version
    const auto selected = app.get_subcommands();
    const CLI::App* where = selected.empty() ? &app : selected.front();
    std::string msg = e.what();
    if (selected.empty() && argc > 1 && argv[1][0] != '-') {
      msg = std::string("unknown command '") + argv[1] + "'; the commands are";
      for (const auto& c : commands) msg += " " + c.app->get_name();
    }
    else if (selected.empty() && argc < 2)
      msg = "no command given";
    const std::string prefix = where == &app ? "vkunroll" : "vkunroll " + where->get_name();
    std::cerr << prefix << ": error: " << msg << "\n" << formatter->usage(where);
    std::cerr << "(see '" << prefix << " --help')\n";
    return kExitUsage;
  }
  for (const auto& c : commands) {
    if (!c.app->parsed()) continue;
    try {
      return c.run();
    } catch (const std::exception& e) {
      std::string category;
      const int code = exit_code_for(e, &category);
      std::cerr << "vkunroll " << c.app->get_name() << ": error: " << without_prefix(cli_message(e), c.app->get_name()) << "\n";
      if (code == kExitUsage) std::cerr << formatter->usage(c.app) << "(see 'vkunroll " << c.app->get_name() << " --help')\n";
      return code;
    }
  }
  return kExitUsage;
}
