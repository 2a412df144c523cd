// The readers' common part: byte sources, the record rules (EventSink), format detection and
// the public entry points read_events / scan_events.
#include "vkunroll/host/events/event_reader.hpp"

#include <algorithm>
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

FileSource::FileSource(const std::string& path) : ByteSource(path) {
  f_ = std::fopen(path.c_str(), "rb");
  if (!f_) throw Error(path + ": cannot open event file (" + std::strerror(errno) + ")");
  if (fseeko(f_, 0, SEEK_END) != 0) {
    std::fclose(f_);
    throw Error(path + ": cannot seek (not a regular file?)");
  }
  size_ = uint64_t(ftello(f_));
}

FileSource::~FileSource() {
  if (f_) std::fclose(f_);
}

size_t FileSource::read_at(uint64_t offset, void* dst, size_t n) {
  if (offset >= size_ || n == 0) return 0;
  if (fseeko(f_, off_t(offset), SEEK_SET) != 0) throw Error(name() + ": seek to byte " + std::to_string(offset) + " failed");
  const size_t got = std::fread(dst, 1, n, f_);
  if (got < n && std::ferror(f_)) throw Error(name() + ": read error at byte " + std::to_string(offset));
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

int time_unit_exponent(const std::string& unit, const std::string& what) {
  if (unit == "s") return 6;
  if (unit == "ms") return 3;
  if (unit == "us") return 0;
  if (unit == "ns") return -3;
  throw Error(what + ": unknown time unit '" + unit + "' (expected s, ms, us or ns)");
}

// ---- the sink --------------------------------------------------------------------------------

EventSink::EventSink(const std::string& file, const EventReadOptions& options, EventReadReport& report,
                     std::function<void(const EventStream&)> on_chunk, size_t chunk_events)
    : file_(file), options_(options), report_(report), on_chunk_(std::move(on_chunk)), chunk_events_(chunk_events) {
  if (options_.width < 0 || options_.height < 0 || options_.width > 65536 || options_.height > 65536)
    throw Error(file_ + ": sensor size override " + std::to_string(options_.width) + "x" +
                std::to_string(options_.height) + " is invalid (expected 1..65536)");
  if (options_.t_begin_us && options_.t_end_us && *options_.t_end_us < *options_.t_begin_us)
    throw Error(file_ + ": time window [" + std::to_string(*options_.t_begin_us) + ", " +
                std::to_string(*options_.t_end_us) + ") ends before it begins");
  if (options_.width > 0 && options_.height > 0) {
    width_ = options_.width;
    height_ = options_.height;
    override_size_ = true;
  }
  report_.path = file_;
}

void EventSink::set_file_geometry(int width, int height, const std::string& source) {
  if (width <= 0 || height <= 0) return;
  if (width > 65536 || height > 65536)
    throw Error(file_ + ": sensor size " + std::to_string(width) + "x" + std::to_string(height) + " from " + source +
                " is invalid (at most 65536x65536)");
  if (override_size_) {
    if (width != width_ || height != height_)
      note("sensor size " + std::to_string(width) + "x" + std::to_string(height) + " from " + source +
           " overridden by the option " + std::to_string(width_) + "x" + std::to_string(height_));
    return;
  }
  width_ = width;
  height_ = height;
  note("sensor size " + std::to_string(width) + "x" + std::to_string(height) + " from " + source);
}

std::string EventSink::where() const {
  std::string s = file_ + ": record " + std::to_string(index_);
  if (line_ > 0) s += " (line " + std::to_string(line_) + ")";
  else if (byte_offset_ >= 0) s += " (byte " + std::to_string(byte_offset_) + ")";
  return s + ": ";
}

void EventSink::fail(const std::string& rule) const { throw Error(where() + rule); }

void EventSink::fail_rule(const std::string& rule) const {
  fail(rule + " (use --on-bad drop or sort, or EventReadOptions::on_bad, to drop such records and count them)");
}

void EventSink::unknown_record(const std::string& what) {
  ++report_.records;
  if (options_.on_bad == BadEventPolicy::error)
    fail(what + " (use --on-bad drop to skip and count such records)");
  ++report_.dropped_unknown_word;
  ++index_;
}

bool EventSink::add_float_time(double t_us, int64_t x, int64_t y, int64_t p) {
  if (!std::isfinite(t_us)) {
    ++report_.records;
    return reject(&EventReadReport::dropped_nan, [&] {
      return "time is " + std::string(std::isnan(t_us) ? "NaN" : "infinite") + " (rule: every time must be a finite number)";
    });
  }
  if (std::fabs(t_us) > 9.0e18) {
    ++report_.records;
    return reject(&EventReadReport::dropped_nan,
                  [&] { return "time " + std::to_string(t_us) + " us does not fit in int64 microseconds"; });
  }
  return add(std::llround(t_us), x, y, p);
}

bool EventSink::add_float(double t_us, double x, double y, double p) {
  auto integral = [](double v) { return std::isfinite(v) && v == std::floor(v) && std::fabs(v) < 1e15; };
  if (!integral(x) || !integral(y)) {
    ++report_.records;
    return reject(&EventReadReport::dropped_out_of_sensor, [&] {
      std::ostringstream os;
      os << "coordinate x=" << x << " y=" << y << " is not an integer pixel (rule: x, y integral)";
      return os.str();
    });
  }
  if (!integral(p)) {
    ++report_.records;
    return reject(&EventReadReport::dropped_bad_polarity, [&] {
      std::ostringstream os;
      os << "polarity " << p << " is not 0/1 or -1/+1";
      return os.str();
    });
  }
  return add_float_time(t_us, int64_t(x), int64_t(y), int64_t(p));
}

bool EventSink::add(int64_t t, int64_t x, int64_t y, int64_t p) {
  ++report_.records;
  int8_t pol;
  if (p == 1) pol = 1;
  else if (p == 0 || p == -1) pol = -1;
  else return reject(&EventReadReport::dropped_bad_polarity,
                     [&] { return "polarity " + std::to_string(p) + " is not one of 0/1, -1/+1, false/true"; });
  const int64_t w = width_ > 0 ? width_ : 65536, h = height_ > 0 ? height_ : 65536;
  if (x < 0 || y < 0 || x >= w || y >= h) {
    return reject(&EventReadReport::dropped_out_of_sensor, [&] {
      std::string rule = "x=" + std::to_string(x) + " y=" + std::to_string(y) + " is outside the ";
      rule += width_ > 0 ? std::to_string(width_) + "x" + std::to_string(height_) + " sensor (rule: 0 <= x < width, 0 <= y < height)"
                         : std::string("16-bit coordinate range (rule: 0 <= x, y < 65536)");
      return rule;
    });
  }
  if (have_last_ && t < last_t_) {
    if (options_.on_bad == BadEventPolicy::sort) {
      unsorted_ = true;
    } else {
      return reject(&EventReadReport::dropped_time_order, [&] {
        return "t=" + std::to_string(t) + " us is earlier than the previous record's t=" + std::to_string(last_t_) +
               " us (rule: timestamps non-decreasing)";
      });
    }
  } else {
    last_t_ = t;
    have_last_ = true;
  }
  ++index_;
  if ((options_.t_begin_us && t < *options_.t_begin_us) || (options_.t_end_us && t >= *options_.t_end_us)) {
    ++report_.outside_window;
    if (options_.t_end_us && t >= *options_.t_end_us && options_.on_bad != BadEventPolicy::sort) {
      done_ = true;
      report_.stopped_early = true;
    }
    return !done_;
  }
  max_x_ = std::max<int>(max_x_, int(x));
  max_y_ = std::max<int>(max_y_, int(y));
  out_.push(t, uint16_t(x), uint16_t(y), pol);
  ++report_.kept;
  if (on_chunk_ && options_.on_bad != BadEventPolicy::sort && out_.size() >= chunk_events_) flush_chunk();
  return true;
}

void EventSink::flush_chunk() {
  if (out_.empty()) return;
  out_.width = width_;
  out_.height = height_;
  on_chunk_(out_);
  out_.t.clear();
  out_.x.clear();
  out_.y.clear();
  out_.p.clear();
}

EventStream EventSink::finish() {
  if (unsorted_) {
    std::vector<uint32_t> order(out_.size());
    std::iota(order.begin(), order.end(), 0u);
    std::stable_sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return out_.t[a] < out_.t[b]; });
    EventStream s;
    s.reserve(order.size());
    for (uint32_t i : order) s.push(out_.t[i], out_.x[i], out_.y[i], out_.p[i]);
    out_ = std::move(s);
    report_.sorted = true;
  }
  if (!geometry_known()) {
    width_ = std::max(max_x_ + 1, 1);
    height_ = std::max(max_y_ + 1, 1);
    report_.size_inferred = true;
    note("sensor size " + std::to_string(width_) + "x" + std::to_string(height_) +
         " inferred from the largest x and y (the file does not say; pass width/height to set it)");
  }
  report_.width = width_;
  report_.height = height_;
  out_.width = width_;
  out_.height = height_;
  if (on_chunk_) {
    for (size_t i = 0; i < out_.size(); i += chunk_events_) {
      if (i == 0 && out_.size() <= chunk_events_) {
        flush_chunk();
        break;
      }
      EventStream c;
      c.width = width_;
      c.height = height_;
      const size_t e = std::min(out_.size(), i + chunk_events_);
      c.t.assign(out_.t.begin() + i, out_.t.begin() + e);
      c.x.assign(out_.x.begin() + i, out_.x.begin() + e);
      c.y.assign(out_.y.begin() + i, out_.y.begin() + e);
      c.p.assign(out_.p.begin() + i, out_.p.begin() + e);
      on_chunk_(c);
    }
    return {};
  }
  return std::move(out_);
}

