// The base of every error vkunroll throws: the message always says what and where (file, record,
// option). Vulkan failures derive from it in runtime/vk_error.hpp; this header needs no Vulkan.
//
// Each error has a kind, so that a caller can tell "bad data, don't retry" from "device lost, retry"
// (the CLI maps kinds to sysexits exit codes: host/cli/exit_codes.hpp, docs/reliability.md).
#pragma once
#include <stdexcept>
#include <string>

namespace vkunroll {

enum class ErrorKind {
  unspecified,         // not classified (treated as bad input data: deterministic, a retry fails again)
  usage,               // a refused option value or combination
  data,                // input data that breaks a rule (a file's contents, a sequence's timing)
  input_missing,       // an input file or folder that does not exist
  device_unavailable,  // no usable device (no driver, no device matching the selector)
  io,                  // writing (or reading back) an output failed: disk full, read-only, ...
  temporary,           // worth retrying: device lost, a submit timed out, the output is busy
};

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what, ErrorKind kind = ErrorKind::unspecified)
      : std::runtime_error(what), kind_(kind) {}
  ErrorKind kind() const { return kind_; }

 private:
  ErrorKind kind_;
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
