// Internals shared by the event readers: byte sources (file or memory, so the fuzzers can feed
// bytes without touching the disk), and the EventSink that applies the record rules, the time
// window and the bad-event policy for every format in one place.
#pragma once
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "vkunroll/host/events/event_file_reader.hpp"
#include "vkunroll/host/events/event_formats.hpp"
#include "vkunroll/host/events/event_index_detail.hpp"
#include "vkunroll/host/events/event_reader.hpp"
#include "vkunroll/base/error.hpp"

namespace vkunroll::detail {

// Random-access bytes. read_at returns fewer bytes than asked only at the end of the data.
class ByteSource {
 public:
  explicit ByteSource(std::string name) : name_(std::move(name)) {}
  virtual ~ByteSource() = default;
  virtual uint64_t size() const = 0;
  virtual size_t read_at(uint64_t offset, void* dst, size_t n) = 0;
  // False for sources that are cheap only when read front to back (compressed zip members).
  virtual bool seekable() const { return true; }
  const std::string& name() const { return name_; }

 private:
  std::string name_;
};

class FileSource final : public ByteSource {
 public:
  explicit FileSource(const std::string& path);
  ~FileSource() override;
  uint64_t size() const override { return size_; }
  size_t read_at(uint64_t offset, void* dst, size_t n) override;

 private:
  std::FILE* f_ = nullptr;
  uint64_t size_ = 0;
};

class MemorySource final : public ByteSource {
 public:
  MemorySource(std::string name, const uint8_t* data, size_t size) : ByteSource(std::move(name)), data_(data), size_(size) {}
  MemorySource(std::string name, std::vector<uint8_t> owned)
      : ByteSource(std::move(name)), owned_(std::move(owned)), data_(owned_.data()), size_(owned_.size()) {}
  uint64_t size() const override { return size_; }
  size_t read_at(uint64_t offset, void* dst, size_t n) override;

 private:
  std::vector<uint8_t> owned_;
  const uint8_t* data_;
  size_t size_;
};

// Reads everything of a source (for small headers and the fuzzers' sanity checks).
std::vector<uint8_t> read_range(ByteSource& src, uint64_t offset, size_t n);

// Text header lines of a binary file, read in 1 MiB blocks (headers with preference dumps are
// large; one read per line would be quadratic). line() gives the line at `offset` without its
// "\n" (and "\r"), or false when the data ends before a "\n" or the line is longer than 64 KiB.
class HeaderLines {
 public:
  explicit HeaderLines(ByteSource& src) : src_(src) {}
  bool line(uint64_t offset, std::string& out, uint64_t& next) {
    for (int pass = 0; pass < 2; ++pass) {
      if (offset >= base_ && offset <= base_ + buf_.size()) {
        const auto b = buf_.begin() + long(offset - base_);
        const auto nl = std::find(b, buf_.end(), uint8_t('\n'));
        if (nl != buf_.end() && nl - b <= (1 << 16)) {
          out.assign(b, nl);
          if (!out.empty() && out.back() == '\r') out.pop_back();
          next = base_ + uint64_t(nl - buf_.begin()) + 1;
          return true;
        }
        if (nl - b > (1 << 16) || base_ + buf_.size() >= src_.size()) return false;
      }
      base_ = offset;  // sized to the data: a short file does not pay for a 1 MiB buffer
      buf_ = read_range(src_, offset, size_t(std::min<uint64_t>(1 << 20, src_.size() - std::min(src_.size(), offset))));
    }
    return false;
  }

 private:
  ByteSource& src_;
  uint64_t base_ = 0;
  std::vector<uint8_t> buf_;
};

// Applies the rules to each decoded record, in file order, and collects the kept events.
// Event times stay where int64 windows and float64 arithmetic are exact, as frame times do
// (sequence.cpp): |t| <= 2^53 us, about 285 years; Unix-time microseconds today are about 1.7e15.
constexpr int64_t kMaxEventTimeUs = int64_t(1) << 53;
constexpr const char* kEventTimeRule =
    "is beyond +-2^53 us (rule: |t| <= 9007199254740992 us, about 285 years, so that windows and float64 times stay exact)";

class EventSink {
 public:
  EventSink(const std::string& file, const EventReadOptions& options, EventReadReport& report,
            std::function<void(const EventStream&)> on_chunk = nullptr, size_t chunk_events = 0);
  ~EventSink();
  EventSink(const EventSink&) = delete;
  EventSink& operator=(const EventSink&) = delete;

