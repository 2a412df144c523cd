// Windowed reads through the per-file index (EventFileReader): every window equals the full scan
// filtered to it, in every format, on the real recordings, with windows that start mid-packet,
// empty windows, windows before the start and beyond the end, in any order, and under every
// bad-record policy on files with bad records. Also: later windows really seek.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <optional>
#include <random>
#include <sstream>

#include "event_test_encoders.hpp"
#include "event_test_util.hpp"
#include "vk_test_env.hpp"
#include "vkunroll/host/events/event_file_reader.hpp"
#include "vkunroll/host/events/event_reader_detail.hpp"
#include "vkunroll/host/events/event_reader.hpp"
#include "vkunroll/host/events/event_writer.hpp"
#include "vkunroll/base/error.hpp"

namespace fs = std::filesystem;
using namespace vkunroll;
using namespace vkunroll::evtest;

namespace {

struct Window {
  std::optional<int64_t> a, b;
};

std::string str(const Window& w) {
  std::ostringstream os;
  os << "[" << (w.a ? std::to_string(*w.a) : "-inf") << ", " << (w.b ? std::to_string(*w.b) : "+inf") << ")";
  return os.str();
}

// The events of a full scan (sorted by t) inside the window.
EventStream filtered(const EventStream& all, const Window& w) {
  EventStream out;
  out.width = all.width;
  out.height = all.height;
  const size_t lo = w.a ? size_t(std::lower_bound(all.t.begin(), all.t.end(), *w.a) - all.t.begin()) : 0;
  const size_t hi = w.b ? size_t(std::lower_bound(all.t.begin(), all.t.end(), *w.b) - all.t.begin()) : all.size();
  for (size_t i = lo; i < std::max(lo, hi); ++i) out.push(all.t[i], all.x[i], all.y[i], all.p[i]);
  return out;
}

// 200 overlapping frame windows in order (as `vkunroll unroll` reads them), then random windows in
// random order: empty ones, ones before the start and beyond the end, open-ended ones.
std::vector<Window> windows_for(int64_t first, int64_t last, uint32_t seed) {
  std::vector<Window> w;
  const int64_t span = std::max<int64_t>(last - first, 1), period = std::max<int64_t>(span / 200, 1);
  for (int k = 0; k < 200; ++k) w.push_back({first + k * period, first + k * period + period * 3 / 2});
  std::mt19937 rng(seed);
  for (int k = 0; k < 60; ++k) {
    const int64_t a = first - span / 10 + int64_t(rng() % uint64_t(span + span / 5));
    w.push_back({a, a + int64_t(rng() % uint64_t(span / 5 + 1))});
  }
  w.push_back({first + span / 2, first + span / 2});        // empty
  w.push_back({last + 1, last + 100000});                   // beyond the end
  w.push_back({first - 100000, first});                     // before the start
  w.push_back({std::nullopt, first + span / 3});
  w.push_back({first + span / 3, std::nullopt});
  w.push_back({std::nullopt, std::nullopt});
  w.push_back({first, first + 1});
  w.push_back({last, last + 1});
  return w;
}

// Every window through one indexed reader equals the full scan filtered to it.
void expect_windows_match(const std::string& path, const EventReadOptions& o, uint32_t seed = 1) {
  EventReadReport full_rep;
  const EventStream all = read_events(path, o, &full_rep);
  ASSERT_FALSE(all.empty()) << path;
  EventFileReader reader(path, o);
  for (const Window& w : windows_for(all.t.front(), all.t.back(), seed)) {
    SCOPED_TRACE(path + " window " + str(w));
    EventReadReport rep;
    const EventStream got = reader.read(w.a, w.b, &rep);
    expect_same(filtered(all, w), got);
    EXPECT_EQ(rep.kept, got.size());
    if (::testing::Test::HasFailure()) return;
  }
  // Each record once, however many windows covered it: every record was in some window.
  const EventTotals& t = reader.totals();
  EXPECT_EQ(t.records, full_rep.records) << t.summary();
  EXPECT_EQ(t.valid, full_rep.kept + full_rep.outside_window);
  EXPECT_EQ(t.dropped(), full_rep.dropped());
  EXPECT_EQ(t.dropped_time_order, full_rep.dropped_time_order);
  EXPECT_EQ(t.reordered, full_rep.reordered);
}

// A sorted stream with a fraction of records made bad: times moved back (out of order) and x
// beyond the sensor.
EventStream dirty_stream(size_t n, int w, int h, uint32_t seed) {
  EventStream ev = random_stream(n, w, h, seed, 5000, 3);
  std::mt19937 rng(seed + 7);
  for (size_t i = 0; i < ev.size(); ++i) {
    const uint32_t r = rng() % 100;
    if (r < 4) ev.t[i] = std::max<int64_t>(0, ev.t[i] - int64_t(rng() % 400));
    else if (r < 5) ev.x[i] = uint16_t(w + 3);
  }
  return ev;
}

// EVT 2.0 with unknown words (type 0x5) inserted between words.
std::vector<uint8_t> with_unknown_evt2_words(std::vector<uint8_t> b, size_t header, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<uint8_t> out(b.begin(), b.begin() + long(header));
  for (size_t i = header; i + 4 <= b.size(); i += 4) {
    if (rng() % 200 == 0) put32(out, 0x50000000u | (rng() & 0xFFFF));
    out.insert(out.end(), b.begin() + long(i), b.begin() + long(i + 4));
  }
  return out;
}

EventStream concat(const EventStream& a, const EventStream& b) {
  EventStream c = a;
  for (size_t i = 0; i < b.size(); ++i) c.push(b.t[i], b.x[i], b.y[i], b.p[i]);
  return c;
}

EventStream stable_sorted(const EventStream& s) {
  std::vector<size_t> idx(s.size());
  for (size_t i = 0; i < idx.size(); ++i) idx[i] = i;
  std::stable_sort(idx.begin(), idx.end(), [&](size_t a, size_t b) { return s.t[a] < s.t[b]; });
  EventStream out;
  out.width = s.width, out.height = s.height;
  for (size_t i : idx) out.push(s.t[i], s.x[i], s.y[i], s.p[i]);
  return out;
}

// Reads `format` from `path` into a sink: from checkpoint `from` (nullptr: the start), stopping at
// the checkpoint offset `stop`, building its own scratch index.
EventStream read_part(const std::string& path, const std::string& format, const EventReadOptions& o,
                      detail::StreamIndex& ix, const detail::Checkpoint* from, uint64_t stop, EventReadReport& rep) {
  detail::FileSource src(path);
  detail::EventSink sink(path, o, rep);
  sink.use_index(&ix, from, stop);
  detail::read_source(format, src, sink);
  return sink.finish();
}

// Every checkpoint restores the full scan's state exactly: the records before it (a read that stops
// there) and after it (a read that resumes there) are, together, the full scan, record for record
// and counter for counter.
void expect_checkpoints_exact(const std::string& path, const std::string& format, const EventReadOptions& o) {
  detail::StreamIndex ix;
  EventReadReport full_rep;
  const EventStream full = read_part(path, format, o, ix, nullptr, UINT64_MAX, full_rep);
  ASSERT_TRUE(ix.complete) << path;
  ASSERT_GE(ix.segments.size(), 4u) << path;
  for (size_t i = 1; i < ix.segments.size(); ++i) {
    SCOPED_TRACE(path + ": checkpoint " + std::to_string(i) + " at byte " + std::to_string(ix.segments[i].start.offset));
    detail::StreamIndex scratch_a, scratch_b;
    EventReadReport ra, rb;
    const EventStream before = read_part(path, format, o, scratch_a, nullptr, ix.segments[i].start.offset, ra);
    const EventStream after = read_part(path, format, o, scratch_b, &ix.segments[i].start, UINT64_MAX, rb);
    EventStream joined = concat(before, after);
    if (o.on_bad == BadEventPolicy::sort) joined = stable_sorted(joined);
    joined.width = full.width, joined.height = full.height;
    expect_same(full, joined);
    EXPECT_EQ(ra.records + rb.records, full_rep.records);
    EXPECT_EQ(ra.dropped_time_order + rb.dropped_time_order, full_rep.dropped_time_order);
    EXPECT_EQ(ra.dropped_out_of_sensor + rb.dropped_out_of_sensor, full_rep.dropped_out_of_sensor);
    EXPECT_EQ(ra.dropped_unknown_word + rb.dropped_unknown_word, full_rep.dropped_unknown_word);
    EXPECT_EQ(ra.reordered + rb.reordered, full_rep.reordered);
    // A segment's valid-time range covers what the full scan kept from it.
    if (::testing::Test::HasFailure()) return;
  }
}

}  // namespace

