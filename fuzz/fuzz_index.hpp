// Differential check of the index (fuzz_index and the corpus regression test): windowed reads
// through EventFileReader against the full scan. The first byte picks the format (kIndexFormats)
// and the policy, the last bytes the windows. Under drop/sort every window must equal the full scan
// filtered to it; under error each window must throw exactly when (and with the message) a scan
// from the start to the window's end does.
#pragma once
#include <algorithm>
#include <utility>
#include <optional>
#include <string>

#include "vkunroll/host/events/event_reader_detail.hpp"


namespace vkunroll::fuzz {

// A scan from the start (a scratch index turns off the one-off shortcuts: the AEDAT data table,
// the .dat binary search), stopping at the window's end.
inline EventStream scan_from_start(const char* name, const uint8_t* d, size_t n, const std::string& format,
                                   const EventReadOptions& o, EventReadReport& rep) {
  detail::MemorySource src(name, d, n);
  detail::EventSink sink(name, o, rep);
  detail::StreamIndex scratch;
  sink.use_index(&scratch, nullptr, UINT64_MAX);
  detail::read_source(format, src, sink);
  return sink.finish();
}

inline bool same_stream(const EventStream& a, const EventStream& b) {
  return a.t == b.t && a.x == b.x && a.y == b.y && a.p == b.p && a.width == b.width && a.height == b.height;
}

// The streamed formats of the table (event_formats.hpp), in the order the committed corpus's first
// bytes number them (tests/test_event_formats.cpp checks that these are exactly the streamed rows):
// a new streamed format is appended here.
inline constexpr const char* kIndexFormats[] = {"txt", "evt2", "evt3", "dat", "aedat4", "evt21", "aedat2", "aedat3", "bag"};
inline constexpr int kIndexFormatCount = int(sizeof(kIndexFormats) / sizeof(kIndexFormats[0]));

// The format and policy (0 error, 1 drop, 2 sort) of first byte `k` (0-127): 0-14, the first five
// formats x 3 policies; 15-23, the next three x 3; from 24, each further format x 3 policies in turn;
// past those, as 0-14.
inline std::pair<int, int> index_case(int k) {
  if (k >= 15 && k < 24) return {5 + (k - 15) % 3, (k - 15) / 3};
  if (k >= 24 && k < 24 + 3 * (kIndexFormatCount - 8)) return {8 + (k - 24) / 3, (k - 24) % 3};
  return {k % 5, (k / 5) % 3};
}

// False when an indexed read differs from the full scan.
inline bool index_matches_full_scan(const uint8_t* data, size_t size) {
  if (size < 4) return true;
  const auto [f, policy] = index_case(data[0] & 0x7F);
  const std::string format = kIndexFormats[f];
  EventReadOptions o;
  o.on_bad = policy == 0 ? BadEventPolicy::error : policy == 1 ? BadEventPolicy::drop : BadEventPolicy::sort;
  if (data[0] & 0x80) o.width = 64, o.height = 48;
  const uint8_t* body = data + 1;
  const size_t n = size - 1;
  const char* name = "fuzz.index";
  EventReadReport full_rep;
  EventStream all;
  bool full_ok = true;
  try {
    all = scan_from_start(name, body, n, format, o, full_rep);
  } catch (const Error&) {
    full_ok = false;
  }
  std::optional<EventFileReader> reader;
  try {
    reader.emplace(detail::memory_file_reader(name, body, n, format, o));
  } catch (const Error&) {
    return true;
  }
  const int64_t lo = all.empty() ? 0 : all.t.front(), hi = all.empty() ? 1000 : all.t.back();
  const int64_t span = std::max<int64_t>(hi - lo, 1);
  for (int w = 0; w < 8; ++w) {
    const uint8_t a = data[size - 1 - size_t(w) % (size - 1)], b = data[(size_t(w) * 7 + 3) % size];
    const int64_t begin = lo - span / 8 + span * a / 200, end = begin + span * b / 400;
    if (o.on_bad == BadEventPolicy::error || !full_ok) {
      EventReadOptions wo = o;
      wo.t_begin_us = begin, wo.t_end_us = end;
      EventReadReport r1, r2;
      std::string e1, e2;
      EventStream s1, s2;
      try {
        s1 = scan_from_start(name, body, n, format, wo, r1);
      } catch (const Error& e) {
        e1 = e.what();
      }
      try {
        s2 = reader->read(begin, end, &r2);
      } catch (const Error& e) {
        e2 = e.what();
      }
      if (o.on_bad == BadEventPolicy::error && (e1 != e2 || (e1.empty() && !same_stream(s1, s2)))) return false;
      continue;
    }
    EventStream got;
    try {
      got = reader->read(begin, end);
    } catch (const Error&) {
      return false;  // the full scan read every record without an error
    }
    EventStream want;
    want.width = all.width, want.height = all.height;
    for (size_t i = 0; i < all.size(); ++i)
      if (all.t[i] >= begin && all.t[i] < end) want.push(all.t[i], all.x[i], all.y[i], all.p[i]);
    // The sensor size of a file that does not give one is inferred from the window's events.
    if (full_rep.size_inferred) want.width = got.width, want.height = got.height;
    if (!same_stream(want, got)) return false;
  }
  return true;
}

}  // namespace vkunroll::fuzz
