// A job's progress, as log messages of level `progress` (base/log.hpp): a bar with ETA redrawn in
// place on a terminal, plain lines otherwise, nothing when quiet.
#pragma once
#include <string>

#include "vkunroll/base/stopwatch.hpp"

namespace vkunroll {

class Progress {
 public:
  enum class Style { bar, lines, quiet };
  // `automatic`: a bar when stderr is a terminal, plain lines otherwise.
  static Style automatic(bool quiet);

  Progress(std::string what, size_t total, Style style);
  // Marks `done` of `total` finished; `label` says what was just finished.
  void update(size_t done, const std::string& label = {});
  void finish();

  static std::string format_duration(double seconds);  // "42s", "3m05s", "1h02m"

 private:
  std::string what_;
  size_t total_;
  Style style_;
  Stopwatch elapsed_;
  int last_percent_line_ = -1;
  bool finished_ = false;
};

}  // namespace vkunroll
