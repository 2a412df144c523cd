// Events from a pipe or a growing file, decoded as they arrive (`unroll --follow`, docs/follow.md):
// a Prophesee '%' header, then EVT 2.0, 2.1 or 3.0 words, the same decoders and record rules as the .raw reader
// (reader_evt.cpp, EventSink). read_some() never blocks longer than its timeout; opening a FIFO
// that no writer has opened yet does not block either (the idle limit applies while it waits).
#pragma once
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "vkunroll/base/events.hpp"
#include "vkunroll/host/events/event_reader.hpp"

namespace vkunroll {

class EventStreamFollower {
 public:
  // "-": stdin. `options`: the sensor size and the bad-record policy (sort is refused: a live
  // stream cannot be sorted). Throws InputMissingError / DataError naming the path.
  EventStreamFollower(const std::string& path, const EventReadOptions& options);
  ~EventStreamFollower();
  EventStreamFollower(const EventStreamFollower&) = delete;
  EventStreamFollower& operator=(const EventStreamFollower&) = delete;

  enum class Status { data, no_data, end };
  // Waits up to timeout_ms for bytes, decodes every whole word and appends the kept events to
  // `out`. `end`: a pipe's writer closed it (a regular file only grows: no_data at its end).
  // Bad records: Error naming the stream and byte (or dropped and counted, per policy). At `end`
  // the stream is finished as the offline reader finishes a file (finish()).
  Status read_some(int timeout_ms, EventStream& out);
  // The stream is over (its writer closed it, or the run gave up waiting): a header never ended is
  // validated now, and a partial word at the end is a truncated stream, as for the offline reader
  // (an error under --on-bad error, dropped and counted under drop). Idempotent.
  void finish();
  // Decodes `size` more bytes of the stream into `out` (what read_some does with what it read).
  void feed(const uint8_t* data, size_t size, EventStream& out);
  // A follower fed only by feed() (no file; the fuzzer compares it with the offline reader).
  EventStreamFollower(const std::string& name, const EventReadOptions& options, std::nullptr_t);

  // The sensor clock the stream has reached: the latest event time or time word decoded (a quiet
  // scene still advances it). INT64_MIN before any.
  int64_t clock_us() const { return clock_us_; }

  const std::string& name() const { return name_; }
  bool is_pipe() const { return pipe_; }
  uint64_t bytes_read() const { return bytes_; }
  const EventReadReport& report() const { return report_; }

 private:
  void parse_header(bool at_end);
  void decode(EventStream& out);
  void open_decoder();

  struct Decoder;
  std::string name_;
  int fd_ = -1;
  bool own_fd_ = false, pipe_ = false, header_done_ = false;
  std::string evt_;  // the header's encoding: "2.0", "2.1" or "3.0"
  bool evt21_legacy_ = false;
  EventReadOptions options_;
  EventReadReport report_;
  std::vector<uint8_t> pending_;  // bytes not decoded yet (a header line or a partial word)
  uint64_t bytes_ = 0, data_offset_ = 0;
  int64_t clock_us_ = INT64_MIN;
  bool finished_ = false;
  int header_width_ = 0, header_height_ = 0;  // the '%' header's sensor size (0: not said)
  std::string header_geometry_;
  std::unique_ptr<Decoder> decoder_;
};

}  // namespace vkunroll
