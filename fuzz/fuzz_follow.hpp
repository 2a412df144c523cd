// The live-stream decoder (EventStreamFollower, `unroll --follow`) against the offline .raw reader
// on the same bytes, for fuzz/fuzz_follow.cpp and the corpus regression test. The first byte picks
// the encoding (EVT 3.0, 2.0, 2.1), whether the header says a sensor size and ends with '% end',
// and the policy (drop or error); the second seeds the chunk sizes the stream arrives in. Online
// (fed chunk by chunk, then finished as at a pipe's end) and offline must keep the same events and
// drop the same number of records, or both refuse the stream.
#pragma once
#include <algorithm>
#include <cstring>
#include <string>

#include "vkunroll/host/events/event_reader_detail.hpp"
#include "vkunroll/host/events/event_stream_follow.hpp"

namespace vkunroll::fuzz {

namespace follow_detail {

struct Outcome {
  bool refused = false;
  vkunroll::EventStream events;
  uint64_t dropped = 0;
};

inline Outcome online(const std::string& bytes, const vkunroll::EventReadOptions& o, uint8_t seed) {
  Outcome r;
  try {
    vkunroll::EventStreamFollower f("fuzz.raw", o, nullptr);
    uint32_t state = seed * 2654435761u + 1;
    for (size_t at = 0; at < bytes.size();) {
      state = state * 1103515245u + 12345u;
      const size_t n = std::min<size_t>(bytes.size() - at, 1 + (state >> 16) % 97);
      f.feed(reinterpret_cast<const uint8_t*>(bytes.data()) + at, n, r.events);
      at += n;
    }
    f.finish();
    r.dropped = f.report().dropped();
  } catch (const vkunroll::Error&) {
    r.refused = true;
  }
  return r;
}

inline Outcome offline(const std::string& bytes, const vkunroll::EventReadOptions& o, int encoding) {
  Outcome r;
  try {
    vkunroll::EventReadReport report;
    vkunroll::detail::MemorySource src("fuzz.raw", reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size());
    vkunroll::detail::EventSink sink("fuzz.raw", o, report);
    if (encoding == 0) vkunroll::detail::read_evt3(src, sink);
    else if (encoding == 1) vkunroll::detail::read_evt2(src, sink);
    else vkunroll::detail::read_evt21(src, sink);
    r.events = sink.finish();
    r.dropped = report.dropped();
  } catch (const vkunroll::Error&) {
    r.refused = true;
  }
  return r;
}

}  // namespace follow_detail

// False when the online decoder and the offline reader disagree on `data` (see above).
inline bool follow_matches_offline(const uint8_t* data, size_t size) {
  using namespace follow_detail;
  if (size < 2) return true;
  const int encoding = data[0] % 3;
  static const char* kHeaders[] = {"% evt 3.0\n", "% evt 2.0\n", "% evt 2.1\n"};
  std::string bytes = kHeaders[encoding];
  if (data[0] & 4) bytes += "% format EVT;height=48;width=64\n";
  if (!(data[0] & 8)) bytes += "% end\n";  // a header without '% end' ends at the first data byte
  bytes.append(reinterpret_cast<const char*>(data) + 2, size - 2);
  vkunroll::EventReadOptions o;
  o.on_bad = (data[0] & 16) ? vkunroll::BadEventPolicy::error : vkunroll::BadEventPolicy::drop;
  const Outcome a = online(bytes, o, data[1]), b = offline(bytes, o, encoding);
  if (a.refused != b.refused) return false;
  if (a.refused) return true;
  return a.events.t == b.events.t && a.events.x == b.events.x && a.events.y == b.events.y && a.events.p == b.events.p &&
         a.dropped == b.dropped;
}

}  // namespace vkunroll::fuzz