  // Sensor size found in the file (0 = unknown); options' width/height win when both are set.
  void set_file_geometry(int width, int height, const std::string& source);
  bool geometry_known() const { return width_ > 0 && height_ > 0; }
  int width() const { return width_; }
  int height() const { return height_; }

  // Where the next record lives, for messages: its index in the file and (binary formats) byte offset.
  void set_record_index(uint64_t index) { index_ = index; }
  void set_byte_offset(int64_t offset) { byte_offset_ = offset; }
  void set_line(uint64_t line) { line_ = line; }

  // One record: t in microseconds; p raw (0/1, -1/+1, bool). Returns false once reading can stop
  // (a valid record at or after t_end with a policy other than sort).
  bool add(int64_t t_us, int64_t x, int64_t y, int64_t p);
  // A record whose time is a float in microseconds (NaN/inf checked, rounded to the nearest us).
  bool add_float_time(double t_us, int64_t x, int64_t y, int64_t p);
  // A record whose coordinates are floats (checked to be integral and finite).
  bool add_float(double t_us, double x, double y, double p);
  // A record whose time cannot be used (beyond int64 us, ...): counted with NaN times.
  template <class Message>
  bool bad_time(Message&& what) {
    return reject(Outcome::nan, what);
  }
  // A word/line/record the reader does not understand: error, or counted as dropped_unknown_word.
  // `what` is a string or a callable returning one (built only when it becomes an error).
  void unknown_record(const std::string& what);
  template <class Message>
  void unknown_record_lazy(Message&& what) {
    if (options_.on_bad == BadEventPolicy::error) unknown_record(what());
    tally(Outcome::unknown_word, false);
    ++index_;
  }
  // A record of another kind the reader skips on purpose (trigger, IMU, ...): counted only.
  void ignored(const std::string& kind, uint64_t n = 1) { report_.ignored[kind] += n; }
  void note(const std::string& text);  // a note once (repeated notes of resumed reads are merged)

  // The reader's count of records it is about to decode: reserves memory (whole-file reads only,
  // at most 16M events) so the arrays do not grow by copying.
  void expect_records(uint64_t n) {
    if (!on_chunk_ && !options_.t_begin_us && !options_.t_end_us) out_.reserve(size_t(std::min<uint64_t>(n, 1u << 24)));
  }
  bool done() const { return done_; }
  const EventReadOptions& options() const { return options_; }
  EventReadReport& report() { return report_; }
  const std::string& file() const { return file_; }

  // ---- reads through a StreamIndex (EventFileReader; see event_index_detail.hpp) ----
  // Streamed readers start at `from` (nullptr: the data start), call boundary() at their start and
  // at every checkpoint offset, stop when boundary() returns false, and call end_of_data() when
  // they reach the end. Without an index they read from the start and never checkpoint.
  void use_index(StreamIndex* index, const Checkpoint* from, uint64_t stop_offset);
  bool indexing() const { return index_map_ != nullptr; }
  StreamIndex* index() const { return index_map_; }
  const Checkpoint* resume_point() const { return from_ ? &*from_ : nullptr; }
  // Restores the record index and time-order state of a checkpoint the reader resumes at.
  void resume(const Checkpoint& c);
  // The reader is at a record boundary; `c` holds its offset, next record index and decoder state
  // (the sink adds its own). Returns false when the reader must stop here.
  bool boundary(Checkpoint c);
  void end_of_data(Checkpoint c);
  // First offset of the next checkpoint after `offset` (UINT64_MAX when not indexing).
  uint64_t next_checkpoint(uint64_t offset, uint64_t base) const {
    return indexing() ? next_checkpoint_offset(offset, base) : UINT64_MAX;
  }
  // Also count every record into `totals`, once per record index (`seen` remembers which).
  void count_into(EventTotals* totals, RecordRanges* seen) { totals_ = totals, seen_ = seen; }
  // Random-access readers: report the t of the first and last row and stop (EventFileReader uses it
  // to skip files whose span misses a window).
  void probe_time_span() { probe_ = true; }
  bool probing() const { return probe_; }
  void probed(double t_first_us, double t_last_us) { probe_first_ = t_first_us, probe_last_ = t_last_us; }
  std::pair<double, double> probe_result() const { return {probe_first_, probe_last_}; }
  // Smallest and largest time of the valid records since the last checkpoint (of the whole read
  // for the random-access formats, which have none); min > max when there were none.
  std::pair<int64_t, int64_t> valid_time_range() const { return {seg_min_, seg_max_}; }