// ---- detection and dispatch ------------------------------------------------------------------

namespace {
std::string lower_ext(const std::string& path) {
  std::string e = std::filesystem::path(path).extension().string();
  for (auto& c : e) c = char(std::tolower(static_cast<unsigned char>(c)));
  return e;
}
}  // namespace

std::string detect_format(ByteSource& src, const std::string& path) {
  const auto head = read_range(src, 0, 64);
  auto starts = [&](const char* magic, size_t n) { return head.size() >= n && std::memcmp(head.data(), magic, n) == 0; };
  if (starts("\x89HDF\r\n\x1a\n", 8)) return "h5";
  if (starts("\x93NUMPY", 6)) return "npy";
  if (starts("PK\x03\x04", 4) || starts("PK\x05\x06", 4)) return "npz";
  if (starts("#!AER-DAT4", 10)) return "aedat4";
  const std::string ext = lower_ext(path);
  if (ext == ".h5" || ext == ".hdf5" || ext == ".hdf") return "h5";
  if (ext == ".npy") return "npy";
  if (ext == ".npz") return "npz";
  if (ext == ".aedat4" || ext == ".aedat") return "aedat4";
  if (ext == ".txt" || ext == ".csv" || ext == ".tsv") return "txt";
  if (ext == ".dat") return "dat";
  if (ext == ".raw" || (!head.empty() && head[0] == '%')) {
    const PropheseeHeader h = parse_prophesee_header(src);
    if (h.evt == "3.0") return "evt3";
    if (h.evt == "2.0") return "evt2";
    if (h.evt.empty())
      throw Error(path + ": Prophesee header does not say the encoding (no '% evt' or '% format' line, unknown plugin);"
                         " pass --format evt2 or evt3");
    throw Error(path + ": Prophesee encoding EVT " + h.evt + " is not supported (EVT 2.0 and 3.0 are)");
  }
  throw Error(path + ": cannot tell the event format from the extension '" + ext +
              "' or the first bytes; pass --format (txt, h5, npy, npz, evt2, evt3, dat, aedat4)");
}

