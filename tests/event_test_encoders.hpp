// Small encoders for the event formats, written from the format descriptions (not from the
// readers), so the reader tests read files that a test builds. Also used by fuzz/make_seeds.
#pragma once
#include <hdf5.h>

#include <cstdint>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "host/events.hpp"

namespace vkunroll::evtest {

// Sorted random stream (repeated timestamps included), polarity +1/-1.
inline EventStream random_stream(size_t n, int w, int h, uint32_t seed, int64_t t0 = 1000, int max_gap = 7) {
  std::mt19937 rng(seed);
  EventStream s;
  s.width = w;
  s.height = h;
  s.reserve(n);
  int64_t t = t0;
  for (size_t i = 0; i < n; ++i) {
    t += int64_t(rng() % uint32_t(max_gap + 1));
    s.push(t, uint16_t(rng() % uint32_t(w)), uint16_t(rng() % uint32_t(h)), (rng() & 1) ? 1 : -1);
  }
  return s;
}

// ---- HDF5 helpers ------------------------------------------------------------------------------

inline void h5_write_1d(hid_t loc, const char* name, hid_t file_type, hid_t mem_type, const void* data, hsize_t n,
                        hid_t dcpl = H5P_DEFAULT) {
  hsize_t dims[1] = {n};
  hid_t space = H5Screate_simple(1, dims, nullptr);
  hid_t d = H5Dcreate2(loc, name, file_type, space, H5P_DEFAULT, dcpl, H5P_DEFAULT);
  if (n) H5Dwrite(d, mem_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data);
  H5Dclose(d);
  H5Sclose(space);
}

// `events` N x 4 (t, x, y, p with p 1/0) in `file_type`; Gev-RS adds img_to_idx.
inline void write_h5_nx4(const std::string& path, const EventStream& ev, hid_t file_type, bool img_to_idx) {
  hid_t f = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
  std::vector<int64_t> rows(ev.size() * 4);
  for (size_t i = 0; i < ev.size(); ++i) {
    rows[4 * i] = ev.t[i];
    rows[4 * i + 1] = ev.x[i];
    rows[4 * i + 2] = ev.y[i];
    rows[4 * i + 3] = ev.p[i] > 0 ? 1 : 0;
  }
  hsize_t dims[2] = {ev.size(), 4};
  hid_t space = H5Screate_simple(2, dims, nullptr);
  hid_t d = H5Dcreate2(f, "events", file_type, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
  H5Dwrite(d, H5T_NATIVE_INT64, H5S_ALL, H5S_ALL, H5P_DEFAULT, rows.data());
  H5Dclose(d);
  H5Sclose(space);
  if (img_to_idx) {
    const int64_t idx[4] = {0, int64_t(ev.size() / 3), int64_t(2 * ev.size() / 3), int64_t(ev.size())};
    h5_write_1d(f, "img_to_idx", H5T_STD_I64LE, H5T_NATIVE_INT64, idx, 4);
  }
  H5Fclose(f);
}

// DRE: top-level x, y, p, t + image_ts (float, 1000.5 at [1]), start_image_ts, end_image_ts.
inline void write_h5_dre(const std::string& path, const EventStream& ev) {
  hid_t f = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
  std::vector<uint8_t> p(ev.size());
  for (size_t i = 0; i < ev.size(); ++i) p[i] = ev.p[i] > 0 ? 1 : 0;
  h5_write_1d(f, "x", H5T_STD_U16LE, H5T_NATIVE_UINT16, ev.x.data(), ev.size());
  h5_write_1d(f, "y", H5T_STD_U16LE, H5T_NATIVE_UINT16, ev.y.data(), ev.size());
  h5_write_1d(f, "p", H5T_STD_U8LE, H5T_NATIVE_UINT8, p.data(), ev.size());
  h5_write_1d(f, "t", H5T_STD_I64LE, H5T_NATIVE_INT64, ev.t.data(), ev.size());
  const double its[3] = {50.0, 1000.5, 1950.0};
  const int64_t start[3] = {0, 950, 1900}, end[3] = {100, 1050, 2000};
  h5_write_1d(f, "image_ts", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, its, 3);
  h5_write_1d(f, "start_image_ts", H5T_STD_I64LE, H5T_NATIVE_INT64, start, 3);
  h5_write_1d(f, "end_image_ts", H5T_STD_I64LE, H5T_NATIVE_INT64, end, 3);
  H5Fclose(f);
}

// DSEC: events/{x,y,p,t} Blosc-compressed (filter 32001), t uint32 relative to t_offset, ms_to_idx.
// Returns false when the Blosc filter cannot be used.
inline bool write_h5_dsec(const std::string& path, const EventStream& ev, int64_t t_offset) {
  if (H5Zfilter_avail(32001) <= 0) {
    // Dynamically loaded filters become available on first use; try a probe dataset.
  }
  hid_t f = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
  hid_t g = H5Gcreate2(f, "events", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
  hid_t dcpl = H5Pcreate(H5P_DATASET_CREATE);
  hsize_t chunk[1] = {512};
  H5Pset_chunk(dcpl, 1, chunk);
  const unsigned cd[7] = {0, 0, 0, 0, 5, 1, 1};  // clevel 5, shuffle, blosclz
  H5Pset_filter(dcpl, 32001, H5Z_FLAG_MANDATORY, 7, cd);
  std::vector<uint32_t> t(ev.size());
  std::vector<uint8_t> p(ev.size());
  for (size_t i = 0; i < ev.size(); ++i) {
    t[i] = uint32_t(ev.t[i]);
    p[i] = ev.p[i] > 0 ? 1 : 0;
  }
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  hsize_t dims[1] = {ev.size()};
  hid_t space = H5Screate_simple(1, dims, nullptr);
  hid_t probe = H5Dcreate2(g, "x", H5T_STD_U16LE, space, H5P_DEFAULT, dcpl, H5P_DEFAULT);
  H5Sclose(space);
  const bool ok = probe >= 0 && H5Dwrite(probe, H5T_NATIVE_UINT16, H5S_ALL, H5S_ALL, H5P_DEFAULT, ev.x.data()) >= 0;
  if (probe >= 0) H5Dclose(probe);
  if (ok) {
    h5_write_1d(g, "y", H5T_STD_U16LE, H5T_NATIVE_UINT16, ev.y.data(), ev.size(), dcpl);
    h5_write_1d(g, "p", H5T_STD_U8LE, H5T_NATIVE_UINT8, p.data(), ev.size(), dcpl);
    h5_write_1d(g, "t", H5T_STD_U32LE, H5T_NATIVE_UINT32, t.data(), ev.size(), dcpl);
    hid_t s = H5Screate(H5S_SCALAR);
    hid_t d = H5Dcreate2(f, "t_offset", H5T_STD_I64LE, s, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    H5Dwrite(d, H5T_NATIVE_INT64, H5S_ALL, H5S_ALL, H5P_DEFAULT, &t_offset);
    H5Dclose(d);
    H5Sclose(s);
    std::vector<uint64_t> ms;
    size_t i = 0;
    const int64_t last = ev.empty() ? 0 : ev.t.back();
    for (int64_t m = 0; m * 1000 <= last; ++m) {
      while (i < ev.size() && ev.t[i] < m * 1000) ++i;
      ms.push_back(i);
    }
    h5_write_1d(f, "ms_to_idx", H5T_STD_U64LE, H5T_NATIVE_UINT64, ms.data(), ms.size());
  }
  H5Pclose(dcpl);
  H5Gclose(g);
  H5Fclose(f);
  return ok;
}

}  // namespace vkunroll::evtest
