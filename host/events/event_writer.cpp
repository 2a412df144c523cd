// Writers of the project's two event layouts (sequence-format.md): events.h5 and events.txt.
#include <hdf5.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "vkunroll/host/events/event_writer.hpp"
#include "vkunroll/base/error.hpp"

namespace vkunroll {

namespace {

void check_stream(const std::string& path, const EventStream& ev) {
  const size_t n = ev.t.size();
  if (ev.x.size() != n || ev.y.size() != n || ev.p.size() != n)
    throw DataError(path + ": cannot write events: arrays have different lengths (t " + std::to_string(n) + ", x " +
                std::to_string(ev.x.size()) + ", y " + std::to_string(ev.y.size()) + ", p " + std::to_string(ev.p.size()) + ")");
  for (size_t i = 0; i < n; ++i) {
    if ((ev.width > 0 && ev.x[i] >= ev.width) || (ev.height > 0 && ev.y[i] >= ev.height))
      throw DataError(path + ": cannot write events: event " + std::to_string(i) + " at x=" + std::to_string(ev.x[i]) +
                  " y=" + std::to_string(ev.y[i]) + " is outside the " + std::to_string(ev.width) + "x" +
                  std::to_string(ev.height) + " sensor");
    if (ev.p[i] != 1 && ev.p[i] != -1)
      throw DataError(path + ": cannot write events: event " + std::to_string(i) + " has polarity " +
                  std::to_string(int(ev.p[i])) + " (expected +1 or -1)");
    if (i && ev.t[i] < ev.t[i - 1])
      throw DataError(path + ": cannot write events: event " + std::to_string(i) + " at t=" + std::to_string(ev.t[i]) +
                  " is earlier than the one before (t must be non-decreasing)");
  }
}

// A write that failed, with the system's reason (errno's text), never a guess: an IoError.
[[noreturn]] void write_failed(const std::string& path, const std::string& what, int err) {
  throw IoError(path + ": " + what + ": " + (err ? std::strerror(err) : "the system gave no reason") +
                (err ? " (errno " + std::to_string(err) + ")" : ""));
}

struct H5Closer {
  hid_t id;
  herr_t (*close)(hid_t);
  ~H5Closer() {
    if (id >= 0) close(id);
  }
};

void write_dataset(const std::string& path, hid_t group, const char* name, hid_t file_type, hid_t mem_type,
                   const void* data, hsize_t n) {
  hsize_t dims[1] = {n};
  H5Closer space{H5Screate_simple(1, dims, nullptr), H5Sclose};
  H5Closer dcpl{H5Pcreate(H5P_DATASET_CREATE), H5Pclose};
  H5Pset_obj_track_times(dcpl.id, 0);  // no creation/modification times: same events -> same bytes
  if (n > 0) {
    // Chunked so readers can take hyperslabs of an hour-long stream without reading it all.
    hsize_t chunk[1] = {std::min<hsize_t>(n, hsize_t(1) << 16)};
    H5Pset_chunk(dcpl.id, 1, chunk);
  }
  errno = 0;
  H5Closer d{H5Dcreate2(group, name, file_type, space.id, H5P_DEFAULT, dcpl.id, H5P_DEFAULT), H5Dclose};
  if (d.id < 0) write_failed(path, std::string("cannot create dataset events/") + name, errno);
  if (n > 0 && H5Dwrite(d.id, mem_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0)
    write_failed(path, std::string("cannot write dataset events/") + name, errno);
}

void write_int_attr(const std::string& path, hid_t obj, const char* name, int64_t v) {
  H5Closer space{H5Screate(H5S_SCALAR), H5Sclose};
  H5Closer a{H5Acreate2(obj, name, H5T_STD_I64LE, space.id, H5P_DEFAULT, H5P_DEFAULT), H5Aclose};
  if (a.id < 0 || H5Awrite(a.id, H5T_NATIVE_INT64, &v) < 0) throw IoError(path + ": cannot write attribute " + name);
}

}  // namespace

void write_events_hdf5(const std::string& path, const EventStream& ev) {
  check_stream(path, ev);
  H5E_auto2_t func = nullptr;
  void* data = nullptr;
  H5Eget_auto2(H5E_DEFAULT, &func, &data);
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  struct Restore {
    H5E_auto2_t f;
    void* d;
    ~Restore() { H5Eset_auto2(H5E_DEFAULT, f, d); }
  } restore{func, data};
  errno = 0;
  H5Closer file{H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT), H5Fclose};
  if (file.id < 0) write_failed(path, "cannot create the HDF5 file", errno);
  H5Closer gcpl{H5Pcreate(H5P_GROUP_CREATE), H5Pclose};
  H5Pset_obj_track_times(gcpl.id, 0);
  H5Closer g{H5Gcreate2(file.id, "events", H5P_DEFAULT, gcpl.id, H5P_DEFAULT), H5Gclose};
  if (g.id < 0) throw IoError(path + ": cannot create group events");
  const hsize_t n = ev.size();
  std::vector<int8_t> p01(n);
  for (size_t i = 0; i < n; ++i) p01[i] = ev.p[i] > 0 ? 1 : 0;
  write_dataset(path, g.id, "t", H5T_STD_I64LE, H5T_NATIVE_INT64, ev.t.data(), n);
  write_dataset(path, g.id, "x", H5T_STD_U16LE, H5T_NATIVE_UINT16, ev.x.data(), n);
  write_dataset(path, g.id, "y", H5T_STD_U16LE, H5T_NATIVE_UINT16, ev.y.data(), n);
  write_dataset(path, g.id, "p", H5T_STD_I8LE, H5T_NATIVE_INT8, p01.data(), n);
  write_int_attr(path, g.id, "width", ev.width);
  write_int_attr(path, g.id, "height", ev.height);
  write_int_attr(path, file.id, kEventFileMark, 1);  // the output rule replaces only marked files
  errno = 0;
  if (H5Fflush(file.id, H5F_SCOPE_GLOBAL) < 0) write_failed(path, "cannot flush the HDF5 file", errno);
  const hid_t id = file.id;
  file.id = -1;  // closed here, not by the guard: a close that fails (the last blocks) is an error too
  errno = 0;
  if (H5Fclose(id) < 0) write_failed(path, "cannot close the HDF5 file", errno);
}

bool event_file_written_by_vkunroll(const std::string& path) {
  char head[64] = {};
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) return false;
  const size_t n = std::fread(head, 1, sizeof head - 1, f);
  std::fclose(f);
  if (std::string(head, n).rfind(kTextEventMark, 0) == 0) return true;
  if (n < 8 || std::memcmp(head, "\x89HDF\r\n\x1a\n", 8) != 0) return false;
  H5E_auto2_t func = nullptr;
  void* data = nullptr;
  H5Eget_auto2(H5E_DEFAULT, &func, &data);
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  H5Closer file{H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose};
  const bool marked = file.id >= 0 && H5Aexists(file.id, kEventFileMark) > 0;
  H5Eset_auto2(H5E_DEFAULT, func, data);
  return marked;
}

