// Event readers: every format read from a file this test writes, round trips through the
// writers, the real samples, every bad-input rule (the fuzz corpus: test_event_corpus.cpp).
#include <gtest/gtest.h>
#include <hdf5.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "event_test_encoders.hpp"
#include "event_test_util.hpp"
#include "../fuzz/fuzz_common.hpp"
#include "../fuzz/hdf5_image_builder.hpp"
#include "vkunroll/host/events/event_reader.hpp"
#include "vkunroll/host/events/event_reader_detail.hpp"
#include "vkunroll/base/error.hpp"
#include "vk_test_env.hpp"

namespace fs = std::filesystem;
using namespace vkunroll;
using namespace vkunroll::evtest;


// ---- text ------------------------------------------------------------------------------------

TEST(EventReaders, TextRoundTripThroughWriter) {
  const EventStream ev = random_stream(5000, 64, 48, 1);
  const std::string path = tmp("round.txt");
  write_events_text(path, ev);
  EventReadReport rep;
  const EventStream back = read_events(path, {}, &rep);
  expect_same(ev, back);
  EXPECT_EQ(rep.format, "txt");
  EXPECT_EQ(rep.records, 5000u);
  EXPECT_EQ(rep.kept, 5000u);
  EXPECT_FALSE(rep.size_inferred);
  EXPECT_EQ(rep.dropped(), 0u);
}

TEST(EventReaders, TextE2vidHeaderMeansSecondsAndSize) {
  const std::string path = tmp("e2vid.txt");
  write_file(path, "240 180\n0.000000000 10 20 1\n0.000123456 11 21 0\n1.5 239 179 1\n");
  EventReadReport rep;
  const EventStream ev = read_events(path, {}, &rep);
  ASSERT_EQ(ev.size(), 3u);
  EXPECT_EQ(ev.width, 240);
  EXPECT_EQ(ev.height, 180);
  EXPECT_EQ(ev.t[1], 123);  // 123.456 us rounds to 123
  EXPECT_EQ(ev.t[2], 1500000);
  EXPECT_EQ(ev.p[1], -1);
  EXPECT_EQ(rep.time_unit, "s");
}

TEST(EventReadersText, CsvHeaderColumnsUnitsAndComments) {
  const std::string path = tmp("cols.csv");
  write_file(path, "# recorded by hand\nx,y,timestamp,polarity\n3,4,1.5,True\n5,6,2.25,False\n\n% another comment\n7,1,3,1\n");
  EventReadOptions o;
  o.width = 8;
  o.height = 8;
  o.text_time_unit = "ms";
  const EventStream ev = read_events(path, o);
  ASSERT_EQ(ev.size(), 3u);
  EXPECT_EQ(ev.t[0], 1500);
  EXPECT_EQ(ev.t[1], 2250);
  EXPECT_EQ(ev.t[2], 3000);
  EXPECT_EQ(ev.x[0], 3);
  EXPECT_EQ(ev.y[0], 4);
  EXPECT_EQ(ev.p[0], 1);
  EXPECT_EQ(ev.p[1], -1);

  const std::string path2 = tmp("cols2.txt");
  write_file(path2, "1 2 1500 -1\n1 2 1501 1\n");  // x y t_ns p
  o.text_columns = "xytp";
  o.text_time_unit = "ns";
  const EventStream ev2 = read_events(path2, o);
  ASSERT_EQ(ev2.size(), 2u);
  EXPECT_EQ(ev2.t[0], 2);  // 1.5 us rounds half away from zero
  EXPECT_EQ(ev2.t[1], 2);
  EXPECT_EQ(ev2.p[0], -1);
  o.text_columns = "xyq";
  expect_error(path2, o, {"column order"});
}

TEST(EventReadersText, AutoUnitSecondsForManyDecimalsMicrosecondsOtherwise) {
  const std::string a = tmp("ecd.txt"), b = tmp("decimal_us.txt");
  write_file(a, "0.003811 96 133 0\n0.003820 127 171 0\n");
  write_file(b, "1234.5 1 1 1\n1235.25 1 1 0\n");
  EventReadReport ra, rb;
  EXPECT_EQ(read_events(a, {}, &ra).t[1], 3820);
  EXPECT_EQ(ra.time_unit, "s");
  const EventStream eb = read_events(b, {}, &rb);
  EXPECT_EQ(eb.t[0], 1235);  // 1234.5 us -> 1235 (half away from zero)
  EXPECT_EQ(eb.t[1], 1235);
  EXPECT_EQ(rb.time_unit, "us");
  EXPECT_TRUE(rb.size_inferred);
  EXPECT_EQ(eb.width, 2);
}

