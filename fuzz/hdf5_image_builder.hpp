// Builds an HDF5 file image in memory from fuzzer bytes: the layout, each column's dtype, lengths,
// values, attributes and indexes all come from the bytes (see fuzz_hdf5.cpp for why). Shared by the
// libFuzzer harness and the GoogleTest that replays tests/fuzz_corpus/hdf5.
#pragma once
#include <hdf5.h>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "vkunroll/host/events/event_reader.hpp"

namespace vkunroll::fuzz {

// Consumes the fuzzer's bytes front to back; past the end every value is 0/false.
class FuzzBytes {
 public:
  FuzzBytes(const uint8_t* data, size_t size) : d_(data), n_(size) {}
  template <class T>
  T any() {
    T v{};
    uint8_t b[sizeof(T)] = {};
    for (size_t i = 0; i < sizeof(T) && pos_ < n_; ++i) b[i] = d_[pos_++];
    std::memcpy(&v, b, sizeof(T));
    return v;
  }
  template <class T>
  T range(T lo, T hi) {
    const uint64_t span = uint64_t(hi) - uint64_t(lo) + 1;
    return span == 0 ? T(lo + T(any<uint64_t>())) : T(lo + T(any<uint32_t>() % span));
  }
  bool boolean() { return any<uint8_t>() & 1; }
  std::vector<uint8_t> bytes(size_t n) {
    const size_t k = std::min(n, n_ - pos_);
    std::vector<uint8_t> v(d_ + pos_, d_ + pos_ + k);
    pos_ += k;
    return v;
  }

