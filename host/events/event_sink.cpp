// The EventSink: the record rules, the time window and the bad-event policy for every format in
// one place; the outcome counters (ReadStats, EventTotals); the index checkpoints of streamed reads.
#include <algorithm>
#include <cmath>
#include <numeric>
#include <sstream>

#include "vkunroll/host/events/event_reader_detail.hpp"

namespace vkunroll::detail {

void RecordRanges::add(uint64_t lo, uint64_t hi) {
  if (lo >= hi) return;
  auto it = std::lower_bound(r_.begin(), r_.end(), std::make_pair(lo, uint64_t(0)));
  if (it != r_.begin() && std::prev(it)->second >= lo) --it;
  auto end = it;
  while (end != r_.end() && end->first <= hi) {
    lo = std::min(lo, end->first);
    hi = std::max(hi, end->second);
    ++end;
  }
  it = r_.erase(it, end);
  r_.insert(it, {lo, hi});
}

EventSink::EventSink(const std::string& file, const EventReadOptions& options, EventReadReport& report,
                     std::function<void(const EventStream&)> on_chunk, size_t chunk_events)
    : file_(file), options_(options), report_(report), on_chunk_(std::move(on_chunk)), chunk_events_(chunk_events) {
  if (options_.width < 0 || options_.height < 0 || options_.width > 65536 || options_.height > 65536)
    throw UsageError(file_ + ": sensor size override " + std::to_string(options_.width) + "x" +
                std::to_string(options_.height) + " is invalid (expected 1..65536)");
  if (options_.t_begin_us && options_.t_end_us && *options_.t_end_us < *options_.t_begin_us)
    throw UsageError(file_ + ": time window [" + std::to_string(*options_.t_begin_us) + ", " +
                std::to_string(*options_.t_end_us) + ") us ends before it begins (t_end_us < t_begin_us)");
  if (options_.width > 0 && options_.height > 0) {
    width_ = options_.width;
    height_ = options_.height;
    override_size_ = true;
  }
  report_.path = file_;
}

EventSink::~EventSink() { merge_seen(); }

void EventSink::note(const std::string& text) {
  if (std::find(report_.notes.begin(), report_.notes.end(), text) == report_.notes.end()) report_.notes.push_back(text);
}

void EventSink::set_file_geometry(int width, int height, const std::string& source) {
  if (width <= 0 || height <= 0) return;
  if (width > 65536 || height > 65536)
    throw DataError(file_ + ": sensor size " + std::to_string(width) + "x" + std::to_string(height) + " from " + source +
                " is invalid (at most 65536x65536)");
  if (override_size_) {
    if (width != width_ || height != height_) {
      const std::string said = "sensor size " + std::to_string(width) + "x" + std::to_string(height) + " from " + source +
                               " differs from the size given (meta.json or the width/height option), " +
                               std::to_string(width_) + "x" + std::to_string(height_) + ", which is used";
      note(said);
      if (report_.size_disagreement.empty()) report_.size_disagreement = file_ + ": " + said;
      if (totals_ && totals_->size_disagreement.empty()) totals_->size_disagreement = file_ + ": " + said;
    }
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

void EventSink::fail(const std::string& rule) const { throw DataError(where() + rule); }

void EventSink::fail_rule(const std::string& rule) const {
  fail(rule + " (use " + opt("on_bad") + " drop or sort, or EventReadOptions::on_bad, to drop such records and count them)");
}

void EventSink::unknown_record(const std::string& what) {
  if (options_.on_bad == BadEventPolicy::error)
    fail(what + " (use " + opt("on_bad") + " drop to skip and count such records)");
  tally(Outcome::unknown_word, false);
  ++index_;
}

// ---- counting ----------------------------------------------------------------------------------

void EventSink::tally(Outcome outcome, bool reordered) {
  ++report_.records;
  switch (outcome) {
    case Outcome::kept: ++report_.kept; break;
    case Outcome::outside_window: ++report_.outside_window; break;
    case Outcome::out_of_sensor: ++report_.dropped_out_of_sensor; break;
    case Outcome::time_order: ++report_.dropped_time_order; break;
    case Outcome::nan: ++report_.dropped_nan; break;
    case Outcome::unknown_word: ++report_.dropped_unknown_word; break;
    case Outcome::bad_polarity: ++report_.dropped_bad_polarity; break;
  }
  if (reordered) ++report_.reordered;
  if (totals_) count_distinct(outcome, reordered);
}

// Counts the record at index_ into the totals unless an earlier read counted it.
void EventSink::count_distinct(Outcome outcome, bool reordered) {
  const uint64_t r = index_;
  if (!runs_.empty() && runs_.back().second == r) ++runs_.back().second;
  else runs_.push_back({r, r + 1});
  const auto& seen = seen_->ranges();
  while (seen_cursor_ < seen.size() && seen[seen_cursor_].second <= r) ++seen_cursor_;
  if (seen_cursor_ < seen.size() && seen[seen_cursor_].first <= r) return;  // counted before
  EventTotals& t = *totals_;
  ++t.records;
  switch (outcome) {
    case Outcome::kept:
    case Outcome::outside_window: ++t.valid; break;
    case Outcome::out_of_sensor: ++t.dropped_out_of_sensor; break;
    case Outcome::time_order: ++t.dropped_time_order; break;
    case Outcome::nan: ++t.dropped_nan; break;
    case Outcome::unknown_word: ++t.dropped_unknown_word; break;
    case Outcome::bad_polarity: ++t.dropped_bad_polarity; break;
  }
  if (reordered) ++t.reordered;
}

void EventSink::merge_seen() {
  if (!seen_) return;
  for (const auto& [lo, hi] : runs_) seen_->add(lo, hi);
  runs_.clear();
  seen_cursor_ = 0;
}

// ---- the rules ---------------------------------------------------------------------------------

bool EventSink::add_float_time(double t_us, int64_t x, int64_t y, int64_t p) {
  if (!std::isfinite(t_us)) {
    return reject(Outcome::nan, [&] {
      return "time is " + std::string(std::isnan(t_us) ? "NaN" : t_us > 0 ? "+infinity" : "-infinity") +
             " (rule: every time must be a finite number)";
    });
  }
  if (std::fabs(t_us) > double(kMaxEventTimeUs)) {
    return reject(Outcome::nan, [&] {
      std::ostringstream os;
      os.precision(17);
      os << "time " << t_us << " us " << kEventTimeRule;
      return os.str();
    });
  }
  return add(std::llround(t_us), x, y, p);
}

bool EventSink::add_float(double t_us, double x, double y, double p) {
  auto integral = [](double v) { return std::isfinite(v) && v == std::floor(v) && std::fabs(v) < 1e15; };
  if (!integral(x) || !integral(y)) {
    return reject(Outcome::out_of_sensor, [&] {
      std::ostringstream os;
      os << "coordinate x=" << x << " y=" << y << " is not an integer pixel (rule: x, y integral)";
      return os.str();
    });
  }
  if (!integral(p)) {
    return reject(Outcome::bad_polarity, [&] {
      std::ostringstream os;
      os << "polarity " << p << " is not 0/1 or -1/+1";
      return os.str();
    });
  }
  return add_float_time(t_us, int64_t(x), int64_t(y), int64_t(p));
}

bool EventSink::add(int64_t t, int64_t x, int64_t y, int64_t p) {
  int8_t pol;
  if (p == 1) pol = 1;
  else if (p == 0 || p == -1) pol = -1;
  else return reject(Outcome::bad_polarity,
                     [&] { return "polarity " + std::to_string(p) + " is not one of 0/1, -1/+1, false/true"; });
  // One time rule for every reader (HDF5 took INT64_MAX, text refused it; INT64_MIN overflowed spans).
  if (t > kMaxEventTimeUs || t < -kMaxEventTimeUs)
    return reject(Outcome::nan, [&] { return "time " + std::to_string(t) + " us " + kEventTimeRule; });
  const int64_t w = width_ > 0 ? width_ : 65536, h = height_ > 0 ? height_ : 65536;
  if (x < 0 || y < 0 || x >= w || y >= h) {
    return reject(Outcome::out_of_sensor, [&] {
      std::string rule = "x=" + std::to_string(x) + " y=" + std::to_string(y) + " is outside the ";
      rule += width_ > 0 ? std::to_string(width_) + "x" + std::to_string(height_) + " sensor (rule: 0 <= x < width, 0 <= y < height)"
                         : std::string("16-bit coordinate range (rule: 0 <= x, y < 65536)");
      return rule;
    });
  }
  bool reordered = false;
  if (have_last_ && t < last_t_) {
    if (options_.on_bad != BadEventPolicy::sort) {
      return reject(Outcome::time_order, [&] {
        return "t=" + std::to_string(t) + " us is earlier than the previous record's t=" + std::to_string(last_t_) +
               " us (rule: timestamps non-decreasing)";
      });
    }
    unsorted_ = true;
    reordered = true;
  } else {
    last_t_ = t;
    have_last_ = true;
  }
  seg_min_ = std::min(seg_min_, t);
  seg_max_ = std::max(seg_max_, t);
  if ((options_.t_begin_us && t < *options_.t_begin_us) || (options_.t_end_us && t >= *options_.t_end_us)) {
    tally(Outcome::outside_window, reordered);
    ++index_;
    if (options_.t_end_us && t >= *options_.t_end_us && options_.on_bad != BadEventPolicy::sort) {
      done_ = true;
      report_.stopped_early = true;
    }
    return !done_;
  }
  tally(Outcome::kept, reordered);
  ++index_;
  max_x_ = std::max<int>(max_x_, int(x));
  max_y_ = std::max<int>(max_y_, int(y));
  out_.push(t, uint16_t(x), uint16_t(y), pol);
  if (on_chunk_ && options_.on_bad != BadEventPolicy::sort && out_.size() >= chunk_events_) flush_chunk();
  return true;
}

// ---- the index ---------------------------------------------------------------------------------

void EventSink::use_index(StreamIndex* index, const Checkpoint* from, uint64_t stop_offset) {
  index_map_ = index;
  from_.reset();
  if (from) from_ = *from;
  stop_ = stop_offset;
  open_.reset();
}

void EventSink::resume(const Checkpoint& c) {
  index_ = c.record;
  have_last_ = c.have_last;
  last_t_ = c.last_t;
}

bool EventSink::boundary(Checkpoint c) {
  if (!index_map_) return true;
  if (c.offset >= stop_) return false;
  c.have_last = have_last_;
  c.last_t = last_t_;
  StreamIndex& ix = *index_map_;
  if (open_) {
    ix.segments.push_back({*open_, seg_min_, seg_max_});
    ix.tail = c;
  } else if (!ix.tail) {
    ix.tail = c;  // the data start of a file read for the first time
  }
  // A segment is built only from the tail on: the part before it is indexed already.
  if (!ix.complete && ix.tail && ix.tail->offset == c.offset && ix.tail->record == c.record) open_ = c;
  else open_.reset();
  seg_min_ = INT64_MAX;
  seg_max_ = INT64_MIN;
  return true;
}

void EventSink::end_of_data(Checkpoint c) {
  if (!index_map_) return;
  StreamIndex& ix = *index_map_;
  c.have_last = have_last_;
  c.last_t = last_t_;
  if (open_) {
    ix.segments.push_back({*open_, seg_min_, seg_max_});
    ix.tail = c;
    open_.reset();
  }
  if (ix.tail && ix.tail->offset == c.offset) ix.complete = true;
}

// ---- the end -----------------------------------------------------------------------------------

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
  merge_seen();
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
  if (!geometry_known() && max_x_ < 0) {
    // Nothing to infer from: the size stays unknown (0x0) rather than a made-up 1x1.
    note("no events: the sensor size is unknown (the file does not say; pass width/height to set it)");
  } else if (!geometry_known()) {
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

}  // namespace vkunroll::detail
