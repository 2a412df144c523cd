// Windowed reads of one event file, many times: the first read indexes what it decodes and later
// reads seek. Streamed formats (text, EVT 2.0/2.1/3.0, .dat, AEDAT 2/3/4, ROS bags) keep decoder checkpoints every
// ~32 KiB; .npy, .npz (stored or deflated, through an inflate index) and HDF5 are read by binary
// search on t. Every read returns exactly what read_events(path, options with the window) returns
// from a full scan. Sequence::read_events reads through one of these per event file.
#pragma once
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "vkunroll/host/events/event_reader.hpp"

namespace vkunroll {

namespace detail {
struct FileReaderState;
}

class EventFileReader {
 public:
  // `options`' window is ignored (each read gives its own). Throws Error for a missing file or an
  // unknown format; the file is detected and opened here, read lazily.
  EventFileReader(const std::string& path, const EventReadOptions& options);
  ~EventFileReader();
  EventFileReader(EventFileReader&&) noexcept;
  EventFileReader& operator=(EventFileReader&&) noexcept;

  // Events with t in [t_begin_us, t_end_us) (either side open when nullopt). `report` describes
  // this read only: its counters cover the records this read decoded.
  EventStream read(std::optional<int64_t> t_begin_us, std::optional<int64_t> t_end_us,
                   EventReadReport* report = nullptr);

  // False only when a read of [t_begin_us, t_end_us) certainly returns no events: a .npy/.npz/HDF5
  // file (on_bad error or drop, whose reads binary-search t) whose first and last rows' times both
  // lie outside the window. Sequence::read_events uses it to skip per-frame files.
  bool may_have_events_in(int64_t t_begin_us, int64_t t_end_us);
  // Closes the file handles (a sequence of many per-frame files stays under the descriptor limit);
  // the index and totals stay, the next read reopens the file (an .npz re-checks its CRCs).
  void release_files();

  // Every record the reads so far decoded, each counted once.
  const EventTotals& totals() const;
  const std::string& path() const;
  const std::string& format() const;    // as detect_event_format, or the forced one
  const EventReadOptions& options() const;
  // A format read in file order (text, EVT, .dat, AEDAT, bags): windows stop at their end.
  bool streamed() const;
  // Checkpoints of the streamed formats' index so far (0 for random-access formats).
  size_t checkpoints() const;

  // For detail::memory_file_reader (the fuzzers read bytes from memory).
  explicit EventFileReader(std::unique_ptr<detail::FileReaderState> state);

 private:
  std::unique_ptr<detail::FileReaderState> s_;
};

}  // namespace vkunroll
