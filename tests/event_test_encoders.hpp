// Small encoders for the event formats, written from the format descriptions (not from the
// readers), so the reader tests read files that a test builds. Also used by fuzz/make_seeds.
#pragma once
#include <flatbuffers/flatbuffers.h>
#include <hdf5.h>
#include <lz4frame.h>
#include <zstd.h>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "vkunroll/base/events.hpp"

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


// ---- Prophesee --------------------------------------------------------------------------------

inline void put16(std::vector<uint8_t>& b, uint16_t v) {
  b.push_back(uint8_t(v));
  b.push_back(uint8_t(v >> 8));
}
inline void put32(std::vector<uint8_t>& b, uint32_t v) {
  for (int i = 0; i < 4; ++i) b.push_back(uint8_t(v >> (8 * i)));
}

inline std::vector<uint8_t> text_bytes(const std::string& s) { return std::vector<uint8_t>(s.begin(), s.end()); }

// EVT 2.0: TIME_HIGH (t >> 6) whenever it changes, CD_ON/CD_OFF words with the low 6 bits.
inline std::vector<uint8_t> encode_evt2(const EventStream& ev, const std::string& header) {
  std::vector<uint8_t> b = text_bytes(header);
  int64_t th = -1;
  for (size_t i = 0; i < ev.size(); ++i) {
    const int64_t h = ev.t[i] >> 6;
    if (h != th) {
      put32(b, (0x8u << 28) | uint32_t(h & 0x0FFFFFFF));
      th = h;
    }
    put32(b, (uint32_t(ev.p[i] > 0 ? 1 : 0) << 28) | (uint32_t(ev.t[i] & 63) << 22) | (uint32_t(ev.x[i]) << 11) | ev.y[i]);
  }
  return b;
}

// EVT 3.0: TIME_HIGH / TIME_LOW / ADDR_Y on change; runs of events with the same t, y, p and
// increasing x inside 12 columns become VECT_BASE_X + VECT_12 (or VECT_8) when `vectors`.
inline std::vector<uint8_t> encode_evt3(const EventStream& ev, const std::string& header, bool vectors) {
  std::vector<uint8_t> b = text_bytes(header);
  int64_t th = -1, tl = -1, cy = -1;
  for (size_t i = 0; i < ev.size();) {
    const int64_t h = (ev.t[i] >> 12) & 0xFFF, l = ev.t[i] & 0xFFF;
    if (h != th || (ev.t[i] >> 24) != ((i ? ev.t[i - 1] : ev.t[i]) >> 24)) put16(b, uint16_t(0x8000 | h)), th = h;
    if (l != tl) put16(b, uint16_t(0x6000 | l)), tl = l;
    if (ev.y[i] != cy) put16(b, uint16_t(0x0000 | ev.y[i])), cy = ev.y[i];
    const int pol = ev.p[i] > 0 ? 1 : 0;
    size_t j = i + 1;
    if (vectors)
      while (j < ev.size() && ev.t[j] == ev.t[i] && ev.y[j] == ev.y[i] && ev.p[j] == ev.p[i] && ev.x[j] > ev.x[j - 1] &&
             ev.x[j] < ev.x[i] + 12)
        ++j;
    if (j - i >= 2) {
      put16(b, uint16_t(0x3000 | (pol << 11) | ev.x[i]));
      uint32_t mask = 0;
      for (size_t k = i; k < j; ++k) mask |= 1u << (ev.x[k] - ev.x[i]);
      if (mask < 256 && (j - i) % 2 == 0) put16(b, uint16_t(0x5000 | mask));  // VECT_8 sometimes
      else put16(b, uint16_t(0x4000 | mask));
      i = j;
    } else {
      put16(b, uint16_t(0x2000 | (pol << 11) | ev.x[i]));
      ++i;
    }
  }
  return b;
}

// .dat: '%' header with Width/Height, type 0x0C and size 8, then {u32 t, u32 p<<28 | y<<14 | x}.
inline std::vector<uint8_t> encode_dat(const EventStream& ev) {
  std::vector<uint8_t> b = text_bytes("% Data file containing CD events.\n% Version 2\n% Width " + std::to_string(ev.width) +
                                      "\n% Height " + std::to_string(ev.height) + "\n");
  b.push_back(0x0C);
  b.push_back(8);
  for (size_t i = 0; i < ev.size(); ++i) {
    put32(b, uint32_t(ev.t[i]));
    put32(b, (uint32_t(ev.p[i] > 0 ? 1 : 0) << 28) | (uint32_t(ev.y[i]) << 14) | ev.x[i]);
  }
  return b;
}

// ---- AEDAT 4 ------------------------------------------------------------------------------------

