// Sequence::read_events: one EventFileReader per event file, opened on the first read and kept,
// so every later window seeks through the file's index instead of re-parsing it.
#include <algorithm>
#include <cstdint>
#include <list>
#include <mutex>
#include <numeric>

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/events/event_file_reader.hpp"
#include "vkunroll/host/events/sequence.hpp"

namespace vkunroll {

namespace {

constexpr size_t kMaxOpenFiles = 32;  // per-frame files (Fastec) kept open at once

bool same_options(const EventReadOptions& a, const EventReadOptions& b) {
  return a.on_bad == b.on_bad && a.width == b.width && a.height == b.height && a.text_columns == b.text_columns &&
         a.text_time_unit == b.text_time_unit && a.array_time_unit == b.array_time_unit && a.format == b.format;
}

}  // namespace

class SequenceEventReaders {
 public:
  std::mutex mutex;
  std::vector<std::string> files;
  EventReadOptions options;
  std::vector<std::unique_ptr<EventFileReader>> readers;  // null until first read
  std::list<size_t> open;                                 // readers with open files, most recent first
  EventTotals retired;                                    // totals of readers replaced after an option change
  uint64_t windows = 0, delivered = 0;                    // Sequence::read_events calls, events they returned

  EventFileReader& reader(size_t i) {
    if (!readers[i]) readers[i] = std::make_unique<EventFileReader>(files[i], options);
    open.remove(i);
    open.push_front(i);
    while (open.size() > kMaxOpenFiles) {
      readers[open.back()]->release_files();
      open.pop_back();
    }
    return *readers[i];
  }

  // The files or options of the Sequence changed (it is a plain struct): start over.
  void sync(const std::vector<std::string>& f, const EventReadOptions& o) {
    if (f == files && same_options(o, options)) return;
    for (const auto& r : readers)
      if (r) retired += r->totals();
    files = f;
    options = o;
    readers.clear();
    readers.resize(files.size());
    open.clear();
  }
  EventStream& count(EventStream& ev) {
    ++windows;
    delivered += ev.size();
    return ev;
  }
};

std::shared_ptr<SequenceEventReaders> Sequence::make_event_readers() { return std::make_shared<SequenceEventReaders>(); }

EventStream Sequence::read_events(int64_t t_begin_us, int64_t t_end_us, EventReadReport* report) const {
  if (!event_readers_) throw InternalError(root + ": read_events on a Sequence that was moved from");
  SequenceEventReaders& c = *event_readers_;
  std::lock_guard<std::mutex> lock(c.mutex);
  c.sync(event_files, event_options);
  if (event_files.empty()) throw DataError(root + ": the sequence has no event file");
  if (event_files.size() == 1) {
    EventStream ev = c.reader(0).read(t_begin_us, t_end_us, report);
    ev.width = width;
    ev.height = height;
    return std::move(c.count(ev));
  }
  // Fastec: per-frame files, merged in time order; files whose rows all lie outside are skipped.
  EventReadReport local;
  EventReadReport& rep = report ? *report : local;
  rep = EventReadReport{};
  rep.path = root;
  rep.format = "per-frame files";
  EventStream all;
  all.width = width;
  all.height = height;
  size_t files_read = 0;
  for (size_t i = 0; i < event_files.size(); ++i) {
    EventFileReader& r = c.reader(i);
    if (!r.may_have_events_in(t_begin_us, t_end_us)) continue;
    EventReadReport fr;
    const EventStream ev = r.read(t_begin_us, t_end_us, &fr);
    ++files_read;
    for (size_t k = 0; k < ev.size(); ++k) all.push(ev.t[k], ev.x[k], ev.y[k], ev.p[k]);
    static_cast<ReadStats&>(rep) += fr;
    rep.sorted |= fr.sorted;
    rep.empty_file |= fr.empty_file;
    for (const auto& [kind, n] : fr.ignored) rep.ignored[kind] += n;
  }
  rep.stopped_early = files_read < event_files.size();
  rep.width = width;
  rep.height = height;
  rep.notes.push_back(std::to_string(files_read) + " of " + std::to_string(event_files.size()) +
                      " per-frame event files overlap the window");
  if (!std::is_sorted(all.t.begin(), all.t.end())) {
    std::vector<size_t> idx(all.size());
    std::iota(idx.begin(), idx.end(), 0);
    std::stable_sort(idx.begin(), idx.end(), [&](size_t a, size_t b) { return all.t[a] < all.t[b]; });
    EventStream sorted;
    sorted.width = width;
    sorted.height = height;
    sorted.reserve(all.size());
    for (size_t i : idx) sorted.push(all.t[i], all.x[i], all.y[i], all.p[i]);
    rep.notes.push_back("per-frame event files overlap in time: merged and sorted");
    return std::move(c.count(sorted));
  }
  return std::move(c.count(all));
}

void Sequence::read_events_to_end() const {
  if (!event_readers_) return;
  SequenceEventReaders& c = *event_readers_;
  std::lock_guard<std::mutex> lock(c.mutex);
  c.sync(event_files, event_options);
  for (size_t i = 0; i < event_files.size(); ++i) {
    EventFileReader& r = c.reader(i);
    // A window that begins after every record keeps none, and resumes at the index's end.
    if (r.streamed()) (void)r.read(INT64_MAX, std::nullopt);
  }
}

EventTotals Sequence::event_totals() const {
  if (!event_readers_) return {};
  SequenceEventReaders& c = *event_readers_;
  std::lock_guard<std::mutex> lock(c.mutex);
  EventTotals t = c.retired;
  for (const auto& r : c.readers)
    if (r) t += r->totals();
  // A window over per-frame files reads several files: count the windows, not the file reads.
  t.reads = c.windows;
  t.delivered = c.delivered;
  return t;
}

}  // namespace vkunroll
