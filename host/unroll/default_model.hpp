// The shipped default model: what `unroll`, `demo`, Python's `unroll` and the benches run when no
// model file is named. One rule finds it everywhere (docs/usage.md, "The default model").
#pragma once
#include <string>
#include <vector>

#include "vkunroll/host/unroll/unroll_options.hpp"

namespace vkunroll {

inline constexpr const char* kDefaultModelFile = "selfunroll_small_physics.safetensors";

struct DefaultModelSearch {
  std::string path;                   // the file found; empty: none
  std::string source;                 // "VKUNROLL_MODEL", "installed" or "source tree"
  std::vector<std::string> searched;  // every place looked at, in order
};

// VKUNROLL_MODEL when set (it must name an existing file: else UsageError naming it); else
// share/vkunroll/models/<kDefaultModelFile> beside the binary holding this library (an installed
// CLI in <prefix>/bin, the Python module in <prefix>/lib/python3.X/dist-packages/vkunroll), then
// in the configured install prefix; else the source tree's models/ (a build-tree binary).
DefaultModelSearch find_default_model();

// Folders of committed conv choice tables (host/model/conv_choice.hpp, find_committed_conv_table):
// VKUNROLL_CONV_TABLES (one folder) when set; else conv_choices/ in each folder find_default_model
// looks in (share/vkunroll/models/conv_choices installed, models/conv_choices in the source tree).
std::vector<std::string> conv_table_dirs();

// The model a run uses: `given` (--model) when not empty; none for --mode physics; else the
// default. Without one, auto falls back to physics (said in one line on stderr) and s / m /
// choose are a UsageError naming where it looked. `source` says which of these it was.
struct ModelChoice {
  std::string path;    // empty: physics only
  std::string source;  // opt("model") (given), "default (...)", "none"
};
ModelChoice choose_model(UnrollMode mode, const std::string& given);

}  // namespace vkunroll