TEST(EventReadersText, BadRecordsErrorDropOrSort) {
  const std::string path = tmp("bad.txt");
  // line 3 out of sensor, line 4 goes back in time, line 5 NaN, line 6 malformed, line 7 bad polarity
  write_file(path, "# width 10 height 10\n5 1 1 1\n6 10 1 1\n4 2 2 0\n nan 3 3 1\n7 x 3 1\n8 3 3 2\n9 4 4 0\n");
  EventReadOptions o;
  expect_error(path, o, {"bad.txt", "record 1", "line 3", "outside the 10x10 sensor"});
  o.on_bad = BadEventPolicy::drop;
  EventReadReport rep;
  EventStream ev = read_events(path, o, &rep);
  EXPECT_EQ(ev.size(), 2u);  // t=5 and t=9
  EXPECT_EQ(rep.dropped_out_of_sensor, 1u);
  EXPECT_EQ(rep.dropped_time_order, 1u);
  EXPECT_EQ(rep.dropped_nan, 1u);
  EXPECT_EQ(rep.dropped_unknown_word, 1u);
  EXPECT_EQ(rep.dropped_bad_polarity, 1u);
  EXPECT_EQ(rep.records, 7u);
  EXPECT_NE(rep.summary().find("dropped 5"), std::string::npos) << rep.summary();
  o.on_bad = BadEventPolicy::sort;
  ev = read_events(path, o, &rep);
  ASSERT_EQ(ev.size(), 3u);  // 4, 5, 9: the early event is kept and sorted
  EXPECT_EQ(ev.t[0], 4);
  EXPECT_EQ(ev.t[1], 5);
  EXPECT_EQ(ev.t[2], 9);
  EXPECT_TRUE(rep.sorted);
  EXPECT_EQ(rep.dropped_time_order, 0u);
  EXPECT_EQ(rep.dropped(), 4u);

  const std::string back = tmp("back.txt");
  write_file(back, "10 1 1 1\n9 1 1 1\n");
  expect_error(back, {}, {"back.txt", "record 1", "line 2", "earlier than the previous"});
  const std::string nan = tmp("nan.txt");
  write_file(nan, "10 1 1 1\nNaN 1 1 1\n");
  expect_error(nan, {}, {"nan.txt", "record 1", "NaN"});
}

TEST(EventReadersText, SortIsStable) {
  const std::string path = tmp("stable.txt");
  write_file(path, "5 0 0 1\n3 1 0 1\n5 2 0 1\n3 3 0 1\n1 4 0 1\n");
  EventReadOptions o;
  o.on_bad = BadEventPolicy::sort;
  const EventStream ev = read_events(path, o);
  const std::vector<uint16_t> xs(ev.x.begin(), ev.x.end());
  EXPECT_EQ(xs, (std::vector<uint16_t>{4, 1, 3, 0, 2}));
}

TEST(EventReadersText, TimeWindowIsHalfOpenAndStopsEarly) {
  const std::string path = tmp("window.txt");
  std::string s = "# width 4 height 4\n";
  for (int t = 0; t < 100; ++t) s += std::to_string(t) + " 1 1 1\n";
  write_file(path, s);
  EventReadOptions o;
  o.t_begin_us = 10;
  o.t_end_us = 20;
  EventReadReport rep;
  const EventStream ev = read_events(path, o, &rep);
  ASSERT_EQ(ev.size(), 10u);
  EXPECT_EQ(ev.t.front(), 10);
  EXPECT_EQ(ev.t.back(), 19);
  EXPECT_TRUE(rep.stopped_early);
  EXPECT_EQ(rep.records, 21u);  // stopped at the first record at t_end
}

// ---- HDF5 ------------------------------------------------------------------------------------

TEST(EventReaders, Hdf5RoundTripThroughWriterAndWindowSeek) {
  const EventStream ev = random_stream(200000, 346, 260, 2);
  const std::string path = tmp("round.h5");
  write_events_hdf5(path, ev);
  EventReadReport rep;
  expect_same(ev, read_events(path, {}, &rep));
  EXPECT_EQ(rep.format, "h5:events");
  EXPECT_FALSE(rep.size_inferred);

  EventReadOptions o;
  o.t_begin_us = ev.t[150000];
  o.t_end_us = ev.t[150100] + 1;
  const EventStream w = read_events(path, o, &rep);
  size_t expect = 0;
  for (int64_t t : ev.t) expect += t >= *o.t_begin_us && t < *o.t_end_us;
  EXPECT_EQ(w.size(), expect);
  EXPECT_TRUE(rep.stopped_early);
  EXPECT_EQ(rep.records, expect);  // binary search: only the window's rows were read
  for (int64_t t : w.t) {
    EXPECT_GE(t, *o.t_begin_us);
    EXPECT_LT(t, *o.t_end_us);
  }
}

