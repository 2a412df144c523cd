#include "vkunroll/host/unroll/output_paths.hpp"

#include <stdexcept>

#include "vkunroll/host/unroll/output_folder.hpp"

namespace vkunroll {

namespace {

const OutputLayout* unroll_layout() { return &unroll_output_layout(); }
const OutputLayout* sequence_layout() { return &sequence_output_layout(); }

}  // namespace

const std::vector<OutputPath>& output_paths() {
  using S = OutputShape;
  using M = OutputMark;
  static const std::vector<OutputPath> table = {
      {"unroll.out", "cli", "unroll", "out", "--out", S::folder, M::manifest, unroll_layout,
       "output folder: frames/, gs_video.mp4, contact_sheet.png, metrics.csv, frames.jsonl, summary.json "
       "(written into .<name>.partial and renamed into place at the end)"},
      {"unroll.trace", "cli", "unroll", "trace", "--trace", S::file, M::trace, nullptr,
       "Vulkan: write the run's timeline to FILE.json (Chrome trace-event format: open it in ui.perfetto.dev "
       "or chrome://tracing): host stages, and every GPU dispatch with its op, shape, algorithm and GFLOP/s; "
       "an existing FILE is replaced only with --overwrite or --resume and only when it is a vkunroll trace"},
      {"voxelize.out", "cli", "voxelize", "out", "--out", S::file, M::written_by, nullptr,
       "the safetensors file to write (written under a temporary name, renamed when complete)"},
      {"infer.out", "cli", "infer", "out", "--out", S::file, M::written_by, nullptr, "the safetensors file to write"},
      {"simulate.out", "cli", "simulate", "out", "--out", S::folder, M::manifest, sequence_layout, "output folder (created)"},
      {"demo.out", "cli", "demo", "out", "--out", S::folder, M::manifest, nullptr,
       "output folder: sequence/, physics/ and model/ (each replaced whole, only when vkunroll wrote it)"},
      {"bag-sequence.out", "cli", "bag-sequence", "bag_sequence_out", "OUT", S::folder, M::manifest, sequence_layout,
       "the sequence folder to write"},
      {"tune.table", "env", "tune", "cache_dir", "VKUNROLL_CACHE_DIR", S::file, M::conv_table, nullptr,
       "the cache folder of this device's conv choice table (conv-choices-<uuid>-<driver>.tsv)"},
      {"Sequence.create.path", "python", "Sequence.create", "path", "path", S::folder, M::manifest, sequence_layout, ""},
      {"simulate.path", "python", "simulate", "path", "path", S::folder, M::manifest, sequence_layout, ""},
      {"write_events.path", "python", "write_events", "path", "path", S::file, M::written_by, nullptr, ""},
  };
  return table;
}

const OutputPath& output_path(std::string_view id) {
  for (const OutputPath& p : output_paths())
    if (id == p.id) return p;
  throw std::logic_error("output path '" + std::string(id) + "' is not declared in host/unroll/output_paths.cpp");
}

}  // namespace vkunroll
