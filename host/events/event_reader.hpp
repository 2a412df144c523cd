// Event file readers: one entry point for every format of the table in event_formats.hpp (text/CSV,
// HDF5 layouts, NumPy, Prophesee, AEDAT, ROS 1 bags).
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
  // Empty: detect from the file's signature, then its extension. Else a name (or alias) of the
  // format table, event_formats() (event_formats.hpp).
  std::string format;
  // ROS bags: the topic to read. Empty: the bag's only topic of an event type (an error names them
  // when there are several).
  std::string events_topic;
};

// What one read decoded and what it did with each record. Every record decoded has exactly one
// outcome: kept, outside_window or one of the dropped_* reasons; records = their sum.
struct ReadStats {
  uint64_t records = 0; // event records decoded (inside or outside the window)
  uint64_t kept = 0;    // events in the returned stream
  uint64_t outside_window = 0;  // valid records outside [t_begin, t_end) (not an error)
  uint64_t dropped_out_of_sensor = 0, dropped_time_order = 0, dropped_nan = 0,
           dropped_unknown_word = 0, dropped_bad_polarity = 0;
  // on_bad=sort: valid records earlier than a record before them in the file (kept, then moved by
  // the sort). Always 0 under error/drop (there such a record is an error or dropped_time_order).
  uint64_t reordered = 0;

  uint64_t dropped() const {
    return dropped_out_of_sensor + dropped_time_order + dropped_nan + dropped_unknown_word + dropped_bad_polarity;
  }
  ReadStats& operator+=(const ReadStats& o);
};

struct EventReadReport : ReadStats {
  std::string format;   // the format that was read, e.g. "evt3", "h5:dsec", "npz:record"
  std::string path;
  bool sorted = false;          // on_bad=sort found out-of-order records and sorted the stream
  bool size_inferred = false;   // width/height came from max(x)+1, max(y)+1
  bool stopped_early = false;   // the reader stopped at t_end or seeked to t_begin (window read)
  bool empty_file = false;      // the file has 0 bytes: an empty stream, records = 0
  int width = 0, height = 0;
  std::string time_unit;        // unit the file's times were read in ("us" for binary formats)
  std::map<std::string, uint64_t> ignored;  // records of other kinds that were skipped, e.g. "EXT_TRIGGER"
  std::vector<std::string> notes;           // what the reader chose (layout, geometry source, ...)
  // The file declares a sensor size other than the one given (meta.json, width/height): said as a
  // warning by unroll, online and offline, and refused by bag-sequence. Empty: they agree.
  std::string size_disagreement;

  std::string summary() const;  // one paragraph for humans: counts, drops, ignored, notes
};

// What all windowed reads of one file (EventFileReader) or of a sequence's files met so far, each
// record counted once however many windows covered it (windows of neighbouring frames overlap).
struct EventTotals {
  uint64_t reads = 0;      // windowed reads
  uint64_t delivered = 0;  // events returned, summed over the reads (an event in two windows counts twice)
  uint64_t records = 0;    // distinct records decoded
  uint64_t valid = 0;      // distinct records that broke no rule (kept by a window or outside all of them)
  uint64_t dropped_out_of_sensor = 0, dropped_time_order = 0, dropped_nan = 0,
           dropped_unknown_word = 0, dropped_bad_polarity = 0;
  uint64_t reordered = 0;  // distinct valid records out of file order (on_bad=sort)
  uint64_t empty_files = 0;  // event files of 0 bytes among those read
  std::string size_disagreement;  // the first read's EventReadReport::size_disagreement

  uint64_t dropped() const {
    return dropped_out_of_sensor + dropped_time_order + dropped_nan + dropped_unknown_word + dropped_bad_polarity;
  }
  EventTotals& operator+=(const EventTotals& o);
  // "22219 records decoded, 11110 dropped (11110 out of time order), ..." or "no event records".
  std::string summary() const;
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

// Why a text column order is refused ("must name each of t, x, y, p exactly once ...", "has 'q'
// (allowed: ...)"), or "" when it is valid: the one rule of the reader, the CLI and Python.
std::string text_columns_problem(const std::string& order);

// The format read_events would use for `path`: a name of event_formats() (event_formats.hpp).
std::string detect_event_format(const std::string& path);

// "a FIFO", "a character device", "a block device" or "a socket" for such a path, else "" (a
// regular file, a folder, nothing): inputs that could block a read for ever are refused by name.
std::string special_file_kind(const std::string& path);

// DRE-style HDF5 image timestamps (`image_ts`, `start_image_ts`, `end_image_ts`, microseconds);
// a missing dataset stays empty. Throws when the file has none of the three.
struct ImageTimestamps {
  std::vector<double> image_ts, start_image_ts, end_image_ts;
};
ImageTimestamps read_image_timestamps(const std::string& h5_path);

// The layout read_events finds in an HDF5 file: "events" (the project's events/{t,x,y,p}), "dsec",
// "gevrs" (N x 4 'events' + 'img_to_idx'), "v2e" (N x 4 'events'), "dre" (top-level x, y, p, t), or
// "" when it holds no event datasets. Throws Error when the file is not HDF5.
std::string hdf5_event_layout(const std::string& h5_path);

// An integer index dataset of an HDF5 event file, e.g. Gev-RS `img_to_idx` or DSEC `ms_to_idx`.
std::vector<int64_t> read_event_index(const std::string& h5_path, const std::string& dataset);

}  // namespace vkunroll
