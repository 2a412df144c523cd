// The output rule for a single file, the twin of OutputFolder's for folders (docs/reliability.md,
// "Every writer, one output rule"), for every file entry of the output table (output_paths.hpp):
// `infer --out`, `voxelize --out`, `unroll --trace`, tune's table, Python's write_events. An
// existing file is replaced only when asked (--overwrite, overwrite=True) and only when vkunroll
// wrote it (its mark, OutputMark); never an input of the run, a link, a device or FIFO, nor a file
// inside a vkunroll output folder. The writers stage the file (temporary name, rename when complete).
#pragma once
#include <string>
#include <utility>
#include <vector>

#include "vkunroll/host/unroll/output_folder.hpp"
#include "vkunroll/host/unroll/output_paths.hpp"

namespace vkunroll {

// The __metadata__ key and value prefix a safetensors file vkunroll wrote carries.
constexpr const char* kSafetensorsWrittenBy = "written_by";
constexpr const char* kWrittenByVkunroll = "vkunroll";

// True when `path` carries vkunroll's mark of that kind (see OutputMark).
bool written_by_vkunroll(const std::string& path, OutputMark mark = OutputMark::written_by);

// Refuses (an OptionError of kind usage naming `spec`'s field) an output file that is empty, an
// input (`inputs`: what, path), a symbolic link, exists and is not a regular file, lies inside a
// vkunroll output folder (one with a manifest), or exists while `existing` is refuse, or without
// `spec`'s mark (the message names the overwrite option as each front end spells it).
void check_output_file_rule(const std::string& path, const OutputPath& spec, ExistingOutput existing,
                            const std::vector<std::pair<std::string, std::string>>& inputs = {});

// The folder of the output file `path` takes a new file: it is created when missing, and a probe
// file is created in it and removed, before any work (IoError naming opt(field), the folder and the
// errno: a read-only folder, a file where the folder should be, a full disk).
void check_output_folder_writable(const std::string& path, const std::string& field);

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
