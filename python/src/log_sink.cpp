// The library's log (base/log.hpp) -> Python's logging, and its options spelled as keywords.
// The sink is installed when the module is imported, for every thread: a message is logged at once,
// taking the GIL. The threads that log hold no lock a GIL holder could wait for (contexts are locked
// only after the GIL is released), so this cannot deadlock.
#include <cstdio>
#include <map>

#include "common.hpp"
#include "vkunroll/base/env.hpp"
#include "vkunroll/base/log.hpp"

namespace vkunroll::python {

namespace {

int python_level(LogLevel level) {
  switch (level) {
    case LogLevel::debug:
    case LogLevel::progress: return kDebug;
    case LogLevel::info: return kInfo;
    case LogLevel::warning: return kWarning;
    case LogLevel::error: return kError;
  }
  return kInfo;
}

void to_python_logging(LogLevel level, std::string_view message) {
  std::string line = spell_fields(message, python_keyword);
  while (!line.empty() && line.back() == '\n') line.pop_back();  // progress lines carry their own line ends
  if (!line.empty() && line.front() == '\r') line.erase(0, 1);
  if (line.rfind("vkunroll: ", 0) == 0) line.erase(0, 10);
  if (line.empty()) return;
  // Under VKUNROLL_VALIDATION_FATAL the process aborts right after a validation message: say it
  // where it is seen. A value it does not take is refused, by name, where a Context reads it.
  static const bool fatal = [] {
    try {
      return env::flag("VKUNROLL_VALIDATION_FATAL");
    } catch (const Error&) {
      return false;
    }
  }();
  if (fatal && (level == LogLevel::warning || level == LogLevel::error)) std::fprintf(stderr, "vkunroll: %s\n", line.c_str());
  log_message(python_level(level), line);
}

}  // namespace

std::string python_keyword(std::string_view field) {
  // Fields whose keyword differs (vkunroll.stream's arguments; overwrite as it is passed to replace an
  // output; read_events' topic, which Sequence calls events_topic); every other field is its keyword.
  static const std::map<std::string_view, std::string_view> renamed = {
      {"follow_events", "events"}, {"follow_idle_s", "idle_s"}, {"follow_max_events", "max_events"},
      {"overwrite", "overwrite=True"}, {"events_topic", "topic"}};
  const auto it = renamed.find(field);
  return std::string(it == renamed.end() ? field : it->second);
}

void install_log_sink() { set_log_sink(to_python_logging); }

void log_message(int level, const std::string& message) {
  if (!Py_IsInitialized()) return;
  py::gil_scoped_acquire gil;
  try {
    py::module_::import("logging").attr("getLogger")("vkunroll").attr("log")(level, message);
  } catch (py::error_already_set& e) {
    e.discard_as_unraisable("vkunroll logging");
  }
}

}  // namespace vkunroll::python
