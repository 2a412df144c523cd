// HDF5 event files: the project's events/{t,x,y,p}, DSEC (events/{x,y,p,t} + t_offset + ms_to_idx,
// Blosc through Debian's filter plugin), Gev-RS (events N x 4 + img_to_idx), v2e (events N x 4),
// DRE (x, y, p, t + image timestamps). Reads in hyperslab chunks; a time window is found by
// binary search on t (narrowed by ms_to_idx when present), so only the window is read.
#include <hdf5.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <mutex>

#include "vkunroll/host/events/event_reader_detail.hpp"

namespace vkunroll::detail {

namespace {

constexpr hsize_t kChunkRows = hsize_t(1) << 20;

// HDF5 prints its error stack to stderr by default; we turn failures into vkunroll::Error instead.
class QuietHdf5 {
 public:
  QuietHdf5() {
    H5Eget_auto2(H5E_DEFAULT, &func_, &data_);
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  }
  ~QuietHdf5() { H5Eset_auto2(H5E_DEFAULT, func_, data_); }

 private:
  H5E_auto2_t func_ = nullptr;
  void* data_ = nullptr;
};

// Debian installs the Blosc filter plugin outside HDF5's compiled-in default path.
void register_plugin_path() {
  static std::once_flag once;
  std::call_once(once, [] {
    const char* dirs[] = {"/usr/lib/x86_64-linux-gnu/hdf5/serial/plugins", "/usr/lib/aarch64-linux-gnu/hdf5/serial/plugins"};
    for (const char* d : dirs)
      if (std::filesystem::exists(d)) H5PLappend(d);
  });
}

class Handle {
 public:
  Handle() = default;
  Handle(hid_t id, herr_t (*close)(hid_t)) : id_(id), close_(close) {}
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  Handle(Handle&& o) noexcept : id_(o.id_), close_(o.close_) { o.id_ = -1; }
  Handle& operator=(Handle&& o) noexcept {
    if (this != &o) {
      reset();
      id_ = o.id_;
      close_ = o.close_;
      o.id_ = -1;
    }
    return *this;
  }
  ~Handle() { reset(); }
  void reset() {
    if (id_ >= 0 && close_) close_(id_);
    id_ = -1;
  }
  hid_t get() const { return id_; }
  bool valid() const { return id_ >= 0; }

