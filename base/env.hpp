// The environment variables vkunroll reads, each parsed one way here: a value the variable does not
// take is a UsageError naming the variable, its value and what it takes. The table of variables and
// their values: docs/usage.md, "Environment".
#pragma once
#include <optional>
#include <string>

namespace vkunroll::env {

// The variable's value; nullopt when it is unset or empty (empty means "not set" for every variable).
std::optional<std::string> text(const char* name);
// A switch: unset, empty, 0 or false is off; 1 or true is on; any other value is an error.
bool flag(const char* name);
// A number of seconds in (0, max_s], the whole value (no unit, no trailing text); `fallback` when
// unset or empty.
double seconds(const char* name, double fallback, double max_s);

}  // namespace vkunroll::env
