// The benches' same-run peers (PyTorch, NumPy) run as child processes: one way to run them.
#pragma once
#include <cstdio>
#include <string>

// A shell command's exit status (-1: it could not be started) and what it printed on stdout,
// with stderr too when `with_stderr`.
struct CommandOutput {
  int status = -1;
  std::string text;
};

inline CommandOutput run_command(const std::string& cmd, bool with_stderr) {
  CommandOutput r;
  FILE* p = popen((with_stderr ? cmd + " 2>&1" : cmd).c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, p)) > 0) r.text.append(buf, n);
  r.status = pclose(p);
  return r;
}
