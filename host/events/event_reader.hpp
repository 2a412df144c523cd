// Event file readers: one entry point for every format users have (text/CSV, HDF5 layouts,
// NumPy .npy/.npz, Prophesee EVT 2.0 / EVT 3.0 .raw and .dat, iniVation AEDAT 4).
// Every reader checks each record (sensor bounds, time order, NaN times, polarity, unknown
// words) and either throws vkunroll::Error naming the file, record and rule, or drops/sorts
// and counts what it did in an EventReadReport. See docs/events.md.
#pragma once
#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "vkunroll/host/events/event_writer.hpp"
#include "vkunroll/base/events.hpp"

namespace vkunroll {

// What to do with a record that breaks a rule.
//   error: throw vkunroll::Error (file, record index, rule). The default.
//   drop:  drop the record and count it (out-of-sensor, NaN, bad polarity, unknown word, and a
//          time that is earlier than the last kept one).
//   sort:  keep out-of-order records and stable-sort the stream by t at the end; drop (and count)
//          only what cannot be kept (out-of-sensor, NaN, bad polarity, unknown words).
enum class BadEventPolicy { error, drop, sort };

struct EventReadOptions {
  std::optional<int64_t> t_begin_us, t_end_us;  // half-open window [begin, end) in microseconds
  BadEventPolicy on_bad = BadEventPolicy::error;
  // Sensor size when the file lacks it, or an override of the file's size (both > 0 to apply).
  // When neither the file nor these give a size, it is inferred as max(x)+1, max(y)+1 and the
  // report says so.
  int width = 0, height = 0;
  // Text/CSV: column order, a permutation of "txyp" (extra columns: '_' skips one, e.g. "tx_yp").
  std::string text_columns = "txyp";
  // Time unit of text files: "s", "ms", "us", "ns". Empty: auto (see docs/events.md): seconds when
  // the file has E2VID's "W H" first line or a time token with more than 3 decimals in the first
  // 1000 records; microseconds otherwise.
  std::string text_time_unit;
  // Time unit of floating-point time arrays in .npy/.npz/.h5 ("s","ms","us","ns"; default "us").
  // Integer time arrays are always microseconds.
  std::string array_time_unit;
  // Empty: detect from the file's magic bytes, header and extension. Else one of
  // "txt","h5","npy","npz","evt2","evt3","dat","aedat4".
  std::string format;
};

struct EventReadReport {
  std::string format;   // the format that was read, e.g. "evt3", "h5:dsec", "npz:record"
  std::string path;
  uint64_t records = 0; // event records decoded (inside or outside the window)
  uint64_t kept = 0;    // events in the returned stream
  uint64_t outside_window = 0;  // valid records outside [t_begin, t_end) (not an error)
  uint64_t dropped_out_of_sensor = 0, dropped_time_order = 0, dropped_nan = 0,
           dropped_unknown_word = 0, dropped_bad_polarity = 0;
  bool sorted = false;          // on_bad=sort found out-of-order records and sorted the stream
  bool size_inferred = false;   // width/height came from max(x)+1, max(y)+1
  bool stopped_early = false;   // the reader stopped at t_end or seeked to t_begin (window read)
  int width = 0, height = 0;
  std::string time_unit;        // unit the file's times were read in ("us" for binary formats)
  std::map<std::string, uint64_t> ignored;  // records of other kinds that were skipped, e.g. "EXT_TRIGGER"
  std::vector<std::string> notes;           // what the reader chose (layout, geometry source, ...)

  uint64_t dropped() const {
    return dropped_out_of_sensor + dropped_time_order + dropped_nan + dropped_unknown_word + dropped_bad_polarity;
  }
  std::string summary() const;  // one paragraph for humans: counts, drops, ignored, notes
};

// Reads the whole file (or the window) into memory. Throws vkunroll::Error on any problem.
EventStream read_events(const std::string& path, const EventReadOptions& options = {},
                        EventReadReport* report = nullptr);

// Streams the file in time order in chunks of about `chunk_events` events (bounded memory for
// hour-long recordings; with on_bad=sort the whole stream is buffered first). Each chunk carries
// the sensor size when known (0 while it is being inferred). Returns the number of events delivered.
uint64_t scan_events(const std::string& path, const EventReadOptions& options,
                     const std::function<void(const EventStream& chunk)>& on_chunk,
                     EventReadReport* report = nullptr, size_t chunk_events = size_t(1) << 20);

// The format read_events would use for `path` ("txt","h5","npy","npz","evt2","evt3","dat","aedat4").
std::string detect_event_format(const std::string& path);

// DRE-style HDF5 image timestamps (`image_ts`, `start_image_ts`, `end_image_ts`, microseconds);
// a missing dataset stays empty. Throws when the file has none of the three.
struct ImageTimestamps {
  std::vector<double> image_ts, start_image_ts, end_image_ts;
};
ImageTimestamps read_image_timestamps(const std::string& h5_path);

// An integer index dataset of an HDF5 event file, e.g. Gev-RS `img_to_idx` or DSEC `ms_to_idx`.
std::vector<int64_t> read_event_index(const std::string& h5_path, const std::string& dataset);

}  // namespace vkunroll