 private:
  hid_t id_ = -1;
  herr_t (*close_)(hid_t) = nullptr;
};

bool exists(hid_t loc, const std::string& path) {
  // Check each component: H5Lexists fails on a missing intermediate group.
  size_t pos = 0;
  while (true) {
    const size_t slash = path.find('/', pos);
    const std::string prefix = path.substr(0, slash);
    if (H5Lexists(loc, prefix.c_str(), H5P_DEFAULT) <= 0) return false;
    if (slash == std::string::npos) return true;
    pos = slash + 1;
  }
}

// Whether `path` exists under `loc` and is an object of this type.
bool is_object(hid_t loc, const std::string& path, H5O_type_t type) {
  if (!exists(loc, path)) return false;
  H5O_info_t info;
#if H5_VERSION_GE(1, 12, 0)
  if (H5Oget_info_by_name3(loc, path.c_str(), &info, H5O_INFO_BASIC, H5P_DEFAULT) < 0) return false;
#else
  if (H5Oget_info_by_name(loc, path.c_str(), &info, H5P_DEFAULT) < 0) return false;
#endif
  return info.type == type;
}
bool is_dataset(hid_t loc, const std::string& path) { return is_object(loc, path, H5O_TYPE_DATASET); }
bool is_group(hid_t loc, const std::string& path) { return is_object(loc, path, H5O_TYPE_GROUP); }

std::string class_name(H5T_class_t c) {
  switch (c) {
    case H5T_INTEGER: return "integer";
    case H5T_FLOAT: return "float";
    case H5T_STRING: return "string";
    case H5T_COMPOUND: return "compound";
    case H5T_ENUM: return "enum";
    case H5T_ARRAY: return "array";
    case H5T_BITFIELD: return "bitfield";
    case H5T_OPAQUE: return "opaque";
    case H5T_REFERENCE: return "reference";
    case H5T_VLEN: return "variable-length";
    default: return "unknown";
  }
}

// One column of events: a 1-D dataset, or column `col` of an N x K dataset.
struct Column {
  std::string name;  // for messages, e.g. "events/x" or "events[:,1]"
  Handle dset;
  int col = -1;
  hsize_t rows = 0;
  hsize_t ncols = 0;
  H5T_class_t cls = H5T_NO_CLASS;
  Handle enum_type;  // native enum type (h5py bools)
};

Column open_column(hid_t file, const std::string& file_name, const std::string& path, int col, const std::string& what) {
  Column c;
  c.name = col < 0 ? path : path + "[:," + std::to_string(col) + "]";
  c.col = col;
  c.dset = Handle(H5Dopen2(file, path.c_str(), H5P_DEFAULT), H5Dclose);
  if (!c.dset.valid()) throw DataError(file_name + ": cannot open dataset '" + path + "'");
  Handle space(H5Dget_space(c.dset.get()), H5Sclose);
  const int rank = H5Sget_simple_extent_ndims(space.get());
  hsize_t dims[2] = {0, 0};
  if (rank == 1 && col < 0) {
    H5Sget_simple_extent_dims(space.get(), dims, nullptr);
    c.rows = dims[0];
  } else if (rank == 2 && col >= 0) {
    H5Sget_simple_extent_dims(space.get(), dims, nullptr);
    c.rows = dims[0];
    c.ncols = dims[1];
    if (dims[1] < 4)
      throw DataError(file_name + ": dataset '" + path + "' has shape [" + std::to_string(dims[0]) + ", " +
                  std::to_string(dims[1]) + "]; expected N x 4 columns t, x, y, p");
  } else {
    throw DataError(file_name + ": dataset '" + path + "' has rank " + std::to_string(rank) + "; expected " +
                (col < 0 ? "a 1-D array" : "an N x 4 array"));
  }
  // A dataset created but never written reads as its fill value (10^9 zeros read as 10^9 events).
  // Only "not allocated" is refused: chunked datasets fully written can report "partly allocated".
  H5D_space_status_t status = H5D_SPACE_STATUS_ERROR;
  if (c.rows > 0 && H5Dget_space_status(c.dset.get(), &status) >= 0 && status == H5D_SPACE_STATUS_NOT_ALLOCATED)
    throw DataError(file_name + ": dataset '" + path + "' (" + what + ", " + std::to_string(c.rows) +
                    " rows) was never written: its storage is not allocated, so it would read as fill values, not events");
  Handle type(H5Dget_type(c.dset.get()), H5Tclose);
  c.cls = H5Tget_class(type.get());
  if (c.cls == H5T_ENUM) {
    Handle super(H5Tget_super(type.get()), H5Tclose);
    if (H5Tget_class(super.get()) != H5T_INTEGER || H5Tget_size(super.get()) != 1)
      throw DataError(file_name + ": dataset '" + c.name + "' (" + what + ") is an enum that is not a 1-byte bool");
    c.enum_type = Handle(H5Tget_native_type(type.get(), H5T_DIR_ASCEND), H5Tclose);
  } else if (c.cls != H5T_INTEGER && c.cls != H5T_FLOAT) {
    throw DataError(file_name + ": dataset '" + c.name + "' (" + what + ") has type class " + class_name(c.cls) +
                "; expected integer or float numbers");
  }
  return c;
}

// Reads rows [r0, r0+n) of a column as int64 (integers, enums) or double (floats).
void read_column(const std::string& file_name, Column& c, hsize_t r0, hsize_t n, std::vector<int64_t>& iv,
                 std::vector<double>& dv) {
  Handle fspace(H5Dget_space(c.dset.get()), H5Sclose);
  herr_t st;
  if (c.col < 0) {
    hsize_t start[1] = {r0}, count[1] = {n};
    st = H5Sselect_hyperslab(fspace.get(), H5S_SELECT_SET, start, nullptr, count, nullptr);
  } else {
    hsize_t start[2] = {r0, hsize_t(c.col)}, count[2] = {n, 1};
    st = H5Sselect_hyperslab(fspace.get(), H5S_SELECT_SET, start, nullptr, count, nullptr);
  }
  if (st < 0) throw DataError(file_name + ": cannot select rows of '" + c.name + "'");
  hsize_t mdims[1] = {n};
  Handle mspace(H5Screate_simple(1, mdims, nullptr), H5Sclose);
  if (c.cls == H5T_FLOAT) {
    dv.resize(n);
    st = H5Dread(c.dset.get(), H5T_NATIVE_DOUBLE, mspace.get(), fspace.get(), H5P_DEFAULT, dv.data());
  } else if (c.cls == H5T_ENUM) {
    std::vector<int8_t> b(n);
    st = H5Dread(c.dset.get(), c.enum_type.get(), mspace.get(), fspace.get(), H5P_DEFAULT, b.data());
    iv.assign(b.begin(), b.end());
  } else {
    iv.resize(n);
    st = H5Dread(c.dset.get(), H5T_NATIVE_INT64, mspace.get(), fspace.get(), H5P_DEFAULT, iv.data());
  }
  if (st < 0)
    throw DataError(file_name + ": cannot read rows " + std::to_string(r0) + ".." + std::to_string(r0 + n) + " of '" +
                c.name + "' (truncated or corrupt file, or a compression filter that is not installed)");
}

struct Layout {
  std::string kind;  // "events", "dsec", "gevrs", "v2e", "dre"
  Column t, x, y, p;
  int64_t t_offset = 0;
};

int read_int_attr(hid_t obj, const char* name) {
  if (H5Aexists(obj, name) <= 0) return 0;
  Handle a(H5Aopen(obj, name, H5P_DEFAULT), H5Aclose);
  if (!a.valid()) return 0;
  Handle space(H5Aget_space(a.get()), H5Sclose);
  if (H5Sget_simple_extent_npoints(space.get()) != 1) return 0;
  Handle type(H5Aget_type(a.get()), H5Tclose);
  const H5T_class_t c = H5Tget_class(type.get());
  if (c != H5T_INTEGER && c != H5T_FLOAT) return 0;
  int64_t v = 0;
  if (H5Aread(a.get(), H5T_NATIVE_INT64, &v) < 0) return 0;
  return (v > 0 && v <= 65536) ? int(v) : 0;
}

// width/height attributes on `obj`: (width,height) or (sensor_width,sensor_height).
bool size_attrs(hid_t obj, int& w, int& h) {
  w = read_int_attr(obj, "width");
  h = read_int_attr(obj, "height");
  if (w > 0 && h > 0) return true;
  w = read_int_attr(obj, "sensor_width");
  h = read_int_attr(obj, "sensor_height");
  return w > 0 && h > 0;
}

// Entries [r0, r0 + n) of an integer index dataset (float indices must be integral).
std::vector<int64_t> read_index_entries(const std::string& file_name, Column& c, hsize_t r0, hsize_t n) {
  std::vector<int64_t> iv;
  std::vector<double> dv;
  if (n == 0) return {};
  read_column(file_name, c, r0, n, iv, dv);
  if (c.cls == H5T_FLOAT) {
    iv.resize(dv.size());
    for (size_t i = 0; i < dv.size(); ++i) {
      // A float index must be an integer that int64 can hold (converting 1e169 would be undefined).
      if (!std::isfinite(dv[i]) || std::fabs(dv[i]) >= 9.2e18 || dv[i] != std::floor(dv[i]))
        throw DataError(file_name + ": '" + c.name + "'[" + std::to_string(r0 + i) + "] = " + std::to_string(dv[i]) +
                    " is not an integer index");
      iv[i] = int64_t(dv[i]);
    }
  }
  return iv;
}

std::vector<int64_t> read_whole_int(hid_t file, const std::string& file_name, const std::string& path) {
  Column c = open_column(file, file_name, path, -1, path);
  return read_index_entries(file_name, c, 0, c.rows);
}

int64_t read_scalar_int(hid_t file, const std::string& file_name, const std::string& path) {
  Handle d(H5Dopen2(file, path.c_str(), H5P_DEFAULT), H5Dclose);
  if (!d.valid()) throw DataError(file_name + ": cannot open '" + path + "'");
  Handle space(H5Dget_space(d.get()), H5Sclose);
  if (H5Sget_simple_extent_npoints(space.get()) != 1)
    throw DataError(file_name + ": '" + path + "' should hold one number");
  Handle type(H5Dget_type(d.get()), H5Tclose);
  const H5T_class_t c = H5Tget_class(type.get());
  if (c != H5T_INTEGER && c != H5T_FLOAT) throw DataError(file_name + ": '" + path + "' is not a number");
  int64_t v = 0;
  if (H5Dread(d.get(), H5T_NATIVE_INT64, H5S_ALL, H5S_ALL, H5P_DEFAULT, &v) < 0)
    throw DataError(file_name + ": cannot read '" + path + "'");
  return v;
}

Handle open_file(const std::string& path, const void* image, size_t image_size) {
  register_plugin_path();
  if (image) {
    Handle fapl(H5Pcreate(H5P_FILE_ACCESS), H5Pclose);
    H5Pset_fapl_core(fapl.get(), 1 << 16, false);
    if (H5Pset_file_image(fapl.get(), const_cast<void*>(image), image_size) < 0)
      throw InternalError(path + ": cannot use the HDF5 file image");
    Handle f(H5Fopen(path.c_str(), H5F_ACC_RDONLY, fapl.get()), H5Fclose);
    if (!f.valid()) throw DataError(path + ": not a readable HDF5 file");
    return f;
  }
  if (H5Fis_hdf5(path.c_str()) <= 0)
    throw DataError(path + ": not a readable HDF5 file (bad signature or truncated)");
  Handle f(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose);
  if (!f.valid()) throw DataError(path + ": cannot open the HDF5 file (truncated or corrupt?)");
  return f;
}

Layout detect_layout(hid_t f, const std::string& file, EventSink& sink) {
  Layout L;
  auto all_in = [&](const std::string& prefix, std::initializer_list<const char*> names) {
    for (const char* n : names)
      if (!is_dataset(f, prefix + n)) return false;
    return true;
  };
  if (is_group(f, "events") && all_in("events/", {"x", "y", "p"}) && (is_dataset(f, "events/t") || is_dataset(f, "events/ts"))) {
    const std::string tname = is_dataset(f, "events/t") ? "events/t" : "events/ts";
    L.t = open_column(f, file, tname, -1, "time");
    L.x = open_column(f, file, "events/x", -1, "x");
    L.y = open_column(f, file, "events/y", -1, "y");
    L.p = open_column(f, file, "events/p", -1, "polarity");
    if (is_dataset(f, "t_offset") || is_dataset(f, "ms_to_idx")) {
      L.kind = "dsec";
      if (is_dataset(f, "t_offset")) L.t_offset = read_scalar_int(f, file, "t_offset");
      sink.note("DSEC layout: t = events/t + t_offset (" + std::to_string(L.t_offset) + " us)");
    } else {
      L.kind = "events";
    }
    Handle g(H5Gopen2(f, "events", H5P_DEFAULT), H5Gclose);
    int w = 0, h = 0;
    if (size_attrs(g.get(), w, h)) sink.set_file_geometry(w, h, "the events group's width/height attributes");
  } else if (is_dataset(f, "events")) {
    L.kind = is_dataset(f, "img_to_idx") ? "gevrs" : "v2e";
    for (int c = 0; c < 4; ++c) {
      static const char* what[] = {"time", "x", "y", "polarity"};
      Column col = open_column(f, file, "events", c, what[c]);
      (c == 0 ? L.t : c == 1 ? L.x : c == 2 ? L.y : L.p) = std::move(col);
    }
    Handle d(H5Dopen2(f, "events", H5P_DEFAULT), H5Dclose);
    int w = 0, h = 0;
    if (size_attrs(d.get(), w, h)) sink.set_file_geometry(w, h, "the events dataset's width/height attributes");
    if (L.kind == "gevrs" && !sink.geometry_known())
      sink.set_file_geometry(640, 360, "the Gev-RS layout (events + img_to_idx; reference section 4)");
  } else if (all_in("", {"x", "y", "p", "t"})) {
    L.kind = "dre";
    L.t = open_column(f, file, "t", -1, "time");
    L.x = open_column(f, file, "x", -1, "x");
    L.y = open_column(f, file, "y", -1, "y");
    L.p = open_column(f, file, "p", -1, "polarity");
    if (is_dataset(f, "image_ts") && !sink.geometry_known())
      sink.set_file_geometry(346, 260, "the DRE layout (DAVIS346; reference section 4)");
  } else {
    throw DataError(file + ": no event datasets found; expected events/{t,x,y,p} (project, DSEC), an N x 4 'events' "
                       "dataset (Gev-RS, v2e) or top-level x, y, p, t (DRE)");
  }
  if (L.kind == "dsec" && !sink.geometry_known()) sink.set_file_geometry(640, 480, "the DSEC layout (Prophesee Gen3.1)");
  int w = 0, h = 0;
  if (!sink.geometry_known() && size_attrs(f, w, h)) sink.set_file_geometry(w, h, "the file's width/height attributes");
  if (L.x.rows != L.t.rows || L.y.rows != L.t.rows || L.p.rows != L.t.rows)
    throw DataError(file + ": event datasets have different lengths (t " + std::to_string(L.t.rows) + ", x " +
                std::to_string(L.x.rows) + ", y " + std::to_string(L.y.rows) + ", p " + std::to_string(L.p.rows) + ")");
  return L;
}

}  // namespace

void read_hdf5(const std::string& path, const void* image, size_t image_size, EventSink& sink) {
  QuietHdf5 quiet;
  Handle f = open_file(path, image, image_size);
  Layout L = detect_layout(f.get(), path, sink);
  EventReadReport& rep = sink.report();
  rep.format = "h5:" + L.kind;
  const EventReadOptions& o = sink.options();
  double time_scale = 1.0;
  if (L.t.cls == H5T_FLOAT) {
    const std::string unit = o.array_time_unit.empty() ? "us" : o.array_time_unit;
    time_scale = std::pow(10.0, time_unit_exponent(unit, path));
    rep.time_unit = unit;
  }

  hsize_t r0 = 0, r1 = L.t.rows;
  std::vector<int64_t> iv;
  std::vector<double> dv;
  // t of one row, in microseconds (binary search helper; NaN sorts as +inf).
  auto t_at = [&](hsize_t r) -> double {
    read_column(path, L.t, r, 1, iv, dv);
    if (L.t.cls == H5T_FLOAT) return std::isnan(dv[0]) ? INFINITY : dv[0] * time_scale + double(L.t_offset);
    return double(iv[0]) + double(L.t_offset);
  };
  auto lower_bound = [&](hsize_t lo, hsize_t hi, double value) {
    while (lo < hi) {
      const hsize_t mid = lo + (hi - lo) / 2;
      if (t_at(mid) < value) lo = mid + 1;
      else hi = mid;
    }
    return lo;
  };
  if (sink.probing()) {
    if (L.t.rows) sink.probed(t_at(0), t_at(L.t.rows - 1));
    else sink.probed(INFINITY, -INFINITY);
    return;
  }
  if ((o.t_begin_us || o.t_end_us) && o.on_bad != BadEventPolicy::sort && L.t.rows > 0) {
    hsize_t lo = 0, hi = L.t.rows;
    if (L.kind == "dsec" && is_dataset(f.get(), "ms_to_idx") && o.t_begin_us) {
      // ms_to_idx[k] = first event with (t - t_offset) >= 1000 k: narrows the search to one millisecond.
      // Only entries k and k+1 are read (an hour-long recording has 3.6 million).
      Column ms = open_column(f.get(), path, "ms_to_idx", -1, "ms_to_idx");
      int64_t rel = 0;
      if (!__builtin_sub_overflow(*o.t_begin_us, L.t_offset, &rel) && rel >= 0 && ms.rows > 0) {
        const hsize_t k = hsize_t(std::min<int64_t>(rel / 1000, int64_t(ms.rows) - 1));
        const std::vector<int64_t> v = read_index_entries(path, ms, k, std::min<hsize_t>(2, ms.rows - k));
        if (v[0] >= 0 && hsize_t(v[0]) <= hi) lo = hsize_t(v[0]);
        if (v.size() > 1 && v[1] >= int64_t(lo) && hsize_t(v[1]) <= hi) hi = hsize_t(v[1]);
        sink.note("window start found through ms_to_idx");
      }
    }
    if (o.t_begin_us) r0 = lower_bound(lo, hi, double(*o.t_begin_us));
    if (o.t_end_us) r1 = lower_bound(r0, L.t.rows, double(*o.t_end_us));
    rep.stopped_early = r0 > 0 || r1 < L.t.rows;
    sink.note("time window: binary search on t read rows " + std::to_string(r0) + ".." + std::to_string(r1) + " of " +
              std::to_string(L.t.rows));
  }

  sink.expect_records(r1 - r0);
  std::vector<int64_t> ti, xi, yi, pi;
  std::vector<double> td, xd, yd, pd;
  for (hsize_t c0 = r0; c0 < r1; c0 += kChunkRows) {
    const hsize_t n = std::min(kChunkRows, r1 - c0);
    read_column(path, L.t, c0, n, ti, td);
    read_column(path, L.x, c0, n, xi, xd);
    read_column(path, L.y, c0, n, yi, yd);
    read_column(path, L.p, c0, n, pi, pd);
    const bool tf = L.t.cls == H5T_FLOAT;
    const bool cf = L.x.cls == H5T_FLOAT || L.y.cls == H5T_FLOAT || L.p.cls == H5T_FLOAT;
    for (hsize_t i = 0; i < n; ++i) {
      sink.set_record_index(c0 + i);
      bool more;
      int64_t t_int = 0;
      // t + t_offset may overflow int64 in a hostile file: such a time goes through the float path,
      // which rejects it as not representable.
      const bool t_overflow = !tf && __builtin_add_overflow(ti[i], L.t_offset, &t_int);
      if (!tf && !cf && !t_overflow) {
        more = sink.add(t_int, xi[i], yi[i], pi[i]);
      } else {
        const double t = tf ? td[i] * time_scale + double(L.t_offset) : double(ti[i]) + double(L.t_offset);
        const double x = L.x.cls == H5T_FLOAT ? xd[i] : double(xi[i]);
        const double y = L.y.cls == H5T_FLOAT ? yd[i] : double(yi[i]);
        const double p = L.p.cls == H5T_FLOAT ? pd[i] : double(pi[i]);
        if (!cf) more = sink.add_float_time(t, xi[i], yi[i], pi[i]);
        else more = sink.add_float(t, x, y, p);
      }
      if (!more) return;
    }
  }
}

ImageTimestamps read_image_timestamps(const std::string& h5_path) {
  QuietHdf5 quiet;
  Handle f = open_file(h5_path, nullptr, 0);
  ImageTimestamps ts;
  bool any = false;
  auto load = [&](const char* name, std::vector<double>& out) {
    if (!is_dataset(f.get(), name)) return;
    Column c = open_column(f.get(), h5_path, name, -1, name);
    std::vector<int64_t> iv;
    std::vector<double> dv;
    any = true;
    if (c.rows == 0) return;
    read_column(h5_path, c, 0, c.rows, iv, dv);
    if (c.cls == H5T_FLOAT) out = dv;
    else out.assign(iv.begin(), iv.end());
  };
  load("image_ts", ts.image_ts);
  load("start_image_ts", ts.start_image_ts);
  load("end_image_ts", ts.end_image_ts);
  if (!any) throw DataError(h5_path + ": no image_ts, start_image_ts or end_image_ts datasets (DRE layout expected)");
  return ts;
}

std::vector<int64_t> read_event_index(const std::string& h5_path, const std::string& dataset) {
  QuietHdf5 quiet;
  Handle f = open_file(h5_path, nullptr, 0);
  if (!is_dataset(f.get(), dataset)) throw DataError(h5_path + ": no dataset '" + dataset + "'");
  return read_whole_int(f.get(), h5_path, dataset);
}

std::string hdf5_event_layout(const std::string& h5_path) {
  QuietHdf5 quiet;
  Handle f = open_file(h5_path, nullptr, 0);
  EventReadReport rep;
  EventSink sink(h5_path, {}, rep);
  try {
    return detect_layout(f.get(), h5_path, sink).kind;
  } catch (const Error&) {
    return "";
  }
}

}  // namespace vkunroll::detail

namespace vkunroll {
std::string hdf5_event_layout(const std::string& h5_path) { return detail::hdf5_event_layout(h5_path); }
ImageTimestamps read_image_timestamps(const std::string& h5_path) { return detail::read_image_timestamps(h5_path); }
std::vector<int64_t> read_event_index(const std::string& h5_path, const std::string& dataset) {
  return detail::read_event_index(h5_path, dataset);
}
}  // namespace vkunroll
