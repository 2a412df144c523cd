// Shared harness: run a reader over the fuzzer's bytes twice (drop policy, then options chosen by
// the last byte: error or sort, a time window, a sensor override). Returning or throwing
// vkunroll::Error is fine; anything else (crash, sanitizer report, other exception) is a finding.
#pragma once
#include <cstddef>
#include <cstdint>

#include "vkunroll/host/events/event_reader_detail.hpp"

namespace vkunroll::fuzz {

inline EventReadOptions options_from(const uint8_t* data, size_t size, int pass) {
  EventReadOptions o;
  if (pass == 0 || size == 0) {
    o.on_bad = BadEventPolicy::drop;
    return o;
  }
  const uint8_t k = data[size - 1];
  o.on_bad = (k & 1) ? BadEventPolicy::sort : BadEventPolicy::error;
  if (k & 2) o.t_begin_us = int64_t(k) * 37;
  if (k & 4) o.t_end_us = int64_t(k) * 1000;
  if (k & 8) o.width = 64, o.height = 48;
  return o;
}

template <class Read>
int run_reader(const uint8_t* data, size_t size, const char* name, Read read) {
  for (int pass = 0; pass < 2; ++pass) {
    EventReadReport report;
    try {
      detail::MemorySource src(name, data, size);
      detail::EventSink sink(name, options_from(data, size, pass), report);
      read(src, sink);
      const EventStream s = sink.finish();
      (void)report.summary();
      if (s.size() != report.kept) __builtin_trap();  // the report must count what was returned
    } catch (const vkunroll::Error&) {
    }
  }
  return 0;
}

}  // namespace vkunroll::fuzz
