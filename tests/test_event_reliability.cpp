// Issue 18 in the event readers: each finding as a test that failed before its fix, then the
// hostile inputs of our own campaign (docs/reliability.md, "Events and sequences"), each with the
// clear error or the handling it gets.
#include <gtest/gtest.h>
#include <hdf5.h>

#include <cstring>
#include <filesystem>
#include <fstream>

#include "event_test_encoders.hpp"
#include "event_test_util.hpp"
#include "vk_test_env.hpp"
#include "vkunroll/base/error.hpp"
#include "vkunroll/host/events/event_file_reader.hpp"
#include "vkunroll/host/events/event_reader.hpp"

namespace fs = std::filesystem;
using namespace vkunroll;
using namespace vkunroll::evtest;

namespace {

// Offset of the first byte of member data after the zip local header starting at `at`.
size_t member_data(const std::vector<uint8_t>& zip, size_t at) {
  const size_t name = zip[at + 26] | (zip[at + 27] << 8), extra = zip[at + 28] | (zip[at + 29] << 8);
  return at + 30 + name + extra;
}

}  // namespace

// A flipped byte in an .npz member was read as good events (numpy refuses the file).
TEST(EventReliability, NpzMemberCrcIsChecked) {
  const EventStream ev = random_stream(5000, 64, 48, 50);
  const auto npy = encode_npy_nx4<int64_t>(ev, "<i8");
  for (const bool deflate : {false, true}) {
    SCOPED_TRACE(deflate ? "deflated" : "stored");
    const std::string p = tmp(deflate ? "crc_deflated.npz" : "crc_stored.npz");
    write_npz(p, {{"event.npy", npy}}, deflate);
    EventReadOptions o;
    o.on_bad = BadEventPolicy::drop;  // a flipped byte must not pass as a dropped or a good event
    EXPECT_EQ(read_events(p, o).size(), ev.size());
    std::vector<uint8_t> z = read_bytes(p);
    ASSERT_EQ(std::memcmp(z.data(), "PK\x03\x04", 4), 0);
    const size_t data = member_data(z, 0);
    // Stored: an x coordinate's low byte (still a valid pixel); deflated: a byte mid-stream.
    const size_t at = deflate ? data + (z.size() - data) / 3 : data + 128 + 8 * 4 * 100 + 8;
    z[at] ^= 0x01;
    write_bytes(p, z);
    for (const BadEventPolicy policy : {BadEventPolicy::error, BadEventPolicy::drop, BadEventPolicy::sort}) {
      o.on_bad = policy;
      const std::string e = error_of([&] { read_events(p, o); });
      EXPECT_NE(e.find(p + ": member 'event' is corrupt"), std::string::npos) << e;
      if (!deflate) {
        EXPECT_NE(e.find("CRC-32"), std::string::npos) << e;
      }
      o.t_begin_us = ev.t[100];  // a window read checks the whole member too
      EXPECT_NE(error_of([&] { read_events(p, o); }).find("corrupt"), std::string::npos);
      EXPECT_NE(error_of([&] { EventFileReader(p, o).read(ev.t[10], ev.t[20]); }).find("corrupt"), std::string::npos);
      o.t_begin_us.reset();
    }
    if (python_has("numpy")) {  // numpy refuses the same file
      const std::string cmd = "/usr/bin/python3 -c \"import numpy as np; np.load('" + p + "')['event']\" 2>/dev/null";
      EXPECT_NE(std::system(cmd.c_str()), 0);
    }
  }
}

// `inf` was reported as "NaN"; a time beyond int64 was reported as infinite.
TEST(EventReliability, InfiniteAndHugeTextTimesAreNamedAsSuch) {
  const std::string p = tmp("inf.txt");
  write_file(p, "inf 1 2 1\n");
  expect_error(p, {}, {"inf.txt", "record 0 (line 1)", "time is +infinity", "use on_bad drop"});
  write_file(p, "-Infinity 1 2 1\n");
  expect_error(p, {}, {"time is -infinity"});
  write_file(p, "nan 1 2 1\n");
  expect_error(p, {}, {"time is NaN"});
  write_file(p, "1e400 1 2 1\n");
  expect_error(p, {}, {"time '1e400' (us) is beyond +-2^53 us"});
  EventReadOptions o;
  o.on_bad = BadEventPolicy::drop;
  EventReadReport rep;
  write_file(p, "10 1 2 1\ninf 1 2 1\n1e400 1 2 1\n20 1 2 1\n");
  EXPECT_EQ(read_events(p, o, &rep).size(), 2u);
  EXPECT_EQ(rep.dropped_nan, 2u);
  EXPECT_NE(rep.summary().find("2 NaN/inf time"), std::string::npos) << rep.summary();
}

