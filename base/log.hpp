// The library's messages to whoever runs it (the device chosen, the contrast estimate, warnings, a
// job's progress), through one sink with levels that the embedding program installs: the CLI writes
// them to stderr (--quiet: warnings and errors only), Python hands them to logging.getLogger("vkunroll").
// Until a sink is installed, warnings and errors go to stderr and the rest nowhere, so nothing a
// caller should see is lost; the library itself never writes to a stream.
//
//   log_info("unroll: event gate radius 2 (auto)");
//   set_log_sink([](LogLevel l, std::string_view m) { ... });   // once, at start-up
#pragma once
#include <functional>
#include <string_view>

namespace vkunroll {

enum class LogLevel {
  debug,     // detail for the curious
  info,      // what a run chose and did
  progress,  // a job's progress line: "\r..." to redraw in place, or a whole line ending in '\n'
  warning,   // a result that may not be what was asked for
  error,     // a failure the library reports but does not throw (e.g. a validation message)
};
const char* log_level_name(LogLevel level);  // "debug", "info", ...

using LogSink = std::function<void(LogLevel level, std::string_view message)>;

// Installs `sink` for every thread (empty: the default above); returns the sink it replaces.
LogSink set_log_sink(LogSink sink);

// One message (without a trailing newline, but for progress lines) to the installed sink.
void log_message(LogLevel level, std::string_view message);
inline void log_debug(std::string_view m) { log_message(LogLevel::debug, m); }
inline void log_info(std::string_view m) { log_message(LogLevel::info, m); }
inline void log_warning(std::string_view m) { log_message(LogLevel::warning, m); }
inline void log_error(std::string_view m) { log_message(LogLevel::error, m); }

}  // namespace vkunroll
