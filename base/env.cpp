#include "vkunroll/base/env.hpp"

#include <cstdlib>
#include <iomanip>
#include <sstream>

#include "vkunroll/base/error.hpp"

namespace vkunroll::env {

namespace {
[[noreturn]] void refuse(const char* name, const std::string& value, const std::string& expected) {
  throw UsageError(std::string(name) + "='" + value + "': expected " + expected);
}

std::string shortest(double v) {
  std::ostringstream s;
  s << std::setprecision(15) << v;
  return s.str();
}
}  // namespace

std::optional<std::string> text(const char* name) {
  const char* v = std::getenv(name);
  if (!v || !*v) return std::nullopt;
  return std::string(v);
}

bool flag(const char* name) {
  const std::optional<std::string> v = text(name);
  if (!v || *v == "0" || *v == "false") return false;
  if (*v == "1" || *v == "true") return true;
  refuse(name, *v, "1 or true (on), 0 or false (off), or unset");
}

double seconds(const char* name, double fallback, double max_s) {
  const std::optional<std::string> v = text(name);
  if (!v) return fallback;
  char* end = nullptr;
  const double s = std::strtod(v->c_str(), &end);  // the whole value, in range: never a silent 0
  if (end == v->c_str() || *end != '\0' || !(s > 0 && s <= max_s))
    refuse(name, *v, "seconds in (0, " + shortest(max_s) + "] (default " + shortest(fallback) + ")");
  return s;
}

}  // namespace vkunroll::env
