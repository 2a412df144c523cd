// Event readers: every format read from a file this test writes, round trips through the
// writers, the real samples, every bad-input rule, and the fuzz corpus as regression inputs.
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
#include "host/event_reader.hpp"
#include "runtime/error.hpp"
#include "vk_test_env.hpp"

namespace fs = std::filesystem;
using namespace vkunroll;
using namespace vkunroll::evtest;

namespace {

// A folder of this test process; removed at exit by the OS's tmp cleaning, not relied on.
std::string tmp(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("vkunroll_readers_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  return (dir / name).string();
}

void write_file(const std::string& path, const std::string& text) {
  std::ofstream f(path, std::ios::binary);
  f << text;
}

void write_bytes(const std::string& path, const std::vector<uint8_t>& b) {
  std::ofstream f(path, std::ios::binary);
  f.write(reinterpret_cast<const char*>(b.data()), std::streamsize(b.size()));
}

// Expects read_events to throw vkunroll::Error whose message contains every fragment.
void expect_error(const std::string& path, const EventReadOptions& o, std::initializer_list<const char*> fragments) {
  try {
    read_events(path, o);
    ADD_FAILURE() << path << ": expected an error";
  } catch (const Error& e) {
    const std::string msg = e.what();
    for (const char* f : fragments) EXPECT_NE(msg.find(f), std::string::npos) << "missing '" << f << "' in: " << msg;
  }
}

void expect_same(const EventStream& a, const EventStream& b) {
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a.t[i], b.t[i]) << "event " << i;
    ASSERT_EQ(a.x[i], b.x[i]) << "event " << i;
    ASSERT_EQ(a.y[i], b.y[i]) << "event " << i;
    ASSERT_EQ(a.p[i], b.p[i]) << "event " << i;
  }
}

[[maybe_unused]] bool python_has(const std::string& modules) {
  const std::string cmd = "/usr/bin/python3 -c 'import " + modules + "' >/dev/null 2>&1";
  return std::system(cmd.c_str()) == 0;
}

[[maybe_unused]] void run_python(const std::string& code) {
  const std::string script = tmp("script.py");
  write_file(script, code);
  ASSERT_EQ(std::system(("/usr/bin/python3 " + script).c_str()), 0) << code;
}

}  // namespace

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
