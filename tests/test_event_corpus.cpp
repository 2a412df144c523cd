// The fuzz corpus as regression inputs (every reader over every committed corpus and crash file)
// and the fuzzers' findings, each as a test.
#include <gtest/gtest.h>
#include <hdf5.h>

#include <filesystem>
#include <fstream>
#include <functional>

#include "event_test_encoders.hpp"
#include "event_test_util.hpp"
#include "../fuzz/fuzz_common.hpp"
#include "../fuzz/fuzz_index.hpp"
#include "../fuzz/hdf5_image_builder.hpp"
#include "vkunroll/host/events/event_formats.hpp"
#include "vkunroll/host/events/event_reader.hpp"
#include "vkunroll/host/events/event_reader_detail.hpp"
#include "vkunroll/base/error.hpp"

namespace fs = std::filesystem;
using namespace vkunroll;
using namespace vkunroll::evtest;

// ---- fuzz corpus and findings -----------------------------------------------------------------

// Every reader over every committed corpus and crash file (tests/fuzz_corpus/<reader>/*), the way
// the libFuzzer harnesses call them: each must return or throw vkunroll::Error.
TEST(EventReadersFuzzCorpus, EveryReaderSurvivesEveryCorpusFile) {
  const fs::path root = fs::path(VKUNROLL_SOURCE_DIR) / "tests" / "fuzz_corpus";
  ASSERT_TRUE(fs::exists(root)) << root;
  using detail::ByteSource;
  using detail::EventSink;
  size_t files = 0;
  for (const auto& dir : fs::directory_iterator(root)) {
    if (!dir.is_directory()) continue;
    for (const auto& entry : fs::directory_iterator(dir.path())) {
      std::ifstream f(entry.path(), std::ios::binary);
      const std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(f)), {});
      SCOPED_TRACE(entry.path().string());
      ++files;
      // Every reader of the format table: a byte source, or the bytes as an in-memory file (but
      // HDF5, whose harness builds a file from them below: raw bytes would fuzz libhdf5 itself).
      for (const EventFormat& row : event_formats()) {
        const std::string name = "corpus." + std::string(row.name);
        SCOPED_TRACE(name);
        if (row.read_bytes) {
          EXPECT_NO_THROW(fuzz::run_reader(bytes.data(), bytes.size(), name.c_str(), row.read_bytes));
        } else if (row.fuzzer != "hdf5") {
          EXPECT_NO_THROW(fuzz::run_reader(bytes.data(), bytes.size(), name.c_str(), [&](ByteSource&, EventSink& sink) {
            row.read_image(name, bytes.data(), bytes.size(), sink);
          }));
        }
      }
      // The HDF5 harness also builds a file from the bytes (fuzz/hdf5_image_builder.hpp).
      EXPECT_NO_THROW({
        fuzz::FuzzBytes fb(bytes.data(), bytes.size());
        const EventReadOptions o = fuzz::options_from(fb);
        const std::vector<uint8_t> image = fuzz::build_file(fb);
        if (!image.empty()) {
          EventReadReport rep;
          try {
            EventSink sink("corpus.h5", o, rep);
            detail::read_hdf5("corpus.h5", image.data(), image.size(), sink);
            EXPECT_EQ(sink.finish().size(), rep.kept);
          } catch (const Error&) {
          }
        }
      });
    }
  }
  EXPECT_GE(files, 20u);
}

// The index's differential check (fuzz/fuzz_index.hpp) over every corpus file: indexed windows
// equal the full scan, and throw where it throws.
TEST(EventReadersFuzzCorpus, IndexMatchesTheFullScanOnEveryCorpusFile) {
  const fs::path root = fs::path(VKUNROLL_SOURCE_DIR) / "tests" / "fuzz_corpus";
  size_t files = 0, index_files = 0;
  for (const auto& dir : fs::directory_iterator(root)) {
    if (!dir.is_directory()) continue;
    for (const auto& entry : fs::directory_iterator(dir.path())) {
      const std::vector<uint8_t> bytes = read_bytes(entry.path().string());
      SCOPED_TRACE(entry.path().string());
      EXPECT_TRUE(fuzz::index_matches_full_scan(bytes.data(), bytes.size()));
      ++files;
      index_files += dir.path().filename() == "index";
    }
  }
  EXPECT_GE(index_files, 8u);
  EXPECT_GE(files, 20u);
}