// Each format's decoder state (EVT time high bits, vector base and row, .dat wrap count, text
// header state) and the sink's time-order state survive a checkpoint exactly.
TEST(EventIndex, CheckpointsRestoreTheFullScanState) {
  EventStream ev = dirty_stream(60000, 640, 480, 31);
  std::mt19937 rng(32);
  for (size_t i = 0; i < ev.size(); ++i)  // many more records out of order: every checkpoint meets some
    if (rng() % 5 == 0) ev.t[i] = std::max<int64_t>(0, ev.t[i] - int64_t(rng() % 100));
  const EventStream clean = random_stream(60000, 640, 480, 33, (int64_t(1) << 24) - 60000, 4);  // EVT 3 time wrap
  const std::string txt = tmp("cp.txt"), e2 = tmp("cp2.raw"), e3 = tmp("cp3.raw"), e3w = tmp("cp3w.raw"),
                    dat = tmp("cp.dat"), aed = tmp("cp.aedat4");
  {
    std::ofstream f(txt);
    f << "x,y,timestamp,polarity\n";  // a header line: the text reader's 'first line' state
    for (size_t i = 0; i < ev.size(); ++i) f << ev.x[i] << "," << ev.y[i] << "," << ev.t[i] << "," << (ev.p[i] > 0) << "\n";
  }
  const std::string h2 = "% evt 2.0\n% geometry 640x480\n";
  write_bytes(e2, with_unknown_evt2_words(encode_evt2(ev, h2), h2.size(), 6));
  write_bytes(e3, encode_evt3(ev, "% evt 3.0\n% geometry 640x480\n", true));
  write_bytes(e3w, encode_evt3(clean, "% evt 3.0\n% geometry 640x480\n", true));
  write_bytes(dat, encode_dat(ev));
  write_bytes(aed, encode_aedat4(ev, 3, 500));
  for (const BadEventPolicy policy : {BadEventPolicy::drop, BadEventPolicy::sort}) {
    EventReadOptions o;
    o.on_bad = policy;
    o.width = 640, o.height = 480;
    for (const auto& [p, f] : std::vector<std::pair<std::string, std::string>>{
             {txt, "txt"}, {e2, "evt2"}, {e3, "evt3"}, {e3w, "evt3"}, {dat, "dat"}, {aed, "aedat4"}}) {
      SCOPED_TRACE(policy == BadEventPolicy::drop ? "drop" : "sort");
      expect_checkpoints_exact(p, f, o);
      if (HasFailure()) return;
    }
  }
}