void write_events_text(const std::string& path, const EventStream& ev) {
  check_stream(path, ev);
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) write_failed(path, "cannot create the text event file", errno);
  int err = 0;
  std::fprintf(f, "%s: t x y p (t in microseconds, p 1 = brightness increase, 0 = decrease)\n", kTextEventMark);
  std::fprintf(f, "# width %d height %d\n", ev.width, ev.height);
  std::vector<char> buf(1 << 20);
  size_t used = 0;
  bool ok = true;
  for (size_t i = 0; i < ev.size() && ok; ++i) {
    if (buf.size() - used < 64) {
      ok = std::fwrite(buf.data(), 1, used, f) == used;
      if (!ok) err = errno;
      used = 0;
    }
    used += size_t(std::snprintf(buf.data() + used, buf.size() - used, "%lld %u %u %d\n",
                                 static_cast<long long>(ev.t[i]), unsigned(ev.x[i]), unsigned(ev.y[i]), ev.p[i] > 0 ? 1 : 0));
  }
  if (ok && used && !(ok = std::fwrite(buf.data(), 1, used, f) == used)) err = errno;
  if (ok && std::fflush(f) != 0) ok = false, err = errno;
  if (std::fclose(f) != 0 && ok) ok = false, err = errno;
  if (!ok) write_failed(path, "cannot write the text event file", err);
}

}  // namespace vkunroll