void read_source(const std::string& format, ByteSource& src, EventSink& sink) {
  if (format == "txt" || format == "csv") read_text(src, sink);
  else if (format == "evt2") read_evt2(src, sink);
  else if (format == "evt3") read_evt3(src, sink);
  else if (format == "dat") read_dat(src, sink);
  else if (format == "aedat4") read_aedat4(src, sink);
  else if (format == "npy") read_npy(src, sink);
  else throw Error(src.name() + ": unknown event format '" + format +
                   "' (expected txt, h5, npy, npz, evt2, evt3, dat, aedat4)");
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
  if (!std::filesystem::exists(path)) throw Error(path + ": event file does not exist");
  if (std::filesystem::is_directory(path)) throw Error(path + ": is a folder, expected an event file");
  std::string format = options.format;
  std::unique_ptr<detail::FileSource> src;
  if (format.empty() || (format != "h5" && format != "npz")) src = std::make_unique<detail::FileSource>(path);
  if (format.empty()) format = detail::detect_format(*src, path);
  if (format == "hdf5") format = "h5";
  if (format == "csv") format = "txt";
  rep.format = format;
  rep.time_unit = "us";
  detail::EventSink sink(path, options, rep, std::move(on_chunk), chunk_events);
  if (format == "h5") detail::read_hdf5(path, nullptr, 0, sink);
  else if (format == "npz") detail::read_npz(path, nullptr, 0, sink);
  else detail::read_source(format, *src, sink);
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

std::string EventReadReport::summary() const {
  std::ostringstream os;
  os << (path.empty() ? std::string("events") : path) << " [" << format << "]: " << records << " records, " << kept
     << " kept";
  if (outside_window) os << ", " << outside_window << " outside the time window";
  if (stopped_early) os << " (window read: stopped early / seeked)";
  os << "; sensor " << width << "x" << height << (size_inferred ? " (inferred)" : "");
  if (!time_unit.empty() && time_unit != "us") os << "; times read in " << time_unit;
  const uint64_t d = dropped();
  if (d) {
    os << "; dropped " << d << ":";
    if (dropped_out_of_sensor) os << " " << dropped_out_of_sensor << " out of sensor";
    if (dropped_time_order) os << " " << dropped_time_order << " out of time order";
    if (dropped_nan) os << " " << dropped_nan << " NaN/inf time";
    if (dropped_bad_polarity) os << " " << dropped_bad_polarity << " bad polarity";
    if (dropped_unknown_word) os << " " << dropped_unknown_word << " unknown word/line";
  } else {
    os << "; nothing dropped";
  }
  if (sorted) os << "; out-of-order records found and the stream was sorted by t";
  if (!ignored.empty()) {
    os << "; ignored:";
    for (const auto& [k, v] : ignored) os << " " << v << " " << k;
  }
  for (const auto& n : notes) os << "\n  note: " << n;
  return os.str();
}

}  // namespace vkunroll
