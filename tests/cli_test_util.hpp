// Runs the built `vkunroll` binary as a user would (shared by the CLI tests).
#pragma once
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <string>

namespace clitest {

struct CliRun {
  int rc = -1;
  std::string out;  // stdout and stderr together
};

// Runs `vkunroll ARGS` through bash (for ulimit and redirections); rc 128+N when killed by signal N.
inline CliRun cli(const std::string& args, const std::string& prefix = "") {
  const std::string cmd = prefix + std::string(VKUNROLL_CLI_PATH) + " " + args + " 2>&1";
  CliRun r;
  FILE* p = ::popen(("bash -c '" + cmd + "'").c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) r.out.append(buf, n);
  const int st = ::pclose(p);
  r.rc = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
  return r;
}

inline bool has(const CliRun& r, const std::string& needle) { return r.out.find(needle) != std::string::npos; }

// A fresh, empty folder /tmp/vkunroll-<suite>-<name>-<pid>.
inline std::filesystem::path temp_dir(const std::string& suite, const std::string& name) {
  const auto d = std::filesystem::temp_directory_path() / ("vkunroll-" + suite + "-" + name + "-" + std::to_string(::getpid()));
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

}  // namespace clitest