TEST(EventReadersHdf5, LayoutsGevRsV2eDreDsec) {
  const EventStream ev = random_stream(3000, 64, 48, 3);
  // Gev-RS: events N x 4 int64 + img_to_idx; v2e: events N x 4 uint32.
  const std::string gev = tmp("gevrs.h5"), v2e = tmp("v2e.h5"), dre = tmp("dre.h5"), dsec = tmp("dsec.h5");
  write_h5_nx4(gev, ev, H5T_STD_I64LE, true);
  write_h5_nx4(v2e, ev, H5T_STD_U32LE, false);
  EventReadReport rep;
  EventReadOptions o;
  o.width = 64;
  o.height = 48;
  expect_same(ev, read_events(gev, o, &rep));
  EXPECT_EQ(rep.format, "h5:gevrs");
  EXPECT_EQ(read_event_index(gev, "img_to_idx").size(), 4u);
  EventStream r = read_events(v2e, {}, &rep);
  EXPECT_EQ(rep.format, "h5:v2e");
  EXPECT_TRUE(rep.size_inferred);
  r.width = 64;
  r.height = 48;
  expect_same(ev, r);
  // Gev-RS without an override: the reference's 640x360.
  EXPECT_EQ(read_events(gev).width, 640);

  write_h5_dre(dre, ev);
  r = read_events(dre, o, &rep);
  EXPECT_EQ(rep.format, "h5:dre");
  expect_same(ev, r);
  const ImageTimestamps its = read_image_timestamps(dre);
  ASSERT_EQ(its.image_ts.size(), 3u);
  EXPECT_DOUBLE_EQ(its.image_ts[1], 1000.5);
  EXPECT_DOUBLE_EQ(its.start_image_ts[2], 1900.0);
  EXPECT_DOUBLE_EQ(its.end_image_ts[0], 100.0);
  EXPECT_THROW(read_image_timestamps(gev), Error);

  // DSEC: Blosc-compressed events/{x,y,p,t} (t relative, uint32) + t_offset + ms_to_idx.
  if (!write_h5_dsec(dsec, ev, 5000000)) GTEST_SKIP() << "the HDF5 Blosc filter (hdf5-filter-plugin-blosc-serial) is not available";
  r = read_events(dsec, o, &rep);
  EXPECT_EQ(rep.format, "h5:dsec");
  ASSERT_EQ(r.size(), ev.size());
  for (size_t i = 0; i < ev.size(); ++i) ASSERT_EQ(r.t[i], ev.t[i] + 5000000);
  EventReadOptions w = o;
  w.t_begin_us = 5000000 + ev.t[1000];
  w.t_end_us = 5000000 + ev.t[2000];
  r = read_events(dsec, w, &rep);
  size_t expect = 0;
  for (int64_t t : ev.t) expect += t + 5000000 >= *w.t_begin_us && t + 5000000 < *w.t_end_us;
  EXPECT_EQ(r.size(), expect);
  EXPECT_EQ(rep.records, expect);
  EXPECT_EQ(read_events(dsec).width, 640);
}