// Fuzz finding (aedat4): a packet that decompressed to fewer than 12 bytes was compared with
// "EVTS" past its end (heap overflow). Now a clear error.
TEST(EventReadersFuzzCorpus, Aedat4TinyPacketIsAnError) {
  const fs::path crash = fs::path(VKUNROLL_SOURCE_DIR) / "tests/fuzz_corpus/aedat4/crash-f9f37f955c8e1d6a94ef3091934124ebed5377fc";
  ASSERT_TRUE(fs::exists(crash));
  const std::string path = tmp("tiny.aedat4");
  fs::copy_file(crash, path, fs::copy_options::overwrite_existing);
  expect_error(path, {}, {"tiny.aedat4", "corrupt flatbuffer"});
}

// Fuzz finding (hdf5): events/t + t_offset overflowed int64 (undefined behaviour). Now the record
// breaks the time rule: an error, or dropped and counted.
TEST(EventReadersFuzzCorpus, DsecTimeOffsetOverflowIsAnError) {
  const std::string path = tmp("overflow.h5");
  {
    hid_t f = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    hid_t g = H5Gcreate2(f, "events", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    const uint32_t t[2] = {5, 3000000000u};
    const uint16_t x[2] = {1, 2}, y[2] = {1, 2};
    const uint8_t p[2] = {1, 0};
    h5_write_1d(g, "t", H5T_STD_U32LE, H5T_NATIVE_UINT32, t, 2);
    h5_write_1d(g, "x", H5T_STD_U16LE, H5T_NATIVE_UINT16, x, 2);
    h5_write_1d(g, "y", H5T_STD_U16LE, H5T_NATIVE_UINT16, y, 2);
    h5_write_1d(g, "p", H5T_STD_U8LE, H5T_NATIVE_UINT8, p, 2);
    const int64_t off = INT64_MAX - 100;
    hid_t s = H5Screate(H5S_SCALAR);
    hid_t d = H5Dcreate2(f, "t_offset", H5T_STD_I64LE, s, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    H5Dwrite(d, H5T_NATIVE_INT64, H5S_ALL, H5S_ALL, H5P_DEFAULT, &off);
    H5Dclose(d);
    H5Sclose(s);
    H5Gclose(g);
    H5Fclose(f);
  }
  // Record 0 (INT64_MAX - 95) is already beyond the shared time rule; record 1 overflows int64.
  expect_error(path, {}, {"overflow.h5", "record 0", "beyond +-2^53 us"});
  EventReadOptions o;
  o.on_bad = BadEventPolicy::drop;
  EventReadReport rep;
  EXPECT_EQ(read_events(path, o, &rep).size(), 0u);
  EXPECT_EQ(rep.dropped_nan, 2u);
}

// Fuzz finding (hdf5, 10-minute run): a float ms_to_idx holding 1e169 was converted to int64
// (undefined behaviour) during a window read. Now an error naming the dataset.
TEST(EventReadersFuzzCorpus, FloatIndexOutOfRangeIsAnError) {
  const EventStream ev = random_stream(100, 16, 12, 16);
  const std::string path = tmp("float_index.h5");
  {
    hid_t f = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    hid_t g = H5Gcreate2(f, "events", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    std::vector<int8_t> p(ev.size());
    for (size_t i = 0; i < ev.size(); ++i) p[i] = ev.p[i] > 0 ? 1 : 0;
    h5_write_1d(g, "t", H5T_STD_I64LE, H5T_NATIVE_INT64, ev.t.data(), ev.size());
    h5_write_1d(g, "x", H5T_STD_U16LE, H5T_NATIVE_UINT16, ev.x.data(), ev.size());
    h5_write_1d(g, "y", H5T_STD_U16LE, H5T_NATIVE_UINT16, ev.y.data(), ev.size());
    h5_write_1d(g, "p", H5T_STD_I8LE, H5T_NATIVE_INT8, p.data(), ev.size());
    const double ms[2] = {0.0, 1.13531e169};
    h5_write_1d(f, "ms_to_idx", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, ms, 2);
    H5Gclose(g);
    H5Fclose(f);
  }
  EXPECT_EQ(read_events(path).size(), ev.size());  // the index is only used for windows
  EventReadOptions o;
  o.t_begin_us = ev.t[10];
  expect_error(path, o, {"float_index.h5", "ms_to_idx", "not an integer index"});
}