// An EVT3 file named .txt gave an error cut after two raw bytes.
TEST(EventReliability, BinaryFileReadAsTextSaysWhatItLooksLike) {
  std::vector<uint8_t> b = read_bytes(vktest::real_recording("evt3_sample.raw"));
  ASSERT_GT(b.size(), 20000u);
  b.resize(20000);
  const std::string p = tmp("evt3_named.txt");
  write_bytes(p, b);
  expect_error(p, {}, {"evt3_named.txt", "not a text event file", "binary", "Prophesee EVT 3.0", "format evt3", ".raw"});
  EventReadOptions o;
  o.format = "txt";  // forced: the same answer
  expect_error(p, o, {"Prophesee EVT 3.0", "format evt3"});
  const std::string a = tmp("aedat_named.csv");
  write_bytes(a, encode_aedat4(random_stream(100, 64, 48, 52), 1, 50));
  o.format = "txt";
  expect_error(a, o, {"aedat_named.csv", "AEDAT 4", "format aedat4"});
  const std::string g = tmp("garbage.txt");
  write_bytes(g, std::vector<uint8_t>{0x01, 0x02, 0x00, 0xff, 0x10, '\n', 0x00});
  expect_error(g, {}, {"garbage.txt", "byte 0 is binary (0x01)", "match no event format"});
  // A text file with one stray control byte in a line is not binary: the line is a clear bad record.
  write_file(g, "10 1 2 1\n20 1\x01 2 1\n");
  expect_error(g, {}, {"record 1 (line 2)", "\\x01"});
}

// A UTF-8 byte-order mark before a CSV header made the header unreadable: the default column order
// was used and the columns were read as the wrong fields without a word.
TEST(EventReliability, ByteOrderMarkBeforeCsvHeader) {
  const std::string p = tmp("bom.csv");
  write_file(p, "\xEF\xBB\xBFx,y,timestamp,polarity\n1,2,10,1\n3,4,20,0\n");
  EventReadReport rep;
  const EventStream ev = read_events(p, {}, &rep);
  ASSERT_EQ(ev.size(), 2u);
  EXPECT_EQ(ev.t[0], 10);
  EXPECT_EQ(ev.x[1], 3);
  EXPECT_EQ(ev.y[1], 4);
}

// Our own campaign against the readers: each hostile input gets a clear error naming the file and
// what was expected (or is handled, as noted).
TEST(EventReliability, HostileInputsGetClearErrors) {
  const EventStream ev = random_stream(400, 64, 48, 53);
  struct Case {
    std::string name;
    std::vector<uint8_t> bytes;
    std::vector<const char*> expect;
  };
  const auto evt3 = encode_evt3(ev, "% evt 3.0\n% geometry 64x48\n", true);
  const auto evt2 = encode_evt2(ev, "% evt 2.0\n% geometry 64x48\n");
  const auto dat = encode_dat(ev);
  const auto aed = encode_aedat4(ev, 3, 50);
  const auto npy = encode_npy_nx4<int64_t>(ev, "<i8");
  std::vector<Case> cases = {
      {"trunc.raw", {evt3.begin(), evt3.end() - 1}, {"ends inside a 16-bit EVT 3.0 word", "truncated"}},
      {"trunc2.raw", {evt2.begin(), evt2.end() - 3}, {"ends inside a 32-bit EVT 2.0 word"}},
      {"trunc.dat", {dat.begin(), dat.end() - 5}, {"ends inside a 8-byte .dat record"}},
      {"trunc.aedat4", {aed.begin(), aed.begin() + long(aed.size() * 2 / 3)}, {"truncated AEDAT 4"}},
      {"hdr.aedat4", {aed.begin(), aed.begin() + 60}, {"header size", "does not fit the file"}},
      {"trunc.npy", {npy.begin(), npy.end() - 9}, {"truncated file"}},
      {"noheader.raw", text_bytes("no header at all"), {"Prophesee header does not say the encoding", "pass format"}},
      {"evt21.raw", text_bytes("% evt 2.1\nxxxx"), {"record 0 (byte 10)", "ends inside a 64-bit EVT 2.1 word", "truncated file"}},
      {"hugeline.raw", text_bytes("% " + std::string(70000, 'x') + "\n"), {"longer than 64 KiB"}},
      {"neg.txt", text_bytes("10 -1 2 1\n"), {"record 0 (line 1)", "x=-1", "outside"}},
      {"neg.npy", [] {
         std::vector<uint8_t> d;
         for (int64_t v : {int64_t(10), int64_t(-1), int64_t(2), int64_t(1)})
           for (int k = 0; k < 8; ++k) d.push_back(uint8_t(uint64_t(v) >> (8 * k)));
         return encode_npy("{'descr': '<i8', 'fortran_order': False, 'shape': (1, 4), }", d);
       }(), {"record 0", "x=-1", "outside"}},
      {"order.txt", text_bytes("10 1 2 1\n5 1 2 1\n"), {"record 1 (line 2)", "earlier than the previous"}},
      {"pol.txt", text_bytes("10 1 2 0.5\n"), {"polarity '0.5'"}},
      {"fields.txt", text_bytes("10 1 2\n"), {"has 3 fields, expected at least 4"}},
      {"longline.txt", text_bytes(std::string(70000, '1')), {"longer than 65536 bytes"}},
      {"shape.npy", encode_npy("{'descr': '<i8', 'fortran_order': False, 'shape': (10, 3), }", std::vector<uint8_t>(240)),
       {"shape (10, 3)", "expected N x 4"}},
      {"dims.npy", encode_npy("{'descr': '<i8', 'fortran_order': False, 'shape': (5, 2, 2), }", std::vector<uint8_t>(160)),
       {"shape (5, 2, 2)"}},
      {"dtype.npy", encode_npy("{'descr': '<U4', 'fortran_order': False, 'shape': (1, 4), }", std::vector<uint8_t>(64)),
       {"dtype '<U4'"}},
      {"bighdr.npy", [] {
         std::vector<uint8_t> b = text_bytes("\x93NUMPY");
         b.insert(b.end(), {2, 0, 0, 0, 0x20, 0});  // v2 header of 2 MiB
         return b;
       }(), {"implausible"}},
      {"notzip.npz", text_bytes("PK\x03\x04 but not a zip"), {"not a readable .npz"}},
      {"unknown.bin", text_bytes("hello"), {"cannot tell the event format", "pass format"}},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    const std::string p = tmp(c.name);
    write_bytes(p, c.bytes);
    std::vector<const char*> expect = c.expect;
    const std::string name = c.name;
    expect.push_back(name.c_str());
    try {
      read_events(p, {});
      ADD_FAILURE() << "expected an error";
    } catch (const Error& e) {
      for (const char* f : expect) EXPECT_NE(std::string(e.what()).find(f), std::string::npos) << "'" << f << "' in " << e.what();
    }
  }
  // Truncated word formats: with on_bad=drop the partial word (the last event's) is dropped and
  // counted, the rest kept.
  EventReadOptions o;
  o.on_bad = BadEventPolicy::drop;
  EventReadReport rep;
  EXPECT_EQ(read_events(tmp("trunc.raw"), o, &rep).size(), ev.size() - 1);
  EXPECT_EQ(rep.dropped_unknown_word, 1u);
  // A folder, a missing file, a sensor override out of range.
  expect_error(fs::temp_directory_path().string(), {}, {"is a folder"});
  expect_error(tmp("does_not_exist.txt"), {}, {"does_not_exist.txt", "does not exist"});
  o = {};
  o.width = 70000, o.height = 10;
  write_file(tmp("ok.txt"), "10 1 2 1\n");
  expect_error(tmp("ok.txt"), o, {"sensor size override 70000x10 is invalid"});
  o = {};
  o.t_begin_us = 100, o.t_end_us = 50;
  expect_error(tmp("ok.txt"), o, {"time window [100, 50) us ends before it begins"});
}