TEST(EventIndex, StreamedFormatsEqualTheFullScan) {
  const EventStream ev = random_stream(150000, 640, 480, 21, 1000, 4);
  const std::string hdr = "% evt 3.0\n% geometry 640x480\n";
  const std::string txt = tmp("index.txt"), e2 = tmp("index2.raw"), e3 = tmp("index3.raw"), dat = tmp("index.dat"),
                    lz4 = tmp("index_lz4.aedat4"), zst = tmp("index_zstd.aedat4"), raw = tmp("index_none.aedat4");
  write_events_text(txt, ev);
  write_bytes(e2, encode_evt2(ev, "% evt 2.0\n% geometry 640x480\n"));
  write_bytes(e3, encode_evt3(ev, hdr, true));
  write_bytes(dat, encode_dat(ev));
  write_bytes(lz4, encode_aedat4(ev, 1, 3000));
  write_bytes(zst, encode_aedat4(ev, 3, 3000, false));
  write_bytes(raw, encode_aedat4(ev, 0, 7000));
  for (const auto& p : {txt, e2, e3, dat, lz4, zst, raw}) {
    expect_windows_match(p, {});
    if (HasFailure()) return;
  }
}

TEST(EventIndex, LaterWindowsSeekInsteadOfRescanning) {
  const EventStream ev = random_stream(200000, 320, 240, 22, 0, 4);
  const std::string txt = tmp("seek.txt"), e3 = tmp("seek.raw");
  write_events_text(txt, ev);
  write_bytes(e3, encode_evt3(ev, "% evt 3.0\n% geometry 320x240\n", true));
  for (const auto& p : {txt, e3}) {
    SCOPED_TRACE(p);
    EventFileReader r(p, {});
    const int64_t late = ev.t[ev.size() * 9 / 10];
    EventReadReport first, again, earlier;
    r.read(late, late + 1000, &first);      // indexes up to the window
    r.read(late, late + 1000, &again);      // seeks
    r.read(ev.t[1000], ev.t[1000] + 1000, &earlier);
    EXPECT_GT(first.records, ev.size() * 8 / 10);
    EXPECT_LT(again.records, ev.size() / 20) << again.summary();
    EXPECT_LT(earlier.records, ev.size() / 20) << earlier.summary();
    EXPECT_TRUE(again.stopped_early);
    EXPECT_GT(r.checkpoints(), 10u);
    // The stateless read of the same window still scans from the start (the old behaviour).
    EventReadOptions o;
    o.t_begin_us = late;
    o.t_end_us = late + 1000;
    EventReadReport stateless;
    expect_same(read_events(p, o, &stateless), r.read(late, late + 1000));
    EXPECT_GT(stateless.records, ev.size() * 8 / 10);
  }
}

