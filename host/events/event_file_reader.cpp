// EventFileReader: windowed reads of one file through its index (event_index_detail.hpp).
//
// Streamed formats, on_bad error/drop: valid times never decrease, so the first segment whose
// largest valid time reaches t_begin holds the window's first event; the read resumes at that
// segment's checkpoint (restoring the decoder and time-order state a full scan would have there)
// and stops at t_end as a full scan does. A read that gets past the indexed part extends the index.
// on_bad sort: out-of-order records may fall anywhere, so every segment whose valid-time range meets
// the window is decoded, in file order (the stable sort then gives the full scan's order); the
// first sort read indexes the whole file.
#include "vkunroll/host/events/event_file_reader.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "vkunroll/host/events/event_reader_detail.hpp"
#include "vkunroll/host/events/zip_member_detail.hpp"

namespace vkunroll {

namespace detail {

struct FileReaderState {
  std::string path;
  EventReadOptions options;
  std::string format;
  bool empty = false;
  std::unique_ptr<ByteSource> src;   // every format but h5 and npz
  bool in_memory = false;            // a memory source (fuzzing): never released
  std::unique_ptr<NpzArchive> npz;   // members opened once: CRC checked, inflate index kept
  StreamIndex index;
  std::vector<int64_t> prefix_max;   // running max of the segments' t_max (for the binary search)
  EventTotals totals;
  RecordRanges seen;
  bool span_known = false;
  std::optional<std::pair<double, double>> span;

