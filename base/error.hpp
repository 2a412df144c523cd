// The base of every error vkunroll throws: the message always says what and where (file, record,
// option). Vulkan failures derive from it in runtime/vk_error.hpp; this header needs no Vulkan.
//
// Each error has a kind, so that a caller can tell "bad data, don't retry" from "device lost, retry"
// (the CLI maps kinds to sysexits exit codes: host/cli/exit_codes.hpp, docs/reliability.md).
//
// A message names an option by the library's field for it (UnrollOptions' `times_us`, ...), marked
// with opt(), never by one front end's spelling of it: the CLI spells a field as its flag
// (--times-us), Python as its keyword (times_us), each through its own map (Error::spelled). what()
// spells each field as it is. An error about one option is an OptionError: it also carries the
// field, the value given and the rule.
#pragma once
#include <functional>
#include <stdexcept>
#include <string>
#include <string_view>

namespace vkunroll {

// Each kind, its CLI exit (sysexits) and its Python exception (docs/errors.md):
enum class ErrorKind {
  unspecified,         // not classified yet (treated as data); the library may throw it only from the
                       // reviewed list in tools/checks/bare_errors_allowed.txt
  usage,               // 2, ValueError: a refused option value or combination
  data,                // 65, ValueError: input data that breaks a rule (a file's contents, a sequence's timing)
  input_missing,       // 66, FileNotFoundError: an input file or folder that does not exist
  device_unavailable,  // 69, RuntimeError: no usable device (no driver, no device matching the selector)
  internal,            // 70, RuntimeError: a broken invariant of vkunroll itself (a bug: please report it)
  io,                  // 74, RuntimeError: reading or writing a file failed: disk full, read-only, a read error
  temporary,           // 75, RuntimeError: worth retrying: device lost, a submit timed out, the output is busy
};

// The kind's name for messages and docs: "usage", "data", "input_missing", ...
const char* kind_name(ErrorKind kind);

// The option `field` inside a message, e.g. opt("times_us") + " 1e400: ...": a mark the front end spells.
inline std::string opt(std::string_view field) { return "\x1f" + std::string(field) + "\x1f"; }
// How a front end spells a field: the CLI's flag, Python's keyword.
using FieldSpelling = std::function<std::string(std::string_view field)>;
// `text` with each opt() mark spelled by `spell`.
std::string spell_fields(std::string_view text, const FieldSpelling& spell);

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& text, ErrorKind kind = ErrorKind::unspecified);
  ErrorKind kind() const { return kind_; }
  // The message with its options marked (opt()): wrap it, not what(), into another error's message.
  const std::string& text() const { return text_; }
  std::string spelled(const FieldSpelling& spell) const { return spell_fields(text_, spell); }

 private:
  ErrorKind kind_;
  std::string text_;
};

// A refused option or argument: `field` (the option at fault), `value` (as given; may be empty) and
// `rule` (what was expected). `text`: the whole message, options marked with opt(); empty:
// opt(field) + " value: rule" (opt(field) + ": rule" without a value). Usually a usage error
// (exit 2, ValueError); a path option naming nothing is input_missing (66, FileNotFoundError).
class OptionError : public Error {
 public:
  OptionError(std::string field, std::string value, std::string rule, std::string text = {},
              ErrorKind kind = ErrorKind::usage);
  const std::string& field() const { return field_; }
  const std::string& value() const { return value_; }
  const std::string& rule() const { return rule_; }

 private:
  std::string field_, value_, rule_;
};

struct UsageError : Error {
  explicit UsageError(const std::string& what) : Error(what, ErrorKind::usage) {}
};
struct DataError : Error {
  explicit DataError(const std::string& what) : Error(what, ErrorKind::data) {}
};
struct InputMissingError : Error {
  explicit InputMissingError(const std::string& what) : Error(what, ErrorKind::input_missing) {}
};
struct DeviceUnavailableError : Error {
  explicit DeviceUnavailableError(const std::string& what) : Error(what, ErrorKind::device_unavailable) {}
};
// A broken invariant of the library itself (a size that the caller already checked, a state that
// cannot happen): not the user's fault, exit 70.
struct InternalError : Error {
  explicit InternalError(const std::string& what) : Error(what, ErrorKind::internal) {}
};
struct IoError : Error {
  explicit IoError(const std::string& what) : Error(what, ErrorKind::io) {}
};
// Exact time arithmetic out of its range (Rational: overflow, a zero denominator, a non-finite
// value); callers that know which option named the time turn it into a UsageError naming it.
struct TimeRangeError : Error {
  explicit TimeRangeError(const std::string& what) : Error(what, ErrorKind::data) {}
};
// Device lost or a submit that did not finish in time (VulkanError with VK_ERROR_DEVICE_LOST or
// VK_TIMEOUT is classified the same way by the CLI).
struct DeviceLostError : Error {
  explicit DeviceLostError(const std::string& what) : Error(what, ErrorKind::temporary) {}
};
// Another run holds the output folder.
struct OutputBusyError : Error {
  explicit OutputBusyError(const std::string& what) : Error(what, ErrorKind::temporary) {}
};

}  // namespace vkunroll