 private:
  const uint8_t* d_;
  size_t n_;
  size_t pos_ = 0;
};

inline hid_t pick_type(FuzzBytes& fdp, size_t& elem) {
  switch (fdp.range<int>(0, 11)) {
    case 0: elem = 1; return H5Tcopy(H5T_STD_I8LE);
    case 1: elem = 1; return H5Tcopy(H5T_STD_U8LE);
    case 2: elem = 2; return H5Tcopy(H5T_STD_I16LE);
    case 3: elem = 2; return H5Tcopy(H5T_STD_U16BE);
    case 4: elem = 4; return H5Tcopy(H5T_STD_I32LE);
    case 5: elem = 4; return H5Tcopy(H5T_STD_U32LE);
    case 6: elem = 8; return H5Tcopy(H5T_STD_I64LE);
    case 7: elem = 8; return H5Tcopy(H5T_STD_U64LE);
    case 8: elem = 4; return H5Tcopy(H5T_IEEE_F32LE);
    case 9: elem = 8; return H5Tcopy(H5T_IEEE_F64BE);
    case 10: {
      elem = 1;
      hid_t e = H5Tenum_create(H5T_NATIVE_INT8);
      int8_t v0 = 0, v1 = 1;
      H5Tenum_insert(e, "FALSE", &v0);
      H5Tenum_insert(e, "TRUE", &v1);
      return e;
    }
    default: {
      elem = 3;
      hid_t s = H5Tcopy(H5T_C_S1);
      H5Tset_size(s, 3);
      return s;
    }
  }
}

// A dataset of `dims` with a fuzzed type and raw fuzzed bytes as its values (file = memory type).
inline void dataset(FuzzBytes& fdp, hid_t loc, const char* name, std::vector<hsize_t> dims) {
  size_t elem = 1;
  hid_t type = pick_type(fdp, elem);
  hsize_t count = 1;
  for (hsize_t d : dims) count *= d;
  std::vector<uint8_t> bytes = fdp.bytes(size_t(count) * elem);
  bytes.resize(size_t(count) * elem, 0);
  hid_t space = H5Screate_simple(int(dims.size()), dims.data(), nullptr);
  hid_t dcpl = H5Pcreate(H5P_DATASET_CREATE);
  if (fdp.boolean() && count > 0) {
    std::vector<hsize_t> chunk(dims.size(), 1);
    chunk[0] = std::max<hsize_t>(1, std::min<hsize_t>(dims[0], 1 + fdp.range<hsize_t>(0, 16)));
    for (size_t i = 1; i < dims.size(); ++i) chunk[i] = std::max<hsize_t>(dims[i], 1);
    H5Pset_chunk(dcpl, int(dims.size()), chunk.data());
  }
  hid_t d = H5Dcreate2(loc, name, type, space, H5P_DEFAULT, dcpl, H5P_DEFAULT);
  if (d >= 0) {
    if (count) H5Dwrite(d, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, bytes.data());
    H5Dclose(d);
  }
  H5Pclose(dcpl);
  H5Sclose(space);
  H5Tclose(type);
}

inline void int_attr(FuzzBytes& fdp, hid_t obj, const char* name) {
  const int64_t v = fdp.boolean() ? fdp.range<int64_t>(-2, 70000) : fdp.any<int64_t>();
  hid_t s = H5Screate(H5S_SCALAR);
  hid_t a = H5Acreate2(obj, name, H5T_STD_I64LE, s, H5P_DEFAULT, H5P_DEFAULT);
  if (a >= 0) {
    H5Awrite(a, H5T_NATIVE_INT64, &v);
    H5Aclose(a);
  }
  H5Sclose(s);
}

inline std::vector<uint8_t> build_file(FuzzBytes& fdp) {
  hid_t fapl = H5Pcreate(H5P_FILE_ACCESS);
  H5Pset_fapl_core(fapl, 1 << 16, false);
  hid_t f = H5Fcreate("fuzz-build.h5", H5F_ACC_TRUNC, H5P_DEFAULT, fapl);
  H5Pclose(fapl);
  if (f < 0) return {};
  const int layout = fdp.range<int>(0, 3);
  const hsize_t n = fdp.range<hsize_t>(0, 48);
  auto len = [&]() { return fdp.range<int>(0, 15) == 0 ? n + 1 : n; };  // sometimes mismatched
  if (layout == 0 || layout == 1) {
    hid_t g = H5Gcreate2(f, "events", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    for (const char* c : {"t", "x", "y", "p"}) dataset(fdp, g, c, {len()});
    if (fdp.boolean()) int_attr(fdp, g, "width");
    if (fdp.boolean()) int_attr(fdp, g, "height");
    H5Gclose(g);
    if (layout == 1) {
      if (fdp.boolean()) {
        hid_t s = H5Screate(H5S_SCALAR);
        hid_t d = H5Dcreate2(f, "t_offset", H5T_STD_I64LE, s, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
        const int64_t off = fdp.any<int64_t>();
        H5Dwrite(d, H5T_NATIVE_INT64, H5S_ALL, H5S_ALL, H5P_DEFAULT, &off);
        H5Dclose(d);
        H5Sclose(s);
      }
      dataset(fdp, f, "ms_to_idx", {fdp.range<hsize_t>(0, 8)});
    }
  } else if (layout == 2) {
    dataset(fdp, f, "events", {n, fdp.range<hsize_t>(3, 5)});
    if (fdp.boolean()) dataset(fdp, f, "img_to_idx", {fdp.range<hsize_t>(0, 4)});
  } else {
    for (const char* c : {"x", "y", "p", "t"}) dataset(fdp, f, c, {len()});
    if (fdp.boolean()) dataset(fdp, f, "image_ts", {3});
  }
  H5Fflush(f, H5F_SCOPE_GLOBAL);
  const ssize_t size = H5Fget_file_image(f, nullptr, 0);
  std::vector<uint8_t> image(size > 0 ? size_t(size) : 0);
  if (size > 0) H5Fget_file_image(f, image.data(), image.size());
  H5Fclose(f);
  return image;
}


// Read options chosen by the bytes (consumed before the file).
inline EventReadOptions options_from(FuzzBytes& fdp) {
  EventReadOptions o;
  o.on_bad = static_cast<BadEventPolicy>(fdp.range<int>(0, 2));
  if (fdp.boolean()) o.t_begin_us = fdp.range<int64_t>(-100, 100000);
  if (fdp.boolean()) o.t_end_us = fdp.range<int64_t>(-100, 100000);
  if (fdp.boolean()) o.width = 64, o.height = 48;
  static const char* units[] = {"", "s", "ms", "us", "ns", "minutes"};
  o.array_time_unit = units[fdp.range<int>(0, 5)];
  return o;
}

}  // namespace vkunroll::fuzz
