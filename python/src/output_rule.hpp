// Python's writers (Sequence.create, simulate, write_events) under the output rule of every vkunroll
// writer (docs/reliability.md, "Every writer, one output rule"): staged, checked, committed; an
// existing output replaced only with overwrite=True and only when vkunroll wrote it.
#pragma once
#include <string>

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/unroll/output_file.hpp"
#include "vkunroll/host/unroll/output_folder.hpp"

namespace vkunroll::python {

// Messages name the folder the caller gave, not its staging sibling.
inline void rethrow_as_shown(const Error& e, const std::string& staging, const std::string& shown) {
  std::string m = e.what();
  for (size_t at; (at = m.find(staging)) != std::string::npos;) m.replace(at, staging.size(), shown);
  throw Error(m, e.kind());
}

// `fill(staging folder)` writes the sequence; it is loaded back (the loader's schema) and committed.
// `id`: the keyword's entry in the output table (host/unroll/output_paths.hpp).
template <class Fill>
void write_sequence_folder(const char* id, const std::string& dir, bool overwrite, Fill&& fill) {
  OutputFolder folder(dir, overwrite ? ExistingOutput::overwrite : ExistingOutput::refuse, output_path(id));
  const std::string staging = folder.staging().string();
  try {
    fill(staging);
  } catch (const Error& e) {
    rethrow_as_shown(e, staging, dir);
  }
  check_written_sequence(staging, dir);
  folder.commit();
}

// `write(temporary path)` writes the file; it is renamed over `path` when complete.
template <class Write>
void write_output_file(const char* id, const std::string& path, bool overwrite, Write&& write) {
  check_output_file_rule(path, output_path(id), overwrite ? ExistingOutput::overwrite : ExistingOutput::refuse);
  write_file_staged(path, [&](const std::string& tmp) {
    try {
      write(tmp);
    } catch (const Error& e) {
      rethrow_as_shown(e, tmp, path);
    }
  });
}

}  // namespace vkunroll::python
