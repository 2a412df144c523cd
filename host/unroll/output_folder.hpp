// An output folder that survives faults: a run writes into a staging sibling `.<name>.partial`,
// locked against concurrent runs, and renames it into place only at the end (commit). A killed
// run leaves no final-named output; an existing output is replaced whole (never mixed with new
// files) and only when asked. Every write is checked and names the file (IoError).
//
//   OutputFolder out("/data/run1", ExistingOutput::refuse);
//   out.write("frames/a.png", bytes);   // staged: tmp + fsync + rename inside the staging folder
//   out.commit();                       // the staging folder becomes /data/run1
#pragma once
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "vkunroll/host/unroll/output_paths.hpp"

namespace vkunroll {

// What to do with an output folder that exists and is not empty.
enum class ExistingOutput {
  refuse,     // an error (UsageError naming --overwrite and --resume)
  overwrite,  // replace it at commit (it must look like a vkunroll output: see OutputFolder)
  resume,     // replace it at commit, reusing its valid GS frames and a killed run's staged ones
};
const char* existing_output_name(ExistingOutput e);

// What kind of folder an output is: the names it holds at its top (an output from before
// manifests may hold only these, and PNGs in `png_folders`), and the folders made up front.
struct OutputLayout {
  std::vector<std::string> names;
  std::vector<std::string> png_folders;
  std::vector<std::string> make;
  bool resumable = false;  // --resume applies (the refusal names it)
  // An output from before manifests is recognized by its names (unroll's); false: a folder without a
  // manifest is never replaced (a hand-written meta.json and rs/ look like a sequence's names).
  bool by_names_without_manifest = true;
};
const OutputLayout& unroll_output_layout();    // frames/, gs_video.mp4, contact_sheet.png, ...
const OutputLayout& sequence_output_layout();  // a simulated sequence: meta.json, rs/, gs/, events

class OutputFolder {
 public:
  // Creates the parent folders, takes the lock (OutputBusyError when another run holds it) and
  // prepares the staging folder: emptied, except under `resume` (a killed run's files are kept).
  // Refuses (UsageError) a final folder that exists, is not empty and `existing` is refuse, or
  // that holds, at any depth, anything vkunroll did not write there: what its manifest
  // (.vkunroll-manifest, written at commit) does not list, or for an output from before
  // manifests, anything but the output's names and PNGs in frames/ (nothing else is ever deleted).
  // `spec`: the entry of the output table (output_paths.hpp) naming the folder: its field in messages
  // (opt(): each front end spells it) and its layout, unless `layout` is given (demo's subfolders).
  OutputFolder(std::filesystem::path final_dir, ExistingOutput existing, const OutputPath& spec,
               const OutputLayout* layout = nullptr);
  // Without commit: the staging folder is removed (kept under `resume`, for the next --resume).
  ~OutputFolder();
  OutputFolder(const OutputFolder&) = delete;
  OutputFolder& operator=(const OutputFolder&) = delete;

  const std::filesystem::path& final_dir() const { return final_; }
  const std::filesystem::path& staging() const { return staging_; }
  ExistingOutput existing() const { return existing_; }
  // The final folder existed with content when the run started (it is replaced at commit).
  bool replaces_existing() const { return replaces_; }

  // Writes `rel` (a path inside the folder) completely or throws IoError naming the final path:
  // a temporary file in the same folder, checked writes, fsync, rename.
  void write(const std::string& rel, std::string_view bytes) const;
  // Appends one line to `rel` (opened once, O_APPEND; one write per line).
  void append_line(const std::string& rel, const std::string& line);
  // Brings `src` (a file of an earlier output) into the staging folder as `rel`: a hard link,
  // else a copy.
  void adopt(const std::filesystem::path& src, const std::string& rel) const;
  // Deletes what the staging folder holds beyond `keep` (relative paths; folders listed keep
  // only the files listed under them): leftovers of a killed run that this run did not list.
  void prune(const std::vector<std::string>& keep) const;
  // The final path of `rel`, for messages.
  std::string shown(const std::string& rel) const { return (final_ / rel).string(); }

  // Lists the staged files in the manifest, fsyncs, unlocks and renames the staging folder into place (atomically exchanging it with an
  // existing final folder where the filesystem can), then deletes the old one.
  void commit();

 private:
  void lock();
  void check_final();
  void clear_staging() const;
  void write_manifest() const;

  std::filesystem::path final_, staging_;
  std::string field_;
  ExistingOutput existing_;
  OutputLayout layout_;
  bool replaces_ = false;
  bool committed_ = false;
  int lock_fd_ = -1;
  int append_fd_ = -1;
  std::string append_rel_;
};


// A sequence folder a converter wrote into `staging` is loaded back with the loader's schema (and its
// first frame's events read) before it is committed: a writer never commits a folder its own loader
// refuses. DataError naming `shown` (the final folder) and the loader's complaint.
void check_written_sequence(const std::string& staging, const std::string& shown, const std::string& events_topic = {});

// The vkunroll output folder (one holding a manifest) that `path` lies inside, or "" when none: a
// file written there would make the folder hold what its manifest does not list.
std::string enclosing_output_folder(const std::string& path);

// SHA-256 of a file's bytes (hex); throws IoError naming the file.
std::string sha256_file(const std::filesystem::path& path);

}  // namespace vkunroll