  const EventFormat* row = nullptr;  // null for an empty file
  bool streamed() const { return row && row->streamed; }
  bool reads_path() const { return row && row->read_image; }
  void sync_prefix_max() {
    for (size_t i = prefix_max.size(); i < index.segments.size(); ++i)
      prefix_max.push_back(std::max(i ? prefix_max[i - 1] : INT64_MIN, index.segments[i].t_max));
  }
};

namespace {

void run_random(FileReaderState& s, EventSink& sink) {
  if (s.row->read_image == read_npz) {  // members opened once, for every window
    if (!s.npz) s.npz = std::make_unique<NpzArchive>(s.path, nullptr, 0);
    s.npz->read(sink);
  } else if (s.row->read_image) {
    s.row->read_image(s.path, nullptr, 0, sink);
  } else {
    s.row->read_bytes(*s.src, sink);
  }
}

// error / drop: one pass from the checkpoint before the window's first event.
void read_ordered(FileReaderState& s, EventSink& sink) {
  const EventReadOptions& o = sink.options();
  const Checkpoint* from = nullptr;
  if (o.t_begin_us && s.index.tail) {
    s.sync_prefix_max();
    const auto it = std::lower_bound(s.prefix_max.begin(), s.prefix_max.end(), *o.t_begin_us);
    if (it != s.prefix_max.end()) from = &s.index.segments[size_t(it - s.prefix_max.begin())].start;
    else from = &*s.index.tail;
    if (s.index.segments.empty() || from != &s.index.segments.front().start) sink.report().stopped_early = true;
  }
  sink.use_index(&s.index, from, UINT64_MAX);
  s.row->read_bytes(*s.src, sink);
}

// sort: every segment whose valid-time range meets the window, in runs of consecutive segments.
void read_all_overlapping(FileReaderState& s, EventSink& sink) {
  const EventReadOptions& o = sink.options();
  auto meets = [&](const Segment& g) {
    return g.t_min <= g.t_max && (!o.t_begin_us || g.t_max >= *o.t_begin_us) && (!o.t_end_us || g.t_min < *o.t_end_us);
  };
  const size_t n = s.index.segments.size();
  bool read_tail = !s.index.complete, ran = false;
  for (size_t i = 0; i < n;) {
    if (!meets(s.index.segments[i])) {
      ++i;
      sink.report().stopped_early = true;
      continue;
    }
    size_t j = i;
    while (j < n && meets(s.index.segments[j])) ++j;
    const Checkpoint start = s.index.segments[i].start;
    // A run that reaches the indexed part's end goes on through the rest of the file.
    const bool to_end = j == n;
    sink.use_index(&s.index, &start, to_end ? UINT64_MAX : s.index.segments[j].start.offset);
    s.row->read_bytes(*s.src, sink);
    ran = true;
    if (to_end) read_tail = false;
    i = j;
  }
  // The rest of the file when it is not indexed yet; else, when no segment met the window, a read
  // at the end of the data still gives the header's sensor size and notes, as a full scan does.
  if (read_tail || !ran) {
    const std::optional<Checkpoint> tail = s.index.tail;
    sink.use_index(&s.index, tail ? &*tail : nullptr, UINT64_MAX);
    s.row->read_bytes(*s.src, sink);
  }
}

}  // namespace
}  // namespace detail

EventFileReader::EventFileReader(const std::string& path, const EventReadOptions& options)
    : s_(std::make_unique<detail::FileReaderState>()) {
  detail::check_event_file(path);
  s_->path = path;
  s_->options = options;
  s_->options.t_begin_us.reset();
  s_->options.t_end_us.reset();
  std::error_code ec;
  s_->empty = std::filesystem::file_size(path, ec) == 0 && !ec;
  const EventFormat* row = options.format.empty() ? nullptr : &detail::format_row(options.format, path);
  if (!row || row->read_bytes) s_->src = std::make_unique<detail::FileSource>(path);
  if (s_->empty) {
    s_->format = "empty";
    return;
  }
  if (!row) row = &detail::format_row(detail::detect_format(*s_->src, path), path);
  s_->row = row;
  s_->format = std::string(row->name);
  detail::check_topic_applies(path, s_->format, options);
}

EventFileReader::~EventFileReader() = default;
EventFileReader::EventFileReader(EventFileReader&&) noexcept = default;
EventFileReader& EventFileReader::operator=(EventFileReader&&) noexcept = default;

EventStream EventFileReader::read(std::optional<int64_t> t_begin_us, std::optional<int64_t> t_end_us,
                                  EventReadReport* report) {
  detail::FileReaderState& s = *s_;
  EventReadReport local;
  EventReadReport& rep = report ? *report : local;
  rep = EventReadReport{};
  EventReadOptions o = s.options;
  o.t_begin_us = t_begin_us;
  o.t_end_us = t_end_us;
  rep.format = s.format;
  rep.time_unit = "us";
  ++s.totals.reads;
  if (!s.src && !s.reads_path() && !s.empty) s.src = std::make_unique<detail::FileSource>(s.path);
  detail::EventSink sink(s.path, o, rep);
  sink.count_into(&s.totals, &s.seen);
  if (s.empty) {
    s.totals.empty_files = 1;
    return detail::read_empty_file(sink);
  }
  if (!s.streamed()) {
    detail::run_random(s, sink);
    if (o.on_bad == BadEventPolicy::sort && !s.span_known) {
      // A sort read decodes every record: the file's valid-time span, for skipping it later.
      const auto [lo, hi] = sink.valid_time_range();
      if (lo <= hi) s.span = std::make_pair(double(lo), double(hi));
      else s.span = std::make_pair(INFINITY, -INFINITY);  // no valid record: no window has events
      s.span_known = true;
    }
  } else if (o.on_bad == BadEventPolicy::sort) detail::read_all_overlapping(s, sink);
  else detail::read_ordered(s, sink);
  EventStream ev = sink.finish();
  s.totals.delivered += ev.size();
  return ev;
}

bool EventFileReader::may_have_events_in(int64_t t_begin_us, int64_t t_end_us) {
  detail::FileReaderState& s = *s_;
  if (s.empty) return false;
  if (s.streamed()) return true;
  if (s.options.on_bad == BadEventPolicy::sort && !s.span_known) return true;  // known after the first read
  if (!s.span_known) {
    if (!s.src && !s.reads_path()) s.src = std::make_unique<detail::FileSource>(s.path);
    EventReadReport rep;
    detail::EventSink sink(s.path, s.options, rep);
    sink.probe_time_span();
    detail::run_random(s, sink);
    const auto [first, last] = sink.probe_result();
    if (first <= last) s.span = std::make_pair(first, last);  // else unsorted or empty: no shortcut
    s.span_known = true;
  }
  if (!s.span) return true;
  if (s.span->first > s.span->second) return false;  // sort found no valid record
  return !(s.span->second < double(t_begin_us) || s.span->first >= double(t_end_us));
}

void EventFileReader::release_files() {
  if (s_->in_memory) return;
  s_->src.reset();
  s_->npz.reset();
}

EventFileReader::EventFileReader(std::unique_ptr<detail::FileReaderState> state) : s_(std::move(state)) {}

namespace detail {

EventFileReader memory_file_reader(const std::string& name, const uint8_t* data, size_t size, const std::string& format,
                                   const EventReadOptions& options) {
  auto s = std::make_unique<FileReaderState>();
  s->path = name;
  s->options = options;
  s->options.t_begin_us.reset();
  s->options.t_end_us.reset();
  s->row = &format_row(format, name);
  s->format = std::string(s->row->name);
  s->src = std::make_unique<MemorySource>(name, data, size);
  s->in_memory = true;
  if (!s->row->read_bytes)
    throw UsageError(name + ": memory readers take the formats read from a byte source, not '" + format + "'");
  return EventFileReader(std::move(s));
}

}  // namespace detail

const EventTotals& EventFileReader::totals() const { return s_->totals; }
const std::string& EventFileReader::path() const { return s_->path; }
const std::string& EventFileReader::format() const { return s_->format; }
const EventReadOptions& EventFileReader::options() const { return s_->options; }
bool EventFileReader::streamed() const { return s_->streamed(); }
size_t EventFileReader::checkpoints() const { return s_->index.segments.size(); }

}  // namespace vkunroll
