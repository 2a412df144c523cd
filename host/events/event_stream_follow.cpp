#include "vkunroll/host/events/event_stream_follow.hpp"

#include <fcntl.h>
#include <poll.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <algorithm>
#include <chrono>
#include <cstring>
#include <thread>

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/events/event_reader_detail.hpp"
#include "vkunroll/host/events/evt2_words_detail.hpp"
#include "vkunroll/host/events/evt3_words_detail.hpp"

namespace vkunroll {

// The decoder states (EVT 3.0 or EVT 2.0/2.1) and the record rules, kept across reads.
struct EventStreamFollower::Decoder {
  Decoder(const std::string& name, const EventReadOptions& o, EventReadReport& report)
      : sink(name, o, report, [this](const EventStream& c) {
          for (size_t i = 0; i < c.size(); ++i) out->push(c.t[i], c.x[i], c.y[i], c.p[i]);
        }, 1) {}
  EventStream* out = nullptr;  // where this read's events go
  detail::EventSink sink;
  detail::Evt3State state;
  detail::Evt2State state2;
  uint64_t record = 0;
};

EventStreamFollower::EventStreamFollower(const std::string& path, const EventReadOptions& options)
    : name_(path == "-" ? "stdin" : path), options_(options) {
  if (path.empty()) throw OptionError("follow_events", "", "an empty value (name a pipe, a growing file, or - for stdin)");
  if (options_.on_bad == BadEventPolicy::sort)
    throw OptionError("on_bad", "sort", "error or drop",
                      opt("follow") + ": " + opt("on_bad") + " sort cannot apply to a live stream (events are used as they come); use error or drop");
  if (path == "-") {
    fd_ = 0;
  } else {
    // Non-blocking: opening a FIFO that no writer has opened yet must not block (the idle limit
    // applies to the wait); poll() then waits for the writer's bytes.
    fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
    if (fd_ < 0) {
      if (errno == ENOENT) throw OptionError("follow_events", path, "no such file", {}, ErrorKind::input_missing);
      throw OptionError("follow_events", path, std::string("cannot open (") + std::strerror(errno) + ")", {}, ErrorKind::data);
    }
    own_fd_ = true;
  }
  struct stat st {};
  if (::fstat(fd_, &st) == 0) pipe_ = S_ISFIFO(st.st_mode) || S_ISSOCK(st.st_mode) || S_ISCHR(st.st_mode);
  if (::fstat(fd_, &st) == 0 && S_ISDIR(st.st_mode)) throw OptionError("follow_events", path, "is a folder", {}, ErrorKind::data);
}

EventStreamFollower::~EventStreamFollower() {
  if (own_fd_ && fd_ >= 0) ::close(fd_);
}

// '%' lines up to "% end" or the first byte that is not '%' at a line start (or the stream's end:
// a header that never ended is validated all the same).
void EventStreamFollower::parse_header(bool at_end) {
  size_t off = 0;
  bool ended = false;  // "% end" seen, or a byte that starts no '%' line: the data begins at `off`
  while (!ended && off < pending_.size()) {
    if (pending_[off] != '%') {
      ended = true;
      break;
    }
    const auto nl = std::find(pending_.begin() + long(off), pending_.end(), uint8_t('\n'));
    if (nl == pending_.end()) {
      if (pending_.size() - off > (1 << 16)) throw DataError(name_ + ": a '%' header line longer than 64 KiB");
      if (!at_end) return;  // the line is not complete yet
      off = pending_.size();
      break;
    }
    const std::string line(pending_.begin() + long(off), nl);
    off = size_t(nl - pending_.begin()) + 1;
    ended = detail::is_prophesee_header_end(line);
  }
  if (!ended && !at_end) return;  // only header lines so far
  detail::MemorySource head(name_, std::vector<uint8_t>(pending_.begin(), pending_.begin() + long(off)));
  const detail::PropheseeHeader h = detail::parse_prophesee_header(head);
  if (h.evt != "3.0" && h.evt != "2.0" && h.evt != "2.1")
    throw DataError(name_ + ": the stream's '%' header says " + (h.evt.empty() ? std::string("no encoding") : "EVT " + h.evt) +
                    "; " + opt("follow") + " reads EVT 2.0, 2.1 or 3.0 ('% evt 3.0', '% format EVT21;...')" +
                    (ended ? "" : " (the stream ended inside its header, before '% end')"));
  evt_ = h.evt;
  evt21_legacy_ = h.evt21_legacy;
  header_width_ = h.width, header_height_ = h.height, header_geometry_ = h.geometry_source;
  pending_.erase(pending_.begin(), pending_.begin() + long(off));
  data_offset_ = off;
  header_done_ = true;
  open_decoder();
}

void EventStreamFollower::open_decoder() {
  if (decoder_) return;
  decoder_ = std::make_unique<Decoder>(name_, options_, report_);
  // The header's sensor size against the sequence's: a disagreement is said, as offline.
  decoder_->sink.set_file_geometry(header_width_, header_height_, header_geometry_.empty() ? "the '%' header" : header_geometry_);
}

void EventStreamFollower::decode(EventStream& out) {
  decoder_->out = &out;
  Decoder& d = *decoder_;
  const size_t unit = evt_ == "3.0" ? 2 : evt_ == "2.0" ? 4 : 8;  // bytes a word
  const size_t whole = pending_.size() / unit * unit;
  const uint8_t* b = pending_.data();
  auto le32 = [&](size_t i) { return uint32_t(b[i]) | uint32_t(b[i + 1]) << 8 | uint32_t(b[i + 2]) << 16 | uint32_t(b[i + 3]) << 24; };
  for (size_t i = 0; i < whole; i += unit) {
    if (unit == 2) {
      detail::evt3_word(uint16_t(b[i] | (b[i + 1] << 8)), data_offset_ + i, d.state, d.record, d.sink);
    } else if (unit == 4) {
      detail::evt2_word(le32(i), data_offset_ + i, d.state2, d.record, d.sink);
    } else {  // EVT 2.1: a little-endian 64-bit word, or (legacy) the high 32-bit half first
      const uint32_t first = le32(i), second = le32(i + 4);
      detail::evt21_word(evt21_legacy_ ? first : second, evt21_legacy_ ? second : first, data_offset_ + i, d.state2, d.record, d.sink);
    }
  }
  data_offset_ += whole;
  pending_.erase(pending_.begin(), pending_.begin() + long(whole));
  // Time words move the sensor clock even when no event comes (a quiet scene).
  int64_t clock = INT64_MIN;
  if (unit == 2 && d.state.have_high) clock = int64_t(d.state.loop + (d.state.time_high << 12) + d.state.time_low);
  if (unit != 2 && d.state2.have_high) clock = int64_t(d.state2.loop + (d.state2.time_high << 6));
  if (!out.empty()) clock = std::max(clock, out.t.back());
  clock_us_ = std::max(clock_us_, clock);
}

void EventStreamFollower::finish() {
  if (finished_) return;
  finished_ = true;
  if (!header_done_ && !pending_.empty()) parse_header(true);
  if (!header_done_ || pending_.empty()) return;
  Decoder& d = *decoder_;
  const char* word = evt_ == "3.0" ? "16-bit EVT 3.0 word" : evt_ == "2.0" ? "32-bit EVT 2.0 word" : "64-bit EVT 2.1 word";
  d.sink.set_record_index(d.record++);
  d.sink.set_byte_offset(int64_t(data_offset_));
  const size_t trailing = pending_.size();
  pending_.clear();
  // The offline reader's rule and words for a truncated file (reader_evt.cpp, finish_words).
  d.sink.unknown_record(std::string("the stream ends inside a ") + word + " (" + std::to_string(trailing) +
                        " trailing bytes; truncated stream)");
}

EventStreamFollower::Status EventStreamFollower::read_some(int timeout_ms, EventStream& out) {
  if (finished_) return Status::end;
  pollfd p{fd_, POLLIN, 0};
  if (pipe_) {
    const int r = ::poll(&p, 1, timeout_ms);
    if (r < 0 && errno != EINTR) throw DataError(name_ + ": cannot wait for events (" + std::strerror(errno) + ")");
    if (r <= 0) return Status::no_data;
  }
  uint8_t buf[1 << 16];
  const ssize_t n = ::read(fd_, buf, sizeof buf);
  if (n < 0) {
    if (errno == EINTR || errno == EAGAIN) return Status::no_data;
    throw DataError(name_ + ": cannot read events (" + std::strerror(errno) + ")");
  }
  if (n == 0) {
    if (pipe_) {
      finish();
      return Status::end;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(timeout_ms));  // a growing file: wait for more
    return Status::no_data;
  }
  feed(buf, size_t(n), out);
  return Status::data;
}

void EventStreamFollower::feed(const uint8_t* data, size_t size, EventStream& out) {
  bytes_ += uint64_t(size);
  pending_.insert(pending_.end(), data, data + size);
  if (!header_done_) parse_header(false);
  if (header_done_) decode(out);
}

EventStreamFollower::EventStreamFollower(const std::string& name, const EventReadOptions& options, std::nullptr_t)
    : name_(name), options_(options) {}

}  // namespace vkunroll
