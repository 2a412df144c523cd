#include "vkunroll/host/unroll/default_model.hpp"

#include <dlfcn.h>

#include <cstdlib>
#include <filesystem>

#include "vkunroll/base/env.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/base/log.hpp"

namespace vkunroll {

namespace fs = std::filesystem;

namespace {

// The file (executable or shared module) that holds this code: the anchor for installed paths.
fs::path binary_dir() {
  Dl_info info{};
  std::error_code ec;
  if (dladdr(reinterpret_cast<void*>(&find_default_model), &info) && info.dli_fname && *info.dli_fname) {
    const fs::path p = fs::weakly_canonical(info.dli_fname, ec);
    if (!ec && fs::is_regular_file(p, ec)) return p.parent_path();
  }
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  return ec ? fs::path() : exe.parent_path();
}

// Where models are looked for, in order (after VKUNROLL_MODEL): installed beside the binary, in the
// install prefix, the source tree.
std::vector<std::pair<fs::path, std::string>> model_places() {
  std::vector<std::pair<fs::path, std::string>> places;
  if (const fs::path dir = binary_dir(); !dir.empty()) {
    places.emplace_back(dir / ".." / "share" / "vkunroll" / "models", "installed");
    places.emplace_back(dir / ".." / ".." / ".." / ".." / "share" / "vkunroll" / "models", "installed");
  }
  places.emplace_back(fs::path(VKUNROLL_INSTALL_DATADIR) / "vkunroll" / "models", "installed");
  places.emplace_back(fs::path(VKUNROLL_SOURCE_DIR) / "models", "source tree");
  return places;
}

}  // namespace

std::vector<std::string> conv_table_dirs() {
  if (const std::optional<std::string> d = env::text("VKUNROLL_CONV_TABLES")) return {*d};
  std::vector<std::string> dirs;
  for (const auto& [dir, source] : model_places()) dirs.push_back((dir / "conv_choices").lexically_normal().string());
  return dirs;
}

DefaultModelSearch find_default_model() {
  DefaultModelSearch r;
  if (const std::optional<std::string> m = env::text("VKUNROLL_MODEL")) {
    std::error_code ec;
    if (!fs::is_regular_file(*m, ec))
      throw UsageError("VKUNROLL_MODEL=" + *m + ": no such model file (unset it to use the shipped default)");
    return {*m, "VKUNROLL_MODEL", {"VKUNROLL_MODEL=" + *m}};
  }
  for (const auto& [dir, source] : model_places()) {
    std::error_code ec;
    const fs::path file = fs::weakly_canonical(dir / kDefaultModelFile, ec);
    r.searched.push_back((ec ? dir / kDefaultModelFile : file).string());
    if (!ec && fs::is_regular_file(file, ec)) {
      r.path = file.string();
      r.source = source;
      return r;
    }
  }
  return r;
}

ModelChoice choose_model(UnrollMode mode, const std::string& given) {
  if (mode == UnrollMode::physics) return {"", "none"};
  if (!given.empty()) return {given, opt("model")};
  const DefaultModelSearch d = find_default_model();
  if (!d.path.empty()) return {d.path, "default (" + d.source + ")"};
  std::string where;
  for (const std::string& s : d.searched) where += (where.empty() ? "" : ", ") + s;
  if (mode != UnrollMode::automatic)
    throw OptionError("mode", unroll_mode_name(mode), "needs a model",
                      opt("mode") + " " + unroll_mode_name(mode) + " needs a model: no " + opt("model") +
                          " given and no default model found (looked for " + where + ")");
  log_info("unroll: no model file found (looked for " + where + "): running the physics unroller (" + opt("mode") + " physics)");
  return {"", "none"};
}

}  // namespace vkunroll