TEST(EventIndex, RealRecordingsEqualTheFullScan) {
  for (const char* name : {"evt3_sample.raw", "sample.aedat4"}) {
    expect_windows_match(vktest::real_recording(name), {}, 5);
    if (HasFailure()) return;
  }
}

TEST(EventIndex, RandomAccessFormatsEqualTheFullScan) {
  const EventStream ev = random_stream(200000, 346, 260, 23, 100, 4);
  const std::string h5 = tmp("ra.h5"), npy = tmp("ra.npy"), npz = tmp("ra_stored.npz"), npzc = tmp("ra_deflated.npz"),
                    rec = tmp("ra_record.npz");
  write_events_hdf5(h5, ev);
  const auto arr = encode_npy_nx4<int64_t>(ev, "<i8");
  write_bytes(npy, arr);
  write_npz(npz, {{"event.npy", arr}}, false);
  write_npz(npzc, {{"event.npy", arr}}, true);  // 6.4 MB: several inflate access points
  write_npz(rec, {{"event.npy", encode_npy_record(ev)}}, true);
  EventReadOptions o;
  o.width = 346, o.height = 260;
  for (const auto& p : {h5, npy, npz, npzc, rec}) {
    expect_windows_match(p, o, 9);
    if (HasFailure()) return;
  }
}

TEST(EventIndex, BadRecordsDropAndSortEqualTheFullScan) {
  const EventStream ev = dirty_stream(80000, 640, 480, 24);
  const std::string txt = tmp("dirty.txt"), e2 = tmp("dirty2.raw"), e3 = tmp("dirty3.raw"), dat = tmp("dirty.dat"),
                    aed = tmp("dirty.aedat4");
  {
    std::ofstream f(txt);
    f << "# width 640 height 480\n";
    std::mt19937 rng(3);
    for (size_t i = 0; i < ev.size(); ++i) {
      f << ev.t[i] << " " << ev.x[i] << " " << ev.y[i] << " " << (ev.p[i] > 0 ? (rng() % 300 == 0 ? 2 : 1) : 0) << "\n";
      if (rng() % 500 == 0) f << "garbage line\n";
    }
  }
  const std::string h2 = "% evt 2.0\n% geometry 640x480\n";
  write_bytes(e2, with_unknown_evt2_words(encode_evt2(ev, h2), h2.size(), 5));
  write_bytes(e3, encode_evt3(ev, "% evt 3.0\n% geometry 640x480\n", true));
  write_bytes(dat, encode_dat(ev));
  write_bytes(aed, encode_aedat4(ev, 1, 2500));
  for (const BadEventPolicy policy : {BadEventPolicy::drop, BadEventPolicy::sort}) {
    EventReadOptions o;
    o.on_bad = policy;
    for (const auto& p : {txt, e2, e3, dat, aed}) {
      SCOPED_TRACE(policy == BadEventPolicy::drop ? "drop" : "sort");
      expect_windows_match(p, o, 11);
      if (HasFailure()) return;
    }
  }
}

