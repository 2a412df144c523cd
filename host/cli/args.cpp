#include "vkunroll/host/cli/args.hpp"

#include <cerrno>
#include <cstdlib>

namespace vkunroll::cli {

Args::Args(std::string command, const std::vector<std::string>& argv, std::set<std::string> options,
           std::set<std::string> flags)
    : command_(std::move(command)) {
  for (size_t i = 0; i < argv.size(); ++i) {
    const std::string& a = argv[i];
    if (a == "-h" || a == "--help") {
      help_ = true;
      continue;
    }
    if (a.size() > 2 && a.rfind("--", 0) == 0) {
      std::string key = a.substr(2), value;
      const auto eq = key.find('=');
      const bool inline_value = eq != std::string::npos;
      if (inline_value) {
        value = key.substr(eq + 1);
        key = key.substr(0, eq);
      }
      if (flags.count(key)) {
        if (inline_value) throw Error("vkunroll " + command_ + ": --" + key + " takes no value");
        flags_set_.insert(key);
      } else if (options.count(key)) {
        if (!inline_value) {
          if (i + 1 >= argv.size()) throw Error("vkunroll " + command_ + ": --" + key + " needs a value");
          value = argv[++i];
        }
        values_[key] = value;
      } else {
        throw Error("vkunroll " + command_ + ": unknown option --" + key + " (see vkunroll " + command_ + " --help)");
      }
    } else {
      positionals_.push_back(a);
    }
  }
}

std::optional<std::string> Args::get(const std::string& key) const {
  auto it = values_.find(key);
  if (it == values_.end()) return std::nullopt;
  return it->second;
}

std::string Args::get_or(const std::string& key, const std::string& fallback) const {
  auto v = get(key);
  return v ? *v : fallback;
}

std::string Args::require(const std::string& key) const {
  auto v = get(key);
  if (!v) throw Error("vkunroll " + command_ + ": --" + key + " is required (see vkunroll " + command_ + " --help)");
  return *v;
}

double Args::number(const std::string& key, double fallback) const {
  auto v = get(key);
  if (!v) return fallback;
  char* end = nullptr;
  errno = 0;
  const double d = std::strtod(v->c_str(), &end);
  if (errno || end == v->c_str() || *end)
    throw Error("vkunroll " + command_ + ": --" + key + " expects a number, got '" + *v + "'");
  return d;
}

long long Args::integer(const std::string& key, long long fallback) const {
  auto v = get(key);
  if (!v) return fallback;
  char* end = nullptr;
  errno = 0;
  const long long n = std::strtoll(v->c_str(), &end, 10);
  if (errno || end == v->c_str() || *end)
    throw Error("vkunroll " + command_ + ": --" + key + " expects an integer, got '" + *v + "'");
  return n;
}

}  // namespace vkunroll::cli
