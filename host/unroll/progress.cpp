#include "vkunroll/host/unroll/progress.hpp"

#include <unistd.h>

#include <algorithm>
#include <cstdio>

#include "vkunroll/base/log.hpp"

namespace vkunroll {

Progress::Style Progress::automatic(bool quiet) {
  if (quiet) return Style::quiet;
  return isatty(fileno(stderr)) ? Style::bar : Style::lines;
}

Progress::Progress(std::string what, size_t total, Style style)
    : what_(std::move(what)), total_(std::max<size_t>(total, 1)), style_(style) {}

std::string Progress::format_duration(double s) {
  char buf[32];
  if (s < 60)
    std::snprintf(buf, sizeof buf, "%.0fs", s);
  else if (s < 3600)
    std::snprintf(buf, sizeof buf, "%dm%02ds", int(s) / 60, int(s) % 60);
  else
    std::snprintf(buf, sizeof buf, "%dh%02dm", int(s) / 3600, (int(s) % 3600) / 60);
  return buf;
}

void Progress::update(size_t done, const std::string& label) {
  if (style_ == Style::quiet) return;
  done = std::min(done, total_);
  const double elapsed = elapsed_.seconds();
  const double eta = done ? elapsed / done * (total_ - done) : 0;
  const int percent = static_cast<int>(100 * done / total_);
  if (style_ == Style::bar) {
    const int width = 30, filled = width * static_cast<int>(done) / static_cast<int>(total_);
    std::string bar(filled, '#');
    bar.resize(width, '.');
    char line[256];
    std::snprintf(line, sizeof line, "\r%s [%s] %zu/%zu %3d%% elapsed %s ETA %s %-24.24s", what_.c_str(), bar.c_str(), done,
                  total_, percent, format_duration(elapsed).c_str(), done ? format_duration(eta).c_str() : "?", label.c_str());
    log_message(LogLevel::progress, line);
  } else if (percent / 10 != last_percent_line_ / 10 || done == total_) {
    // Plain lines (logs, CI): one line per 10% step.
    last_percent_line_ = percent;
    char line[512];
    std::snprintf(line, sizeof line, "%s: %zu/%zu (%d%%) elapsed %s ETA %s%s%s\n", what_.c_str(), done, total_, percent,
                  format_duration(elapsed).c_str(), done ? format_duration(eta).c_str() : "?", label.empty() ? "" : " ",
                  label.c_str());
    log_message(LogLevel::progress, line);
  }
}

void Progress::finish() {
  if (finished_) return;
  finished_ = true;
  if (style_ == Style::bar) log_message(LogLevel::progress, "\n");
}

}  // namespace vkunroll