TEST(EventReadersHdf5, FloatSecondsBoolPolarityAndBadInput) {
  const std::string path = tmp("float.h5");
  {
    hid_t f = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    hid_t g = H5Gcreate2(f, "events", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    const double t[4] = {0.5, 0.000001, 1.25, NAN};
    const uint16_t x[4] = {1, 2, 3, 4}, y[4] = {0, 1, 2, 3};
    const int8_t p[4] = {1, 0, 1, 0};
    h5_write_1d(g, "t", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, t, 4);
    h5_write_1d(g, "x", H5T_STD_U16LE, H5T_NATIVE_UINT16, x, 4);
    h5_write_1d(g, "y", H5T_STD_U16LE, H5T_NATIVE_UINT16, y, 4);
    hid_t etype = H5Tenum_create(H5T_NATIVE_INT8);
    int8_t v0 = 0, v1 = 1;
    H5Tenum_insert(etype, "FALSE", &v0);
    H5Tenum_insert(etype, "TRUE", &v1);
    h5_write_1d(g, "p", etype, etype, p, 4);
    H5Tclose(etype);
    H5Gclose(g);
    H5Fclose(f);
  }
  EventReadOptions o;
  o.array_time_unit = "s";
  o.width = 8;
  o.height = 8;
  // 0.5 s then 1 us: out of order; then NaN.
  expect_error(path, o, {"float.h5", "record 1", "earlier than the previous"});
  o.on_bad = BadEventPolicy::sort;
  EventReadReport rep;
  const EventStream ev = read_events(path, o, &rep);
  ASSERT_EQ(ev.size(), 3u);
  EXPECT_EQ(ev.t[0], 1);
  EXPECT_EQ(ev.t[1], 500000);
  EXPECT_EQ(ev.t[2], 1250000);
  EXPECT_EQ(ev.p[0], -1);  // bool false
  EXPECT_EQ(ev.p[1], 1);
  EXPECT_EQ(rep.dropped_nan, 1u);
  EXPECT_TRUE(rep.sorted);

  // wrong dtype: strings for x
  const std::string bad = tmp("strings.h5");
  {
    hid_t f = H5Fcreate(bad.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    hid_t g = H5Gcreate2(f, "events", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    const int64_t t[2] = {1, 2};
    const uint16_t y[2] = {0, 1};
    const int8_t p[2] = {1, 0};
    hid_t st = H5Tcopy(H5T_C_S1);
    H5Tset_size(st, 4);
    const char xs[8] = {'1', 0, 0, 0, '2', 0, 0, 0};
    h5_write_1d(g, "t", H5T_STD_I64LE, H5T_NATIVE_INT64, t, 2);
    h5_write_1d(g, "x", st, st, xs, 2);
    h5_write_1d(g, "y", H5T_STD_U16LE, H5T_NATIVE_UINT16, y, 2);
    h5_write_1d(g, "p", H5T_STD_I8LE, H5T_NATIVE_INT8, p, 1);  // also a length mismatch, found later
    H5Tclose(st);
    H5Gclose(g);
    H5Fclose(f);
  }
  expect_error(bad, {}, {"strings.h5", "events/x", "string", "expected integer or float"});

  // truncated file
  const EventStream ok = random_stream(100000, 32, 32, 4);
  const std::string full = tmp("full.h5"), cut = tmp("cut.h5");
  write_events_hdf5(full, ok);
  std::vector<uint8_t> bytes;
  {
    std::ifstream f(full, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(f), {});
  }
  bytes.resize(bytes.size() / 2);
  write_bytes(cut, bytes);
  expect_error(cut, {}, {"cut.h5"});

  // no event datasets at all
  const std::string empty = tmp("none.h5");
  H5Fclose(H5Fcreate(empty.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT));
  expect_error(empty, {}, {"none.h5", "no event datasets"});
}

TEST(EventReadersHdf5, WriterRefusesBadStreams) {
  EventStream ev = random_stream(10, 8, 8, 5);
  ev.x[3] = 8;
  EXPECT_THROW(write_events_hdf5(tmp("refused.h5"), ev), Error);
  ev.x[3] = 0;
  ev.t[5] = -100;
  EXPECT_THROW(write_events_text(tmp("refused.txt"), ev), Error);
}

// ---- Prophesee -------------------------------------------------------------------------------

TEST(EventReaders, Evt2FromEncoder) {
  EventStream ev = random_stream(20000, 640, 480, 6);
  const std::string path = tmp("a.raw");
  write_bytes(path, encode_evt2(ev, "% evt 2.0\n% format EVT2;height=480;width=640\n% end\n"));
  EventReadReport rep;
  expect_same(ev, read_events(path, {}, &rep));
  EXPECT_EQ(rep.format, "evt2");
  EXPECT_EQ(detect_event_format(path), "evt2");
}

TEST(EventReadersEvt, Evt2UnknownWordsTriggersAndTruncation) {
  EventStream ev = random_stream(100, 640, 480, 7);
  auto bytes = encode_evt2(ev, "% geometry 640x480\n% evt 2.0\n");
  const size_t header = std::string("% geometry 640x480\n% evt 2.0\n").size();
  // a trigger word (ignored, counted) and an unknown word type 0x5 after the 10th word
  std::vector<uint8_t> extra;
  put32(extra, 0xA0000001u);
  put32(extra, 0x50000000u);
  bytes.insert(bytes.begin() + long(header + 40), extra.begin(), extra.end());
  const std::string path = tmp("unknown.raw");
  write_bytes(path, bytes);
  size_t cd_before = 0;  // CD words among the 10 words before the inserted ones
  for (size_t i = 0; i < 10; ++i) cd_before += (bytes[header + 4 * i + 3] >> 4) <= 1;
  const std::string at = "record " + std::to_string(cd_before) + " (byte " + std::to_string(header + 44) + ")";
  expect_error(path, {}, {"unknown.raw", "unknown EVT 2.0 word type 0x5", at.c_str()});
  EventReadOptions o;
  o.on_bad = BadEventPolicy::drop;
  EventReadReport rep;
  expect_same(ev, read_events(path, o, &rep));
  EXPECT_EQ(rep.dropped_unknown_word, 1u);
  EXPECT_EQ(rep.ignored.at("EXT_TRIGGER"), 1u);
  // truncated: two trailing bytes of a word (error), counted with drop
  bytes.resize(bytes.size() - 2);
  write_bytes(path, bytes);
  EXPECT_EQ(read_events(path, o, &rep).size(), ev.size() - 1);
  EXPECT_EQ(rep.dropped_unknown_word, 2u);
  auto clean = encode_evt2(ev, "% evt 2.0\n");
  clean.resize(clean.size() - 2);
  write_bytes(path, clean);
  expect_error(path, {}, {"unknown.raw", "truncated", "2 trailing bytes"});
}

TEST(EventReaders, Evt3FromEncoderWithVectorsAndTimeWrap) {
  // Rows of neighbouring events at one time make VECT_12/VECT_8 words; start near the 24-bit wrap.
  EventStream ev;
  ev.width = 1280;
  ev.height = 720;
  std::mt19937 rng(8);
  int64_t t = (int64_t(1) << 24) - 3000;
  for (int k = 0; k < 3000; ++k) {
    t += int64_t(rng() % 5);
    const uint16_t y = uint16_t(rng() % 720), x0 = uint16_t(rng() % 1260);
    const int8_t p = (rng() & 1) ? 1 : -1;
    const int n = 1 + int(rng() % 6);
    uint16_t x = x0;
    for (int i = 0; i < n; ++i) {
      ev.push(t, x, y, p);
      x = uint16_t(x + 1 + rng() % 2);
    }
  }
  ASSERT_GT(ev.t.back(), int64_t(1) << 24);
  const std::string path = tmp("b.raw");
  const auto bytes = encode_evt3(ev, "% evt 3.0\n% plugin_name hal_plugin_gen41_evk3\n% end\n", true);
  EXPECT_LT(bytes.size(), ev.size() * 2 + 20000);  // vectors really were used
  write_bytes(path, bytes);
  EventReadReport rep;
  expect_same(ev, read_events(path, {}, &rep));
  EXPECT_EQ(rep.format, "evt3");

  EventReadOptions o;
  o.t_begin_us = ev.t[ev.size() / 2];
  o.t_end_us = ev.t[ev.size() * 3 / 4];
  const EventStream w = read_events(path, o, &rep);
  size_t expect = 0;
  for (int64_t tt : ev.t) expect += tt >= *o.t_begin_us && tt < *o.t_end_us;
  EXPECT_EQ(w.size(), expect);
  EXPECT_TRUE(rep.stopped_early);
  EXPECT_LT(rep.records, ev.size());
}

TEST(EventReadersEvt, Evt3OutOfSensorUnknownWordAndNoGeometry) {
  EventStream ev = random_stream(50, 1280, 720, 9);
  auto bytes = encode_evt3(ev, "% evt 3.0\n% format EVT3;height=720;width=1280\n", false);
  put16(bytes, 0x8000 | uint16_t((ev.t.back() >> 12) & 0xFFF));
  put16(bytes, 0x0000 | 719);
  put16(bytes, 0x2000 | 1300);  // x = 1300 on a 1280-wide sensor
  put16(bytes, 0x9000);         // unknown type 0x9
  const std::string path = tmp("c.raw");
  write_bytes(path, bytes);
  expect_error(path, {}, {"c.raw", "record 50", "x=1300", "1280x720"});
  EventReadOptions o;
  o.on_bad = BadEventPolicy::drop;
  EventReadReport rep;
  expect_same(ev, read_events(path, o, &rep));
  EXPECT_EQ(rep.dropped_out_of_sensor, 1u);
  EXPECT_EQ(rep.dropped_unknown_word, 1u);
  // a header that says neither encoding nor geometry: detection asks for --format
  const std::string bare = tmp("bare.raw");
  write_bytes(bare, encode_evt3(ev, "% date today\n", false));
  expect_error(bare, {}, {"bare.raw", "pass format"});
  o = {};
  o.format = "evt3";
  const EventStream r = read_events(bare, o, &rep);
  EXPECT_TRUE(rep.size_inferred);
  EXPECT_EQ(r.size(), ev.size());
}

TEST(EventReaders, DatFromEncoderWithWindowSeek) {
  const EventStream ev = random_stream(50000, 304, 240, 10);
  const std::string path = tmp("d.dat");
  write_bytes(path, encode_dat(ev));
  EventReadReport rep;
  expect_same(ev, read_events(path, {}, &rep));
  EXPECT_EQ(rep.format, "dat");
  EventReadOptions o;
  o.t_begin_us = ev.t[40000];
  o.t_end_us = ev.t[40100] + 1;
  const EventStream w = read_events(path, o, &rep);
  size_t expect = 0;
  for (int64_t t : ev.t) expect += t >= *o.t_begin_us && t < *o.t_end_us;
  EXPECT_EQ(w.size(), expect);
  EXPECT_LT(rep.records, expect + 10);  // binary search: the records before the window were not read
  auto bytes = encode_dat(ev);
  bytes.resize(bytes.size() - 3);
  write_bytes(path, bytes);
  expect_error(path, {}, {"d.dat", "truncated"});
}

TEST(EventReaders, RealEvt3SampleYieldsExactCount) {
  const std::string path = vktest::real_recording("evt3_sample.raw");
  EventReadReport rep;
  const EventStream ev = read_events(path, {}, &rep);
  EXPECT_EQ(ev.size(), 219596u);
  EXPECT_EQ(rep.format, "evt3");
  EXPECT_EQ(ev.width, 1280);
  EXPECT_EQ(ev.height, 720);
  EXPECT_EQ(rep.dropped(), 0u);
  EXPECT_TRUE(std::is_sorted(ev.t.begin(), ev.t.end()));
  size_t on = 0;
  for (int8_t p : ev.p) on += p > 0;
  EXPECT_GT(on, 0u);
  EXPECT_LT(on, ev.size());
}

// ---- AEDAT 4 ----------------------------------------------------------------------------------

TEST(EventReaders, Aedat4FromEncoderLz4ZstdNone) {
  const EventStream ev = random_stream(12000, 346, 260, 11);
  for (int compression : {0, 1, 3}) {
    const std::string path = tmp("e" + std::to_string(compression) + ".aedat4");
    write_bytes(path, encode_aedat4(ev, compression));
    EventReadReport rep;
    expect_same(ev, read_events(path, {}, &rep));
    EXPECT_EQ(rep.format, "aedat4");
    EXPECT_EQ(rep.ignored.size(), 1u);
    EXPECT_EQ(rep.ignored.begin()->second, 3u) << rep.summary();  // the IMU packet's 3 elements
    EventReadOptions o;
    o.t_begin_us = ev.t[7500];
    o.t_end_us = ev.t[8500];
    const EventStream w = read_events(path, o, &rep);
    size_t expect = 0;
    for (int64_t t : ev.t) expect += t >= *o.t_begin_us && t < *o.t_end_us;
    EXPECT_EQ(w.size(), expect);
    EXPECT_LE(rep.records, 3000u) << "the data table should skip packets outside the window";
  }
}

TEST(EventReadersAedat4, TruncatedAndCorrupt) {
  const EventStream ev = random_stream(3000, 64, 48, 12);
  auto bytes = encode_aedat4(ev, 1, 1000, false);
  const std::string path = tmp("t.aedat4");
  bytes.resize(bytes.size() - 100);
  write_bytes(path, bytes);
  expect_error(path, {}, {"t.aedat4", "truncated"});
  EventReadOptions o;
  o.on_bad = BadEventPolicy::drop;
  EventReadReport rep;
  EXPECT_EQ(read_events(path, o, &rep).size(), 2000u);
  EXPECT_EQ(rep.dropped_unknown_word, 1u);
  // corrupt the middle of the first compressed packet
  bytes = encode_aedat4(ev, 1, 1000, false);
  const size_t header = 18 + size_t(bytes[14] | (bytes[15] << 8));
  for (size_t i = header + 40; i < header + 80; ++i) bytes[i] ^= 0x5A;
  write_bytes(path, bytes);
  expect_error(path, {}, {"t.aedat4", "packet at byte"});
  write_bytes(path, text_bytes("#!AER-DAT4.0\r\n\x10\x00\x00"));
  expect_error(path, {}, {"t.aedat4"});
}

TEST(EventReaders, RealAedat4SampleYieldsExactCount) {
  const std::string path = vktest::real_recording("sample.aedat4");
  EventReadReport rep;
  const EventStream ev = read_events(path, {}, &rep);
  EXPECT_EQ(ev.size(), 111954u);
  EXPECT_EQ(ev.width, 320);
  EXPECT_EQ(ev.height, 240);
  EXPECT_EQ(rep.dropped(), 0u);
  ASSERT_EQ(rep.ignored.size(), 1u) << rep.summary();
  EXPECT_GT(rep.ignored.begin()->second, 0u);  // IMU samples counted, not read
  // A window through the data table returns exactly the events of the full read in that window.
  EventReadOptions o;
  o.t_begin_us = ev.t[40000];
  o.t_end_us = ev.t[60000];
  const EventStream w = read_events(path, o, &rep);
  size_t expect = 0;
  for (int64_t t : ev.t) expect += t >= *o.t_begin_us && t < *o.t_end_us;
  EXPECT_EQ(w.size(), expect);
  EXPECT_LT(rep.records, 40000u);
}

// ---- NumPy ------------------------------------------------------------------------------------

TEST(EventReaders, NpyNx4DtypesOrdersAndRecords) {
  const EventStream ev = random_stream(4000, 346, 260, 13);
  EventReadOptions o;
  o.width = 346;
  o.height = 260;
  struct Case {
    std::string name;
    std::vector<uint8_t> bytes;
  };
  const std::vector<Case> cases = {
      {"i8", encode_npy_nx4<int64_t>(ev, "<i8")},
      {"f8", encode_npy_nx4<double>(ev, "<f8", true)},
      {"u4f", encode_npy_nx4<uint32_t>(ev, "<u4", false, true)},
      {"i4pm", encode_npy_nx4<int32_t>(ev, "<i4", true)},
      {"rec", encode_npy_record(ev)},
  };
  for (const auto& c : cases) {
    const std::string path = tmp(c.name + ".npy");
    write_bytes(path, c.bytes);
    EventReadReport rep;
    SCOPED_TRACE(c.name);
    expect_same(ev, read_events(path, o, &rep));
    EventReadOptions w = o;
    w.t_begin_us = ev.t[1000];
    w.t_end_us = ev.t[1200];
    size_t expect = 0;
    for (int64_t t : ev.t) expect += t >= *w.t_begin_us && t < *w.t_end_us;
    EXPECT_EQ(read_events(path, w, &rep).size(), expect);
    EXPECT_EQ(rep.records, expect);
  }
}

TEST(EventReadersNumpy, BadDtypesShapesAndTruncation) {
  const EventStream ev = random_stream(10, 8, 8, 14);
  const std::string path = tmp("bad.npy");
  write_bytes(path, encode_npy("{'descr': '<U4', 'fortran_order': False, 'shape': (10, 4), }", std::vector<uint8_t>(160)));
  expect_error(path, {}, {"bad.npy", "'<U4'", "expected bool, integer"});
  write_bytes(path, encode_npy("{'descr': '<i8', 'fortran_order': False, 'shape': (10, 3), }", std::vector<uint8_t>(240)));
  expect_error(path, {}, {"bad.npy", "shape (10, 3)", "N x 4"});
  write_bytes(path, encode_npy("{'descr': [('x', '<u2'), ('y', '<u2'), ('t', '<i8')], 'fortran_order': False, 'shape': (2,), }",
                               std::vector<uint8_t>(24)));
  expect_error(path, {}, {"bad.npy", "without a 'p' field"});
  auto bytes = encode_npy_nx4<int64_t>(ev, "<i8");
  bytes.resize(bytes.size() - 9);
  write_bytes(path, bytes);
  expect_error(path, {}, {"bad.npy", "truncated"});
  write_bytes(path, text_bytes(std::string("\x93NUMPY\x01\x00\x30\x00", 10) + "{'descr': '<i8'"));
  expect_error(path, {}, {"bad.npy", "header"});
  // NaN time in a float array
  EventStream f = ev;
  auto fb = encode_npy_nx4<double>(f, "<f8");
  const double nan = NAN;
  std::memcpy(fb.data() + (fb.size() - 10 * 32) + 5 * 32, &nan, 8);
  write_bytes(path, fb);
  expect_error(path, {}, {"bad.npy", "record 5", "NaN"});
  EventReadOptions o;
  o.on_bad = BadEventPolicy::drop;
  EventReadReport rep;
  EXPECT_EQ(read_events(path, o, &rep).size(), 9u);
  EXPECT_EQ(rep.dropped_nan, 1u);
}

TEST(EventReaders, NpzFromNumpyStoredCompressedRecordSeparate) {
  if (!python_has("numpy")) GTEST_SKIP() << "/usr/bin/python3 with numpy is not available";
  const std::string dir = tmp("");
  run_python("import numpy as np\n"
             "rng = np.random.default_rng(0)\n"
             "n = 5000\n"
             "t = np.sort(rng.integers(0, 10**6, n)); x = rng.integers(0, 346, n); y = rng.integers(0, 260, n)\n"
             "p = rng.integers(0, 2, n)\n"
             "a = np.stack([t, x, y, p], 1)\n"
             "np.savez('" + dir + "/nx4.npz', event=a.astype(np.float64))\n"
             "np.savez_compressed('" + dir + "/nx4c.npz', event=a)\n"
             "r = np.zeros(n, dtype=[('x', '<u2'), ('y', '<u2'), ('p', '?'), ('t', '<i8')])\n"
             "r['x'] = x; r['y'] = y; r['p'] = p.astype(bool); r['t'] = t\n"
             "np.savez_compressed('" + dir + "/rec.npz', event=r)\n"
             "np.savez('" + dir + "/sep.npz', x=x, y=y, p=p * 2 - 1, t=t)\n"
             "np.savez('" + dir + "/two.npz', a=a, b=a)\n"
             "np.savetxt('" + dir + "/ref.txt', a, fmt='%d')\n");
  EventReadOptions o;
  o.width = 346;
  o.height = 260;
  o.text_columns = "txyp";
  const EventStream ref = read_events(dir + "/ref.txt", o);
  ASSERT_EQ(ref.size(), 5000u);
  for (const char* name : {"nx4", "nx4c", "rec", "sep"}) {
    SCOPED_TRACE(name);
    EventReadReport rep;
    expect_same(ref, read_events(dir + "/" + name + ".npz", o, &rep));
    EventReadOptions w = o;
    w.t_begin_us = ref.t[2000];
    w.t_end_us = ref.t[2500];
    size_t expect = 0;
    for (int64_t t : ref.t) expect += t >= *w.t_begin_us && t < *w.t_end_us;
    EXPECT_EQ(read_events(dir + "/" + name + ".npz", w, &rep).size(), expect);
  }
  expect_error(dir + "/two.npz", {}, {"two.npz", "cannot tell which array", "a, b"});
}

// ---- HDF5 from h5py (the writers users actually have) ------------------------------------------

TEST(EventReadersHdf5, FromH5pyDsecBloscAndBoolPolarity) {
  if (!python_has("h5py, numpy")) GTEST_SKIP() << "/usr/bin/python3 with h5py and numpy is not available";
  const std::string dir = tmp("");
  run_python("import h5py, numpy as np\n"
             "rng = np.random.default_rng(1)\n"
             "n = 20000\n"
             "t = np.sort(rng.integers(0, 3 * 10**6, n)).astype(np.uint32)\n"
             "x = rng.integers(0, 640, n).astype(np.uint16); y = rng.integers(0, 480, n).astype(np.uint16)\n"
             "p = rng.integers(0, 2, n).astype(np.uint8)\n"
             "with h5py.File('" + dir + "/h5py_dsec.h5', 'w') as f:\n"
             "    f.create_dataset('events/t', data=t, chunks=True, compression=32001)\n"
             "    f.create_dataset('events/x', data=x, chunks=True, compression=32001)\n"
             "    f.create_dataset('events/y', data=y, chunks=True, compression=32001)\n"
             "    f.create_dataset('events/p', data=p, chunks=True, compression=32001)\n"
             "    f['t_offset'] = np.int64(7 * 10**9)\n"
             "    f['ms_to_idx'] = np.searchsorted(t, np.arange(0, 3001) * 1000).astype(np.uint64)\n"
             "with h5py.File('" + dir + "/h5py_bool.h5', 'w') as f:\n"
             "    f['events/t'] = t.astype(np.int64); f['events/x'] = x; f['events/y'] = y; f['events/p'] = p.astype(bool)\n"
             "np.savetxt('" + dir + "/h5ref.txt', np.stack([t.astype(np.int64) + 7 * 10**9, x, y, p], 1), fmt='%d')\n");
  EventReadOptions o;
  o.width = 640;
  o.height = 480;
  const EventStream ref = read_events(dir + "/h5ref.txt", o);
  EventReadReport rep;
  expect_same(ref, read_events(dir + "/h5py_dsec.h5", o, &rep));
  EXPECT_EQ(rep.format, "h5:dsec");
  const EventStream b = read_events(dir + "/h5py_bool.h5", o, &rep);
  ASSERT_EQ(b.size(), ref.size());
  for (size_t i = 0; i < b.size(); ++i) ASSERT_EQ(b.p[i], ref.p[i]);
  EventReadOptions w = o;
  w.t_begin_us = 7000000000 + 1500000;
  w.t_end_us = 7000000000 + 1600000;
  size_t expect = 0;
  for (int64_t t : ref.t) expect += t >= *w.t_begin_us && t < *w.t_end_us;
  EXPECT_EQ(read_events(dir + "/h5py_dsec.h5", w, &rep).size(), expect);
  EXPECT_EQ(rep.records, expect);
}

// ---- streaming and CLI --------------------------------------------------------------------------

TEST(EventReaders, ScanEventsDeliversChunksInOrder) {
  const EventStream ev = random_stream(30000, 64, 48, 15);
  const std::string path = tmp("scan.h5");
  write_events_hdf5(path, ev);
  EventStream joined;
  size_t chunks = 0;
  const uint64_t n = scan_events(path, {}, [&](const EventStream& c) {
    ++chunks;
    EXPECT_LE(c.size(), 4096u);
    EXPECT_EQ(c.width, 64);
    for (size_t i = 0; i < c.size(); ++i) joined.push(c.t[i], c.x[i], c.y[i], c.p[i]);
  }, nullptr, 4096);
  EXPECT_EQ(n, ev.size());
  EXPECT_GE(chunks, 8u);
  joined.width = 64;
  joined.height = 48;
  expect_same(ev, joined);
}

TEST(EventReaders, CliEventsPrintsCountsAndDrops) {
  const std::string path = tmp("cli.txt");
  write_file(path, "# width 10 height 10\n1 1 1 1\n2 12 1 1\n3 2 2 0\n2 3 3 1\n");
  const std::string out = tmp("cli.out");
  const std::string cmd = std::string(VKUNROLL_CLI_PATH) + " events " + path + " --on-bad drop > " + out + " 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0);
  std::ifstream f(out);
  const std::string text((std::istreambuf_iterator<char>(f)), {});
  EXPECT_NE(text.find("events      2"), std::string::npos) << text;
  EXPECT_NE(text.find("sensor      10x10"), std::string::npos) << text;
  EXPECT_NE(text.find("out of sensor 1, time order 1"), std::string::npos) << text;
  EXPECT_NE(text.find("polarity    1 on (+1), 1 off (-1)"), std::string::npos) << text;
  const std::string bad = std::string(VKUNROLL_CLI_PATH) + " events " + path + " > " + out + " 2>&1";
  EXPECT_NE(std::system(bad.c_str()), 0);
  std::ifstream g(out);
  const std::string err((std::istreambuf_iterator<char>(g)), {});
  EXPECT_NE(err.find("record 1 (line 3)"), std::string::npos) << err;
}