// compression: 0 none, 1 LZ4, 3 zstd.
inline std::vector<uint8_t> aedat_compress(const std::vector<uint8_t>& in, int compression) {
  if (compression == 0) return in;
  std::vector<uint8_t> out;
  if (compression == 1 || compression == 2) {
    out.resize(LZ4F_compressFrameBound(in.size(), nullptr));
    out.resize(LZ4F_compressFrame(out.data(), out.size(), in.data(), in.size(), nullptr));
  } else {
    out.resize(ZSTD_compressBound(in.size()));
    out.resize(ZSTD_compress(out.data(), out.size(), in.data(), in.size(), 3));
  }
  return out;
}

struct AedatPacketHeaderFb {
  int32_t stream, size;
};

struct Aedat4Packet {
  int32_t stream;
  std::vector<uint8_t> payload;
  int64_t n, t0, t1;
};

// The file's data table (FTAB): each packet's offset, stream, event count and time span, compressed.
inline std::vector<uint8_t> aedat4_packet_table(const std::vector<Aedat4Packet>& packets, const std::vector<int64_t>& offsets,
                                                int compression) {
  flatbuffers::FlatBufferBuilder b;
  std::vector<flatbuffers::uoffset_t> defs;
  for (size_t i = 0; i < packets.size(); ++i) {
    const auto start = b.StartTable();
    b.AddElement<int64_t>(4, offsets[i], 0);
    const AedatPacketHeaderFb ph{packets[i].stream, int32_t(0)};
    b.AddStruct(6, &ph);
    b.AddElement<int64_t>(8, packets[i].n, 0);
    b.AddElement<int64_t>(10, packets[i].t0, 0);
    b.AddElement<int64_t>(12, packets[i].t1, 0);
    defs.push_back(b.EndTable(start));
  }
  b.StartVector(defs.size(), sizeof(flatbuffers::uoffset_t));
  for (size_t i = defs.size(); i-- > 0;) b.PushElement(flatbuffers::Offset<void>(defs[i]));
  const auto vec = b.EndVector(defs.size());
  const auto start = b.StartTable();
  b.AddOffset(4, flatbuffers::Offset<void>(vec));
  b.FinishSizePrefixed(flatbuffers::Offset<flatbuffers::Table>(b.EndTable(start)), "FTAB");
  return aedat_compress(std::vector<uint8_t>(b.GetBufferPointer(), b.GetBufferPointer() + b.GetSize()), compression);
}

// Events in packets of `per_packet`, an IMU packet (stream 1) after the first event packet, and
// a data table unless `with_table` is false. Times must be sorted.
inline std::vector<uint8_t> encode_aedat4(const EventStream& ev, int compression, size_t per_packet = 1000,
                                          bool with_table = true) {
  const std::string xml =
      "<dv version=\"2.0\">\n<node name=\"outInfo\" path=\"/mainloop/Recorder/outInfo/\">\n"
      "<node name=\"0\" path=\"/mainloop/Recorder/outInfo/0/\">\n"
      "<attr key=\"compression\" type=\"string\">X</attr>\n<attr key=\"originalOutputName\" type=\"string\">events</attr>\n"
      "<attr key=\"typeIdentifier\" type=\"string\">EVTS</attr>\n"
      "<node name=\"info\" path=\"/mainloop/Recorder/outInfo/0/info/\">\n<attr key=\"sizeX\" type=\"int\">" +
      std::to_string(ev.width) + "</attr>\n<attr key=\"sizeY\" type=\"int\">" + std::to_string(ev.height) +
      "</attr>\n</node>\n</node>\n"
      "<node name=\"1\" path=\"/mainloop/Recorder/outInfo/1/\">\n<attr key=\"originalOutputName\" type=\"string\">imu</attr>\n"
      "<attr key=\"typeIdentifier\" type=\"string\">IMUS</attr>\n</node>\n</node>\n</dv>\n";
  std::vector<Aedat4Packet> packets;
  auto event_packet = [&](size_t a, size_t e) {
    flatbuffers::FlatBufferBuilder b;
    uint8_t* mem = nullptr;
    const auto vec = b.CreateUninitializedVector(e - a, 16, &mem);
    for (size_t i = a; i < e; ++i, mem += 16) {
      std::memset(mem, 0, 16);
      const int64_t t = ev.t[i];
      const int16_t x = int16_t(ev.x[i]), y = int16_t(ev.y[i]);
      std::memcpy(mem, &t, 8);
      std::memcpy(mem + 8, &x, 2);
      std::memcpy(mem + 10, &y, 2);
      mem[12] = ev.p[i] > 0 ? 1 : 0;
    }
    const auto start = b.StartTable();
    b.AddOffset(4, flatbuffers::Offset<void>(vec));
    b.FinishSizePrefixed(flatbuffers::Offset<flatbuffers::Table>(b.EndTable(start)), "EVTS");
    packets.push_back({0, std::vector<uint8_t>(b.GetBufferPointer(), b.GetBufferPointer() + b.GetSize()), int64_t(e - a),
                       ev.t[a], ev.t[e - 1]});
  };
  auto imu_packet = [&](int64_t t) {
    flatbuffers::FlatBufferBuilder b;
    uint8_t* mem = nullptr;
    const auto vec = b.CreateUninitializedVector(3, 48, &mem);
    std::memset(mem, 0, 3 * 48);
    const auto start = b.StartTable();
    b.AddOffset(4, flatbuffers::Offset<void>(vec));
    b.FinishSizePrefixed(flatbuffers::Offset<flatbuffers::Table>(b.EndTable(start)), "IMUS");
    packets.push_back({1, std::vector<uint8_t>(b.GetBufferPointer(), b.GetBufferPointer() + b.GetSize()), 3, t, t});
  };
  for (size_t a = 0; a < ev.size(); a += per_packet) {
    event_packet(a, std::min(ev.size(), a + per_packet));
    if (a == 0) imu_packet(ev.t[0]);
  }
  auto header = [&](int64_t table_pos) {
    flatbuffers::FlatBufferBuilder b;
    b.ForceDefaults(true);
    const auto info = b.CreateString(xml);
    const auto start = b.StartTable();
    b.AddElement<int32_t>(4, compression, 0);
    b.AddElement<int64_t>(6, table_pos, -1);
    b.AddOffset(8, info);
    b.Finish(flatbuffers::Offset<flatbuffers::Table>(b.EndTable(start)), "IOHE");
    return std::vector<uint8_t>(b.GetBufferPointer(), b.GetBufferPointer() + b.GetSize());
  };
  const size_t hsize = header(0).size();
  std::vector<uint8_t> body;
  std::vector<int64_t> offsets;
  const uint64_t data_begin = 14 + 4 + hsize;
  for (const auto& p : packets) {
    const auto c = aedat_compress(p.payload, compression);
    offsets.push_back(int64_t(data_begin + body.size() + 8));
    put32(body, uint32_t(p.stream));
    put32(body, uint32_t(c.size()));
    body.insert(body.end(), c.begin(), c.end());
  }
  const int64_t table_pos = with_table ? int64_t(data_begin + body.size()) : -1;
  std::vector<uint8_t> file = text_bytes("#!AER-DAT4.0\r\n");
  const auto h = header(table_pos);
  put32(file, uint32_t(h.size()));
  file.insert(file.end(), h.begin(), h.end());
  file.insert(file.end(), body.begin(), body.end());
  if (with_table) {
    const auto c = aedat4_packet_table(packets, offsets, compression);
    file.insert(file.end(), c.begin(), c.end());
  }
  return file;
}

