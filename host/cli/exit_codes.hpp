// Exit codes of `vkunroll`, after BSD sysexits.h, so a scheduler can tell "bad data, don't retry"
// (65, 66, 2) from "device lost, retry" (75). Documented in docs/reliability.md and `vkunroll --help`.
#pragma once
#include <exception>
#include <string>

namespace vkunroll::cli {

enum ExitCode : int {
  kExitOk = 0,
  kExitUsage = 2,         // a refused option, value or combination (also: an existing output without --overwrite)
  kExitData = 65,         // EX_DATAERR: input data that breaks a rule; unclassified vkunroll errors
  kExitNoInput = 66,      // EX_NOINPUT: an input file or folder does not exist
  kExitUnavailable = 69,  // EX_UNAVAILABLE: no usable device (no driver, no device matching --device)
  kExitSoftware = 70,     // EX_SOFTWARE: an internal error (ErrorKind::internal, or an exception that is not a vkunroll error)
  kExitOsError = 71,      // EX_OSERR: out of host memory
  kExitIo = 74,           // EX_IOERR: reading or writing a file failed (disk full, read-only, file too large, a read error)
  kExitTempFail = 75,     // EX_TEMPFAIL: retry: device lost, a submit timed out, device memory, output busy
};

// The exit code of an exception escaping a subcommand, and a one-word category for the message.
int exit_code_for(const std::exception& e, std::string* category = nullptr);

}  // namespace vkunroll::cli
