#include "vkunroll/base/log.hpp"

#include <cstdio>
#include <iterator>
#include <mutex>
#include <string>

namespace vkunroll {

namespace {

// The sink until one is installed: what a caller must not miss, on stderr (the one place the
// library writes to a stream, for programs that install no sink).
void default_sink(LogLevel level, std::string_view message) {
  if (level != LogLevel::warning && level != LogLevel::error) return;
  const std::string line = std::string(message) + "\n";
  std::fwrite(line.data(), 1, line.size(), stderr);
}

std::mutex& sink_mutex() {
  static std::mutex m;
  return m;
}

LogSink& installed() {
  static LogSink sink;
  return sink;
}

}  // namespace

const char* log_level_name(LogLevel level) {
  static const char* const names[] = {"debug", "info", "progress", "warning", "error"};  // in LogLevel's order
  static_assert(std::size(names) == static_cast<size_t>(LogLevel::error) + 1);
  const auto i = static_cast<size_t>(level);
  return i < std::size(names) ? names[i] : "?";
}

LogSink set_log_sink(LogSink sink) {
  std::lock_guard<std::mutex> lock(sink_mutex());
  LogSink previous = std::move(installed());
  installed() = std::move(sink);
  return previous;
}

void log_message(LogLevel level, std::string_view message) {
  LogSink sink;
  {
    std::lock_guard<std::mutex> lock(sink_mutex());
    sink = installed();  // a copy: the sink runs unlocked, so it may log (or be replaced) itself
  }
  if (sink) sink(level, message);
  else default_sink(level, message);
}

}  // namespace vkunroll
