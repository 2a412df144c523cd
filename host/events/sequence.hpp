// A recording: RS frames with their row timing, optional ground truth, and the event file(s).
// Reads the project's generic layout (meta.json, sequence-format.md) and the reference datasets'
// layouts (Gev-RS, Gev-RS-Real, DRE, Fastec-RS; selfunroll-network.md section 4), detected from
// the folder or named explicitly. How each layout's timing is derived: docs/event_tensors.md.
#pragma once
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "vkunroll/host/events/event_reader.hpp"
#include "vkunroll/base/events.hpp"
#include "vkunroll/base/row_timing.hpp"

namespace vkunroll {

enum class SequenceLayout { automatic, generic, gev_rs, gev_rs_real, dre, fastec };
const char* sequence_layout_name(SequenceLayout l);           // "generic", "gev-rs", ...
SequenceLayout parse_sequence_layout(const std::string& s);   // also "auto"; throws Error

struct SequenceOptions {
  SequenceLayout layout = SequenceLayout::automatic;
  // Timing overrides (applied after the layout's own timing, to every frame).
  std::optional<Rational> line_delay_us, exposure_us;
  std::optional<Readout> readout;
  std::optional<std::vector<Rational>> t0s_us;  // one per frame (exactly as many as frames)
  // Gev-RS: the half-row variant (row step 100 us, exposure 8 GS frames).
  bool gev_half_row = false;
  // Gev-RS-Real: frame period; default inferred (see docs). Fastec: GS frames between RS frames.
  std::optional<Rational> frame_period_us;
  int fastec_frame_step_gs = 260;
  // Passed to the event reader (bad-record policy, format, ...); sensor size is set by the loader.
  EventReadOptions events;
  // Replaces the layout's event file(s) by this one.
  std::optional<std::string> events_file;
  // Read every frame's image header and check its size against the sensor.
  bool check_frame_sizes = true;
};

struct SequenceFrame {
  std::string image;  // absolute or root-relative path as found
  RowTiming timing;
};

struct SequenceGroundTruth {
  std::string image;
  Rational t_us;
};

class SequenceEventReaders;  // the sequence's open event files and their indexes (sequence_events.cpp)

struct Sequence {
  std::string root;
  SequenceLayout layout = SequenceLayout::generic;
  int width = 0, height = 0;
  std::vector<SequenceFrame> frames;
  std::vector<SequenceGroundTruth> ground_truth;
  std::vector<std::string> event_files;  // one file, or Fastec's per-frame files in order
  EventReadOptions event_options;        // what read_events passes to the reader
  std::vector<std::string> notes;        // how the timing was derived, for the user
  std::vector<std::string> warnings;     // legal but implausible meta.json values, unknown fields (meta_schema.hpp)

  // Events with t in [t_begin_us, t_end_us): exactly what a full scan of the file(s) gives. The
  // first read opens each event file once (EventFileReader) and indexes what it decodes; later
  // reads seek. `report` covers this read only (records decoded, kept, dropped by reason, ...).
  // Copies of a Sequence share the open files; concurrent reads are serialized.
  EventStream read_events(int64_t t_begin_us, int64_t t_end_us, EventReadReport* report = nullptr) const;
  // What all reads so far decoded, each record counted once however many windows covered it: for
  // the unroll summary ("11110 of 22219 records dropped (out of time order)", "no event records").
  EventTotals event_totals() const;
  // Decodes what no read has decoded yet of each streamed event file (windows stop at their end), so
  // the record rules hold over the whole stream: a backward time jump after the last window is an
  // error (on_bad error) or dropped and counted (drop), as a full scan has it. Keeps no event.
  void read_events_to_end() const;
  const SequenceFrame& frame(int index) const;  // throws Error naming the index and the count

 private:
  static std::shared_ptr<SequenceEventReaders> make_event_readers();
  std::shared_ptr<SequenceEventReaders> event_readers_ = make_event_readers();  // never null
};

// Throws Error naming the file and field on a missing or malformed sequence.
Sequence load_sequence(const std::string& path, const SequenceOptions& options = {});
// The layout of a folder: generic when it has meta.json, else a reference dataset only when the
// folder is unambiguously that dataset (its event file holds that dataset's layout; see
// docs/events.md, "Sequence layouts"). Anything else is an Error naming the folder, what it holds
// and how to choose a layout (--layout, SequenceOptions::layout).
SequenceLayout detect_sequence_layout(const std::string& path);

// Width and height of a PNG (IHDR) or any image OpenCV reads; throws Error naming the file.
std::pair<int, int> image_size(const std::string& path);

}  // namespace vkunroll