  // Flush, sort (policy sort), infer the size when unknown. Returns the kept stream (empty when
  // chunks were delivered to on_chunk).
  EventStream finish();

  // "file: record N (byte B): " prefix for errors.
  std::string where() const;
  [[noreturn]] void fail(const std::string& rule) const;

 private:
  enum class Outcome { kept, outside_window, out_of_sensor, time_order, nan, unknown_word, bad_polarity };
  // Error (the rule's message is built only then) or count and drop.
  template <class Rule>
  bool reject(Outcome outcome, Rule&& rule) {
    if (options_.on_bad == BadEventPolicy::error) fail_rule(rule());
    tally(outcome, false);
    ++index_;
    return !done_;
  }
  [[noreturn]] void fail_rule(const std::string& rule) const;
  void tally(Outcome outcome, bool reordered);
  void count_distinct(Outcome outcome, bool reordered);
  void merge_seen();
  void flush_chunk();

  std::string file_;
  EventReadOptions options_;
  EventReadReport& report_;
  std::function<void(const EventStream&)> on_chunk_;
  size_t chunk_events_;
  EventStream out_;
  int width_ = 0, height_ = 0;
  bool override_size_ = false;
  uint64_t index_ = 0;
  int64_t byte_offset_ = -1;
  uint64_t line_ = 0;
  bool have_last_ = false;
  int64_t last_t_ = 0;
  bool unsorted_ = false;
  bool done_ = false;
  int max_x_ = -1, max_y_ = -1;
  // index building
  StreamIndex* index_map_ = nullptr;
  std::optional<Checkpoint> from_;  // a copy: the index's vector may grow during the read
  uint64_t stop_ = UINT64_MAX;
  std::optional<Checkpoint> open_;  // start of the segment being built
  int64_t seg_min_ = INT64_MAX, seg_max_ = INT64_MIN;
  // distinct counting
  EventTotals* totals_ = nullptr;
  RecordRanges* seen_ = nullptr;
  size_t seen_cursor_ = 0;
  std::vector<std::pair<uint64_t, uint64_t>> runs_;  // record ranges this read decoded
  bool probe_ = false;
  double probe_first_ = 0, probe_last_ = 0;
};

// Where a packet reader (AEDAT 3.1, AEDAT 4) starts: a resumed read's checkpoint (offset, record),
// else `start` and record 0.
inline uint64_t packet_start(EventSink& sink, uint64_t start, uint64_t& record) {
  record = 0;
  const Checkpoint* c = sink.resume_point();
  if (!c) return start;
  record = c->record;
  sink.resume(*c);
  return c->offset;
}
inline Checkpoint packet_checkpoint(uint64_t offset, uint64_t record) {
  Checkpoint c;
  c.offset = offset, c.record = record;
  return c;
}

// Where a streamed word reader starts: a checkpoint (resumed read, its decoder state loaded) or
// the data start.
template <class State>
uint64_t start_words(EventSink& sink, uint64_t data_offset, State& st, uint64_t& record) {
  const Checkpoint* c = sink.resume_point();
  if (!c) return data_offset;
  st.load(*c);
  record = c->record;
  sink.resume(*c);
  return c->offset;
}

// A checkpoint at `offset` with the decoder state `st` (its save()).
template <class State>
Checkpoint checkpoint_at(uint64_t offset, uint64_t record, const State& st) {
  Checkpoint c;
  c.offset = offset;
  c.record = record;
  st.save(c);
  return c;
}

// A 32-bit microsecond clock that wraps after 71.6 minutes (.dat, AEDAT 2.0): a time that falls by
// more than half the range is the next wrap (jAER reads them as int32: the same unwrapping).
struct Wrap32Clock {
  uint64_t loop = 0;
  uint32_t prev = 0;
  bool have_prev = false;
  void save(Checkpoint& c) const { c.state = {int64_t(loop), int64_t(prev), have_prev}; }
  void load(const Checkpoint& c) { loop = uint64_t(c.state[0]), prev = uint32_t(c.state[1]), have_prev = c.state[2] != 0; }
  int64_t time(uint32_t ts) {
    if (have_prev && ts < prev && prev - ts > (1u << 31)) loop += uint64_t(1) << 32;
    prev = ts;
    have_prev = true;
    return int64_t(loop + ts);
  }
};

// The sensor size of an iniVation camera named in a header line (jAER's AEChip / HardwareInterface,
// libcaer's '#Source N: DAVIS346B'): letters and digits, any case; false for a name it does not know.
bool sensor_size_from_device_name(const std::string& name, int& w, int& h);

// Time unit name -> microseconds per unit as a power of ten exponent: s 6, ms 3, us 0, ns -3.
int time_unit_exponent(const std::string& unit, const std::string& what);

// The readers. Each reads the whole source (or stops at sink.done()).
void read_text(ByteSource& src, EventSink& sink);
void read_evt2(ByteSource& src, EventSink& sink);
void read_evt3(ByteSource& src, EventSink& sink);
void read_dat(ByteSource& src, EventSink& sink);
void read_aedat4(ByteSource& src, EventSink& sink);
void read_rosbag(ByteSource& src, EventSink& sink);  // ROS 1 bag 2.0 (reader_rosbag.cpp)
void read_evt21(ByteSource& src, EventSink& sink);   // Prophesee EVT 2.1 (64-bit vectorized words)
void read_aedat2(ByteSource& src, EventSink& sink);  // jAER AEDAT 2.0, DAVIS address layout
void read_aedat3(ByteSource& src, EventSink& sink);  // AEDAT 3.1 packets (libcaer / cAER)
void read_npy(ByteSource& src, EventSink& sink);
// .npz from a file path, or from memory when `data` is non-null (fuzzing).
void read_npz(const std::string& path, const uint8_t* data, size_t size, EventSink& sink);
// HDF5 from a path, or from an in-memory file image when `image` is non-null (fuzzing).
void read_hdf5(const std::string& path, const void* image, size_t image_size, EventSink& sink);

// Prophesee '%' header lines: key/value pairs, the byte where binary data starts.
struct PropheseeHeader {
  std::vector<std::pair<std::string, std::string>> lines;
  uint64_t data_offset = 0;
  int width = 0, height = 0;
  std::string geometry_source;
  std::string evt;  // "2.0", "3.0", "2.1" or "" when the header does not say
  // EVT 2.1 byte order: "% format EVT21;endianness=legacy" (IMX636: the 64-bit word's high 32-bit
  // half first) rather than one little-endian 64-bit word (OpenEB's default "EVT21").
  bool evt21_legacy = false;
};
PropheseeHeader parse_prophesee_header(ByteSource& src);
// Whether a '%' header line (without its '\n') is the header's last, "% end": '%', spaces, "end",
// an optional '\r'. The live decoder and the file readers share it, so they agree where data begins.
bool is_prophesee_header_end(std::string_view line);

// What a binary file that was taken for text looks like, from its magic bytes or '%' header:
// format "evt3", extension ".raw", description "a Prophesee EVT 3.0 recording (...)"; format empty
// when nothing matches.
struct BinaryGuess {
  std::string format, extension, description;
};
BinaryGuess guess_binary_format(ByteSource& src);

// Format of a source from its magic bytes/header and the file name's extension (the table's
// signatures and extensions, event_formats.cpp).
std::string detect_format(ByteSource& src, const std::string& path);

// The table's row of `format` (a name or alias); an unknown one is an OptionError naming `path`.
const EventFormat& format_row(const std::string& format, const std::string& path);
// Throws Error when `path` does not exist or is a folder.
void check_event_file(const std::string& path);
// A ROS bag topic given for a file that is not a bag is refused (UsageError naming the topic and the
// file): an option that does not apply is never ignored.
void check_topic_applies(const std::string& path, const std::string& format, const EventReadOptions& o);
// A 0-byte event file: an empty stream, the report says so (empty_file, records 0).
EventStream read_empty_file(EventSink& sink);

// An EventFileReader over bytes in memory (a streamed format or npy; the index fuzzer uses it).
// `data` must outlive the reader.
EventFileReader memory_file_reader(const std::string& name, const uint8_t* data, size_t size, const std::string& format,
                                   const EventReadOptions& options);

// Reads `src` with the given (already detected) format's byte-source reader; the fuzzers call this.
void read_source(const std::string& format, ByteSource& src, EventSink& sink);

}  // namespace vkunroll::detail
