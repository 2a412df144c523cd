// The output rule for a single file, the twin of OutputFolder's for folders (docs/reliability.md,
// "Every writer, one output rule"): `infer --out`, `voxelize --out`, Python's write_events. An
// existing file is replaced only when asked (--overwrite, overwrite=True) and only when vkunroll
// wrote it (its mark: `written_by` in a safetensors file's __metadata__, an HDF5 root attribute,
// the text event header); never an input of the run. The writers stage the file (temporary name,
// rename when complete).
#pragma once
#include <string>
#include <utility>
#include <vector>

#include "vkunroll/host/unroll/output_folder.hpp"

namespace vkunroll {

// The __metadata__ key and value prefix a safetensors file vkunroll wrote carries.
constexpr const char* kSafetensorsWrittenBy = "written_by";
constexpr const char* kWrittenByVkunroll = "vkunroll";

// True when `path` carries vkunroll's mark (see above).
bool written_by_vkunroll(const std::string& path);

// Refuses (an OptionError naming `field`) an output file that is an input (`inputs`: what, path), that
// exists and is not a regular file, or that exists while `existing` is refuse, or without
// vkunroll's mark (the message names the overwrite option as each front end spells it).
void check_output_file_rule(const std::string& path, const std::string& field, ExistingOutput existing,
                            const std::vector<std::pair<std::string, std::string>>& inputs = {});

// Writes `path` through `write_to(temporary path)` and renames it into place (the temporary file is
// removed on failure): a killed run never leaves a torn file under the final name.
template <class Write>
void write_file_staged(const std::string& path, Write&& write_to);
std::string staged_file_name(const std::string& path);
void commit_staged_file(const std::string& tmp, const std::string& path);
void discard_staged_file(const std::string& tmp);

template <class Write>
void write_file_staged(const std::string& path, Write&& write_to) {
  const std::string tmp = staged_file_name(path);
  try {
    write_to(tmp);
  } catch (...) {
    discard_staged_file(tmp);
    throw;
  }
  commit_staged_file(tmp, path);
}

}  // namespace vkunroll
