// A small argument parser for the subcommands: --key value, --flag, and positionals.
// Unknown options are errors that name the option and the subcommand.
#pragma once
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "vkunroll/base/error.hpp"

namespace vkunroll::cli {

class Args {
 public:
  // `flags` take no value; `options` take one. Both are given without the leading "--".
  Args(std::string command, const std::vector<std::string>& argv, std::set<std::string> options,
       std::set<std::string> flags = {});

  bool has(const std::string& key) const { return values_.count(key) || flags_set_.count(key); }
  std::optional<std::string> get(const std::string& key) const;
  std::string get_or(const std::string& key, const std::string& fallback) const;
  std::string require(const std::string& key) const;
  double number(const std::string& key, double fallback) const;
  long long integer(const std::string& key, long long fallback) const;
  const std::vector<std::string>& positionals() const { return positionals_; }
  bool help() const { return help_; }
  const std::string& command() const { return command_; }

 private:
  std::string command_;
  std::map<std::string, std::string> values_;
  std::set<std::string> flags_set_;
  std::vector<std::string> positionals_;
  bool help_ = false;
};

}  // namespace vkunroll::cli