// HDF5 files that are not what they claim: mismatched lengths, strings, truncation.
TEST(EventReliability, HostileHdf5GetsClearErrors) {
  const std::string lens = tmp("lens.h5"), strs = tmp("strs.h5"), cut = tmp("cut.h5");
  const int64_t t[4] = {1, 2, 3, 4};
  const uint16_t x[4] = {1, 2, 3, 4};
  const uint8_t p[4] = {1, 0, 1, 0};
  {
    hid_t f = H5Fcreate(lens.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    hid_t g = H5Gcreate2(f, "events", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    h5_write_1d(g, "t", H5T_STD_I64LE, H5T_NATIVE_INT64, t, 4);
    h5_write_1d(g, "x", H5T_STD_U16LE, H5T_NATIVE_UINT16, x, 3);
    h5_write_1d(g, "y", H5T_STD_U16LE, H5T_NATIVE_UINT16, x, 4);
    h5_write_1d(g, "p", H5T_STD_U8LE, H5T_NATIVE_UINT8, p, 4);
    H5Gclose(g);
    H5Fclose(f);
  }
  expect_error(lens, {}, {"lens.h5", "different lengths", "x 3"});
  {
    hid_t f = H5Fcreate(strs.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    hid_t g = H5Gcreate2(f, "events", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    hid_t st = H5Tcopy(H5T_C_S1);
    H5Tset_size(st, 8);
    const char s[4][8] = {"a", "b", "c", "d"};
    h5_write_1d(g, "t", st, st, s, 4);
    h5_write_1d(g, "x", H5T_STD_U16LE, H5T_NATIVE_UINT16, x, 4);
    h5_write_1d(g, "y", H5T_STD_U16LE, H5T_NATIVE_UINT16, x, 4);
    h5_write_1d(g, "p", H5T_STD_U8LE, H5T_NATIVE_UINT8, p, 4);
    H5Tclose(st);
    H5Gclose(g);
    H5Fclose(f);
  }
  expect_error(strs, {}, {"strs.h5", "events/t", "type class string"});
  write_events_hdf5(cut, random_stream(20000, 64, 48, 54));
  std::vector<uint8_t> b = read_bytes(cut);
  b.resize(b.size() / 2);
  write_bytes(cut, b);
  expect_error(cut, {}, {"cut.h5"});
}