// on_bad=error: a window read through the index throws exactly when the stateless read of the same
// window (a scan from the start) throws, with the same message; otherwise it returns the same events.
TEST(EventIndex, ErrorPolicyThrowsWhereTheFullScanThrows) {
  EventStream ev = random_stream(50000, 640, 480, 25, 5000, 3);
  ev.t[30000] = ev.t[30000] - 50;  // one record out of time order, 60% into the file
  const std::string txt = tmp("err.txt"), e3 = tmp("err.raw");
  {
    std::ofstream f(txt);  // the writer refuses out-of-order streams
    f << "# width 640 height 480\n";
    for (size_t i = 0; i < ev.size(); ++i) f << ev.t[i] << " " << ev.x[i] << " " << ev.y[i] << " " << (ev.p[i] > 0) << "\n";
  }
  write_bytes(e3, encode_evt3(ev, "% evt 3.0\n% geometry 640x480\n", false));
  for (const auto& p : {txt, e3}) {
    EventFileReader r(p, {});
    size_t threw = 0;
    std::vector<Window> ws = windows_for(ev.t.front(), ev.t.back(), 13);
    std::reverse(ws.begin() + 100, ws.end());  // some late windows first
    for (const Window& w : ws) {
      SCOPED_TRACE(p + " window " + str(w));
      EventReadOptions o;
      o.t_begin_us = w.a;
      o.t_end_us = w.b;
      EventStream want, got;
      const std::string want_err = error_of([&] { want = read_events(p, o); });
      const std::string got_err = error_of([&] { got = r.read(w.a, w.b); });
      EXPECT_EQ(want_err, got_err);
      if (want_err.empty()) expect_same(want, got);
      threw += !got_err.empty();
      if (HasFailure()) return;
    }
    EXPECT_GT(threw, 10u);
    EXPECT_LT(threw, ws.size() - 10);
  }
}

TEST(EventIndex, EmptyFileIsAnEmptyStreamThatSaysSo) {
  for (const char* name : {"empty.txt", "empty.raw", "empty.h5", "empty.npz", "empty.aedat4"}) {
    SCOPED_TRACE(name);
    const std::string p = tmp(name);
    write_file(p, "");
    EventReadReport rep;
    EXPECT_TRUE(read_events(p, {}, &rep).empty());
    EXPECT_TRUE(rep.empty_file);
    EXPECT_EQ(rep.records, 0u);
    EXPECT_NE(rep.summary().find("empty"), std::string::npos) << rep.summary();
    EventFileReader r(p, {});
    EXPECT_TRUE(r.read(0, 1000).empty());
    EXPECT_EQ(r.totals().records, 0u);
    EXPECT_EQ(r.totals().empty_files, 1u);
    EXPECT_NE(r.totals().summary().find("no event records"), std::string::npos) << r.totals().summary();
  }
  // A text file with only comments is not empty, but has no records: the totals say so too.
  const std::string c = tmp("comments.txt");
  write_file(c, "# width 10 height 10\n# nothing else\n");
  EventFileReader r(c, {});
  EXPECT_TRUE(r.read(0, 1000).empty());
  EXPECT_EQ(r.read(0, 1000).width, 10);
  EXPECT_NE(r.totals().summary().find("no event records"), std::string::npos);
}
