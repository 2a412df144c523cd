// The readers' common part: byte sources, the record rules (EventSink), format detection and
// the public entry points read_events / scan_events.
#include "vkunroll/host/events/event_reader.hpp"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <numeric>
#include <sstream>

#include "vkunroll/host/events/event_reader_detail.hpp"

namespace vkunroll {

namespace detail {

// ---- byte sources ----------------------------------------------------------------------------

// The one rule for special files, before anything opens them (opening a FIFO blocks until a
// writer comes): every reader's and detection's file goes through it.
void refuse_special_file(const std::string& path) {
  if (const std::string kind = special_file_kind(path); !kind.empty())
    throw DataError(path + ": is " + kind + ", expected an event file (a regular file: reading " + kind + " could block for ever)");
}

FileSource::FileSource(const std::string& path) : ByteSource(path) {
  refuse_special_file(path);
  f_ = std::fopen(path.c_str(), "rb");
  if (!f_) throw Error(path + ": cannot open event file (" + std::strerror(errno) + ")", errno == ENOENT ? ErrorKind::input_missing : ErrorKind::io);
  if (fseeko(f_, 0, SEEK_END) != 0) {
    std::fclose(f_);
    throw IoError(path + ": cannot seek (not a regular file?)");
  }
  size_ = uint64_t(ftello(f_));
}

FileSource::~FileSource() {
  if (f_) std::fclose(f_);
}

size_t FileSource::read_at(uint64_t offset, void* dst, size_t n) {
  if (offset >= size_ || n == 0) return 0;
  if (fseeko(f_, off_t(offset), SEEK_SET) != 0) throw IoError(name() + ": seek to byte " + std::to_string(offset) + " failed");
  const size_t got = std::fread(dst, 1, n, f_);
  if (got < n && std::ferror(f_)) throw IoError(name() + ": read error at byte " + std::to_string(offset));
  return got;
}

size_t MemorySource::read_at(uint64_t offset, void* dst, size_t n) {
  if (offset >= size_) return 0;
  const size_t k = size_t(std::min<uint64_t>(n, size_ - offset));
  if (k) std::memcpy(dst, data_ + offset, k);
  return k;
}

std::vector<uint8_t> read_range(ByteSource& src, uint64_t offset, size_t n) {
  std::vector<uint8_t> buf(n);
  buf.resize(src.read_at(offset, buf.data(), n));
  return buf;
}

bool sensor_size_from_device_name(const std::string& name, int& w, int& h) {
  std::string n;
  for (char c : name)
    if (std::isalnum(static_cast<unsigned char>(c))) n += char(std::tolower(static_cast<unsigned char>(c)));
  static const struct {
    const char* key;
    int w, h;
  } kChips[] = {{"davis346", 346, 260}, {"davi346", 346, 260}, {"davis240", 240, 180}, {"davis640", 640, 480},
                {"davis128", 128, 128}, {"davis208", 208, 192}, {"dvs128", 128, 128},   {"dvxplorerlite", 320, 240},
                {"dvxplorer", 640, 480}};
  for (const auto& c : kChips)
    if (n.find(c.key) != std::string::npos) {
      w = c.w, h = c.h;
      return true;
    }
  return false;
}

int time_unit_exponent(const std::string& unit, const std::string& what) {
  if (unit == "s") return 6;
  if (unit == "ms") return 3;
  if (unit == "us") return 0;
  if (unit == "ns") return -3;
  throw UsageError(what + ": unknown time unit '" + unit + "' (expected s, ms, us or ns)");
}

// ---- the empty file, the checks before a read -------------------------------------------

EventStream read_empty_file(EventSink& sink) {
  EventReadReport& rep = sink.report();
  rep.format = "empty";
  rep.time_unit = "us";
  rep.empty_file = true;
  sink.note("the event file is empty (0 bytes): no events");
  return sink.finish();
}

void check_event_file(const std::string& path) {
  std::error_code ec;
  const auto st = std::filesystem::status(path, ec);
  if (!std::filesystem::exists(st)) throw InputMissingError(path + ": event file does not exist");
  if (std::filesystem::is_directory(st)) throw DataError(path + ": is a folder, expected an event file");
  refuse_special_file(path);
}

}  // namespace detail

std::string special_file_kind(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  switch (fs::status(path, ec).type()) {
    case fs::file_type::fifo: return "a FIFO";
    case fs::file_type::character: return "a character device";
    case fs::file_type::block: return "a block device";
    case fs::file_type::socket: return "a socket";
    default: return "";
  }
}

namespace detail {

namespace {

// Which reading options apply to which (canonical) formats; every other format refuses them.
struct FormatOption {
  const char* field;                       // the option (EventReadOptions' field, as opt() names it)
  std::string EventReadOptions::*value;    // given when neither empty nor `unset`
  std::vector<std::string_view> formats;   // where it applies
  const char* kind;                        // what such a file is, said in the refusal
  const char* applies_to;
  const char* unset = "";                  // the value that means "not given" (text_columns' default)
};

const std::vector<FormatOption> kFormatOptions = {
    {"events_topic", &EventReadOptions::events_topic, {"bag"}, "a ROS bag", "a topic applies to bags only"},
    {"columns", &EventReadOptions::text_columns, {"txt"}, "a text file", "a column order applies to text and CSV files only",
     "txyp"},
    {"time_unit", &EventReadOptions::text_time_unit, {"txt"}, "a text file",
     "a text time unit applies to text and CSV files only (a binary format carries its own unit)"},
    {"array_time_unit", &EventReadOptions::array_time_unit, {"npy", "npz", "h5"}, "a file of time arrays",
     "an array time unit applies to float time arrays in .npy, .npz and .h5 files only"},
};

}  // namespace

// (Declared as check_topic_applies: the topic was its first row; every option of the table is checked.)
void check_topic_applies(const std::string& path, const std::string& format, const EventReadOptions& o) {
  for (const FormatOption& f : kFormatOptions) {
    const std::string& v = o.*f.value;
    if (v.empty() || v == f.unset || std::find(f.formats.begin(), f.formats.end(), format) != f.formats.end()) continue;
    const bool topic = f.field == std::string_view("events_topic");
    const std::string what = topic ? "events topic '" + v + "' (" + opt(f.field) + " or meta.json's events_topic)"
                                   : opt(f.field) + " '" + v + "'";
    throw OptionError(f.field, v, std::string(f.kind) + " to apply to",
                      what + ": " + path + " is " + format + ", not " + f.kind + "; " + f.applies_to + " (leave it out)");
  }
}

}  // namespace detail

std::string detect_event_format(const std::string& path) {
  detail::FileSource src(path);
  return detail::detect_format(src, path);
}

namespace {

EventStream run_reader(const std::string& path, const EventReadOptions& options, EventReadReport* report,
                       std::function<void(const EventStream&)> on_chunk, size_t chunk_events) {
  EventReadReport local;
  EventReadReport& rep = report ? *report : local;
  rep = EventReadReport{};
  detail::check_event_file(path);
  std::string format = options.format;
  std::error_code ec;
  if (std::filesystem::file_size(path, ec) == 0 && !ec) {
    detail::EventSink sink(path, options, rep, std::move(on_chunk), chunk_events);
    return detail::read_empty_file(sink);
  }
  std::unique_ptr<detail::FileSource> src;
  const EventFormat* row = format.empty() ? nullptr : &detail::format_row(format, path);
  if (!row || row->read_bytes) src = std::make_unique<detail::FileSource>(path);
  if (!row) row = &detail::format_row(detail::detect_format(*src, path), path);
  format = std::string(row->name);
  detail::check_topic_applies(path, format, options);
  rep.format = format;
  rep.time_unit = "us";
  detail::EventSink sink(path, options, rep, std::move(on_chunk), chunk_events);
  if (row->read_image) row->read_image(path, nullptr, 0, sink);
  else row->read_bytes(*src, sink);
  return sink.finish();
}

}  // namespace

EventStream read_events(const std::string& path, const EventReadOptions& options, EventReadReport* report) {
  return run_reader(path, options, report, nullptr, 0);
}

uint64_t scan_events(const std::string& path, const EventReadOptions& options,
                     const std::function<void(const EventStream&)>& on_chunk, EventReadReport* report,
                     size_t chunk_events) {
  uint64_t n = 0;
  run_reader(path, options, report, [&](const EventStream& c) { n += c.size(); on_chunk(c); },
             std::max<size_t>(chunk_events, 1));
  return n;
}

ReadStats& ReadStats::operator+=(const ReadStats& o) {
  records += o.records;
  kept += o.kept;
  outside_window += o.outside_window;
  dropped_out_of_sensor += o.dropped_out_of_sensor;
  dropped_time_order += o.dropped_time_order;
  dropped_nan += o.dropped_nan;
  dropped_unknown_word += o.dropped_unknown_word;
  dropped_bad_polarity += o.dropped_bad_polarity;
  reordered += o.reordered;
  return *this;
}

EventTotals& EventTotals::operator+=(const EventTotals& o) {
  reads += o.reads;
  delivered += o.delivered;
  records += o.records;
  valid += o.valid;
  dropped_out_of_sensor += o.dropped_out_of_sensor;
  dropped_time_order += o.dropped_time_order;
  dropped_nan += o.dropped_nan;
  dropped_unknown_word += o.dropped_unknown_word;
  dropped_bad_polarity += o.dropped_bad_polarity;
  reordered += o.reordered;
  empty_files += o.empty_files;
  if (size_disagreement.empty()) size_disagreement = o.size_disagreement;
  return *this;
}

namespace {

void drop_reasons(std::ostream& os, uint64_t sensor, uint64_t order, uint64_t nan, uint64_t polarity, uint64_t unknown) {
  const char* sep = "";
  auto part = [&](uint64_t n, const char* what) {
    if (n) os << sep << n << " " << what, sep = ", ";
  };
  part(sensor, "out of sensor");
  part(order, "out of time order");
  part(nan, "NaN/inf time");
  part(polarity, "bad polarity");
  part(unknown, "unknown word/line");
}

}  // namespace

std::string EventTotals::summary() const {
  std::ostringstream os;
  if (records == 0) {
    os << "no event records" << (empty_files ? " (the event file is empty: 0 bytes)" : "") << " in " << reads
       << " windowed reads";
    return os.str();
  }
  os << records << " records decoded, " << valid << " valid, " << dropped() << " dropped";
  if (dropped()) {
    os << " (";
    drop_reasons(os, dropped_out_of_sensor, dropped_time_order, dropped_nan, dropped_bad_polarity, dropped_unknown_word);
    os << ")";
  }
  if (reordered) os << ", " << reordered << " reordered by the sort";
  os << "; " << reads << " windowed reads delivered " << delivered << " events";
  return os.str();
}

std::string EventReadReport::summary() const {
  std::ostringstream os;
  os << (path.empty() ? std::string("events") : path) << " [" << format << "]: " << records << " records, " << kept
     << " kept";
  if (empty_file) os << " (the file is empty: 0 bytes)";
  if (outside_window) os << ", " << outside_window << " outside the time window";
  if (stopped_early) os << " (window read: stopped early / seeked)";
  os << "; sensor " << width << "x" << height << (size_inferred ? " (inferred)" : "");
  if (!time_unit.empty() && time_unit != "us") os << "; times read in " << time_unit;
  const uint64_t d = dropped();
  if (d) {
    os << "; dropped " << d << ": ";
    drop_reasons(os, dropped_out_of_sensor, dropped_time_order, dropped_nan, dropped_bad_polarity, dropped_unknown_word);
  } else {
    os << "; nothing dropped";
  }
  if (sorted) os << "; out-of-order records found and the stream was sorted by t (" << reordered << " reordered)";
  if (!ignored.empty()) {
    os << "; ignored:";
    for (const auto& [k, v] : ignored) os << " " << v << " " << k;
  }
  for (const auto& n : notes) os << "\n  note: " << n;
  return os.str();
}

}  // namespace vkunroll
