// Every option, keyword or environment variable that names an output path, declared once (issue
// 58): the CLI declares its options from this table (add_output_option), the writers take their
// rule from it (OutputFolder, check_output_file_rule), and tests/test_output_paths.cpp and
// tests/python/test_output_paths.py try every entry against every case of the rule. A writer names
// its entry by id; output_path() throws for an id the table lacks, so a writer under the rule is
// in the table, and a table entry without a case in those tests fails them.
//
// The rule (docs/reliability.md, "Every writer, one output rule"): written staged and renamed into
// place; an empty name is a usage error; never over a symbolic link, a device, a FIFO or a socket;
// never over an input of the run; a file never inside another vkunroll output folder or the run's
// own; an existing output replaced only when asked and only when vkunroll wrote it (its mark).
#pragma once
#include <string>
#include <string_view>
#include <vector>

namespace vkunroll {

struct OutputLayout;

enum class OutputShape { file, folder };

// How an existing output at the path is recognized as vkunroll's own (only then is it replaced).
enum class OutputMark {
  written_by,  // a safetensors __metadata__ written_by, an HDF5 root attribute, the text event header
  trace,       // a Chrome trace whose process vkunroll named
  conv_table,  // a conv choice table's first line
  manifest,    // a folder's .vkunroll-manifest (or an output from before manifests: its names)
};

struct OutputPath {
  const char* id;         // "<command>.<name>", unique: "unroll.trace", "write_events.path"
  const char* front_end;  // "cli", "python" or "env" (an environment variable of a CLI command)
  const char* command;    // the CLI subcommand or the Python function
  const char* field;      // the library field messages name with opt() (each front end spells it)
  const char* spelled;    // as the front end spells it: "--trace", "OUT", "path", "VKUNROLL_CACHE_DIR"
  OutputShape shape;
  OutputMark mark;
  const OutputLayout* (*layout)();  // a folder's layout (nullptr: a file, or a folder of folders)
  const char* help;       // the CLI's help text of the option
};

// The table, in the order the help and the tests list it.
const std::vector<OutputPath>& output_paths();
// The entry `id` (std::logic_error when there is none: a writer must be declared in the table).
const OutputPath& output_path(std::string_view id);

}  // namespace vkunroll