// ---- NumPy ----------------------------------------------------------------------------------------

// A .npy v1.0 file with the given header dict text and raw data bytes.
inline std::vector<uint8_t> encode_npy(const std::string& dict, const std::vector<uint8_t>& data) {
  std::string h = dict;
  while ((10 + h.size() + 1) % 64) h += ' ';
  h += '\n';
  std::vector<uint8_t> b = text_bytes("\x93NUMPY");
  b.push_back(1);
  b.push_back(0);
  put16(b, uint16_t(h.size()));
  b.insert(b.end(), h.begin(), h.end());
  b.insert(b.end(), data.begin(), data.end());
  return b;
}

// N x 4 array of `T` (t, x, y, p with p 1/0 or -1/+1).
template <class T>
std::vector<uint8_t> encode_npy_nx4(const EventStream& ev, const std::string& descr, bool pm1 = false, bool fortran = false) {
  std::vector<uint8_t> data(ev.size() * 4 * sizeof(T));
  auto put = [&](size_t r, size_t c, T v) {
    const size_t idx = fortran ? c * ev.size() + r : r * 4 + c;
    std::memcpy(data.data() + idx * sizeof(T), &v, sizeof(T));
  };
  for (size_t i = 0; i < ev.size(); ++i) {
    put(i, 0, T(ev.t[i]));
    put(i, 1, T(ev.x[i]));
    put(i, 2, T(ev.y[i]));
    put(i, 3, T(ev.p[i] > 0 ? 1 : (pm1 ? -1 : 0)));
  }
  return encode_npy("{'descr': '" + descr + "', 'fortran_order': " + (fortran ? "True" : "False") + ", 'shape': (" +
                        std::to_string(ev.size()) + ", 4), }",
                    data);
}

// Record array with fields x <u2, y <u2, p |b1, t <i8 (Gev-RS-Real's order).
inline std::vector<uint8_t> encode_npy_record(const EventStream& ev) {
  std::vector<uint8_t> data;
  for (size_t i = 0; i < ev.size(); ++i) {
    put16(data, ev.x[i]);
    put16(data, ev.y[i]);
    data.push_back(ev.p[i] > 0 ? 1 : 0);
    const uint64_t t = uint64_t(ev.t[i]);
    for (int k = 0; k < 8; ++k) data.push_back(uint8_t(t >> (8 * k)));
  }
  return encode_npy("{'descr': [('x', '<u2'), ('y', '<u2'), ('p', '|b1'), ('t', '<i8')], 'fortran_order': False, "
                    "'shape': (" + std::to_string(ev.size()) + ",), }",
                    data);
}

}  // namespace vkunroll::evtest
