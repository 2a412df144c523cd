// NumPy .npy and .npz (members through zip_member.cpp): N x K arrays whose first four columns are
// t, x, y, p (any numeric dtype, C or Fortran order), record arrays with fields x, y, p, t (any
// order), and .npz files holding separate 1-D arrays x, y, p, t. Rows are decoded in chunks; a time
// window starts by binary search on t (deflated members are random access through their index).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <map>
#include <memory>

#include "vkunroll/host/events/zip_member_detail.hpp"

namespace vkunroll::detail {

namespace {

constexpr uint64_t kChunkRows = 1 << 16;

struct DType {
  char kind = 0;  // 'b' bool, 'i' signed, 'u' unsigned, 'f' float
  int size = 0;
  bool big_endian = false;
  std::string text;
};

struct Field {
  std::string name;
  DType type;
  uint64_t offset = 0;
};

struct NpyHeader {
  uint64_t data_offset = 0;
  bool fortran = false;
  std::vector<uint64_t> shape;
  bool structured = false;
  DType type;                // plain arrays
  std::vector<Field> fields; // structured arrays
  uint64_t itemsize = 0;
};

// ---- a tiny parser for the header's Python dict literal ------------------------------------------

class Lit {
 public:
  Lit(const std::string& s, const std::string& file) : s_(s), file_(file) {}
  void ws() {
    while (i_ < s_.size() && (s_[i_] == ' ' || s_[i_] == '\n' || s_[i_] == '\t')) ++i_;
  }
  bool peek(char c) {
    ws();
    return i_ < s_.size() && s_[i_] == c;
  }
  void expect(char c) {
    if (!peek(c)) fail(std::string("expected '") + c + "'");
    ++i_;
  }
  bool accept(char c) {
    if (!peek(c)) return false;
    ++i_;
    return true;
  }
  std::string str() {
    ws();
    if (i_ >= s_.size() || (s_[i_] != '\'' && s_[i_] != '"')) fail("expected a quoted string");
    const char q = s_[i_++];
    std::string out;
    while (i_ < s_.size() && s_[i_] != q) out += s_[i_++];
    if (i_ >= s_.size()) fail("unterminated string");
    ++i_;
    return out;
  }
  std::string word() {
    ws();
    std::string out;
    while (i_ < s_.size() && (std::isalnum(static_cast<unsigned char>(s_[i_])) || s_[i_] == '_')) out += s_[i_++];
    if (out.empty()) fail("expected a value");
    return out;
  }
  uint64_t uint() {
    const std::string w = word();
    uint64_t v = 0;
    for (char c : w) {
      if (c == 'L') break;
      if (c < '0' || c > '9' || v > (uint64_t(1) << 56)) fail("expected a size, got '" + w + "'");
      v = v * 10 + uint64_t(c - '0');
    }
    return v;
  }
  std::vector<uint64_t> tuple_of_uints() {
    std::vector<uint64_t> v;
    expect('(');
    while (!accept(')')) {
      v.push_back(uint());
      if (v.size() > 32) fail("too many dimensions");
      if (!accept(',') && !peek(')')) fail("expected ',' or ')'");
    }
    return v;
  }
  [[noreturn]] void fail(const std::string& what) const {
    throw DataError(file_ + ": malformed .npy header (" + what + " at character " + std::to_string(i_) + " of '" +
                s_.substr(0, 200) + "')");
  }

 private:
  const std::string& s_;
  std::string file_;
  size_t i_ = 0;
};

DType parse_dtype(const std::string& d, const std::string& file, const std::string& what) {
  DType t;
  t.text = d;
  if (d.size() < 2) throw DataError(file + ": " + what + " has dtype '" + d + "'; expected a numeric dtype");
  size_t k = 0;
  if (d[0] == '<' || d[0] == '>' || d[0] == '|' || d[0] == '=') {
    t.big_endian = d[0] == '>';
    k = 1;
  }
  t.kind = d[k];
  int size = 0;
  for (size_t i = k + 1; i < d.size(); ++i) {
    if (d[i] < '0' || d[i] > '9' || size > 1000) { size = -1; break; }
    size = size * 10 + (d[i] - '0');
  }
  t.size = size;
  bool ok = false;
  if (t.kind == 'b' || t.kind == '?') t.kind = 'b', ok = size == 1;
  else if (t.kind == 'i' || t.kind == 'u') ok = size == 1 || size == 2 || size == 4 || size == 8;
  else if (t.kind == 'f') ok = size == 2 || size == 4 || size == 8;
  if (!ok)
    throw DataError(file + ": " + what + " has dtype '" + d +
                "'; expected bool, integer (i1..i8, u1..u8) or float (f2, f4, f8) numbers");
  return t;
}

NpyHeader parse_npy_header(ByteSource& src, const std::string& file) {
  const auto head = read_range(src, 0, 12);
  if (head.size() < 10 || std::memcmp(head.data(), "\x93NUMPY", 6) != 0)
    throw DataError(file + ": not a .npy array (missing the \\x93NUMPY magic)");
  const int major = head[6];
  uint64_t hlen, start;
  if (major == 1) {
    hlen = uint64_t(head[8]) | (uint64_t(head[9]) << 8);
    start = 10;
  } else if (major == 2 || major == 3) {
    if (head.size() < 12) throw DataError(file + ": truncated .npy header");
    hlen = uint64_t(head[8]) | (uint64_t(head[9]) << 8) | (uint64_t(head[10]) << 16) | (uint64_t(head[11]) << 24);
    start = 12;
  } else {
    throw DataError(file + ": .npy format version " + std::to_string(major) + " is not supported (1, 2, 3 are)");
  }
  if (hlen > (1u << 20)) throw DataError(file + ": .npy header of " + std::to_string(hlen) + " bytes is implausible");
  const auto hb = read_range(src, start, size_t(hlen));
  if (hb.size() < hlen) throw DataError(file + ": truncated .npy header (file ends at byte " + std::to_string(start + hb.size()) + ")");
  const std::string text(hb.begin(), hb.end());
  NpyHeader h;
  h.data_offset = start + hlen;
  Lit p(text, file);
  bool have_descr = false, have_shape = false;
  p.expect('{');
  while (!p.accept('}')) {
    const std::string key = p.str();
    p.expect(':');
    if (key == "descr") {
      have_descr = true;
      if (p.peek('[')) {
        h.structured = true;
        p.expect('[');
        uint64_t off = 0;
        while (!p.accept(']')) {
          p.expect('(');
          Field f;
          f.name = p.str();
          p.expect(',');
          if (p.peek('[') || p.peek('(')) p.fail("nested dtypes are not supported in field '" + f.name + "'");
          const std::string ft = p.str();
          if (p.accept(',')) {
            if (p.peek('(')) p.fail("sub-array field '" + f.name + "' is not supported");
          }
          p.expect(')');
          f.offset = off;
          // padding fields ('' names, 'V' types) are skipped but take their bytes
          if (f.name.empty() || ft.find('V') != std::string::npos) {
            uint64_t sz = 0;
            for (char c : ft)
              if (c >= '0' && c <= '9') sz = std::min<uint64_t>(sz * 10 + uint64_t(c - '0'), 1 << 20);
            off += sz;
          } else {
            f.type = parse_dtype(ft, file, "field '" + f.name + "'");
            off += uint64_t(f.type.size);
            h.fields.push_back(f);
          }
          if (!p.accept(',') && !p.peek(']')) p.fail("expected ',' or ']'");
          if (h.fields.size() > 64) p.fail("too many fields");
        }
        h.itemsize = off;
      } else {
        h.type = parse_dtype(p.str(), file, "the array");
        h.itemsize = uint64_t(h.type.size);
      }
    } else if (key == "fortran_order") {
      const std::string v = p.word();
      if (v != "True" && v != "False") p.fail("fortran_order must be True or False");
      h.fortran = v == "True";
    } else if (key == "shape") {
      have_shape = true;
      h.shape = p.tuple_of_uints();
    } else {
      p.fail("unknown key '" + key + "'");
    }
    if (!p.accept(',') && !p.peek('}')) p.fail("expected ',' or '}'");
  }
  if (!have_descr || !have_shape) throw DataError(file + ": .npy header lacks 'descr' or 'shape'");
  if (h.itemsize == 0) throw DataError(file + ": .npy dtype has zero size");
  return h;
}

// ---- columns -----------------------------------------------------------------------------------

struct ColumnSpec {
  ByteSource* src = nullptr;
  uint64_t base = 0;    // byte offset of row 0's element
  uint64_t stride = 0;  // bytes between rows
  DType type;
  std::string name;
};

inline uint64_t load_bits(const uint8_t* p, int size, bool big) {
  uint64_t v = 0;
  if (big)
    for (int i = 0; i < size; ++i) v = (v << 8) | p[i];
  else
    for (int i = size - 1; i >= 0; --i) v = (v << 8) | p[i];
  return v;
}

double half_to_double(uint16_t h) {
  const int e = (h >> 10) & 0x1F, m = h & 0x3FF;
  const double s = (h & 0x8000) ? -1.0 : 1.0;
  if (e == 0) return s * std::ldexp(double(m), -24);
  if (e == 31) return m ? NAN : s * INFINITY;
  return s * std::ldexp(double(m | 0x400), e - 25);
}

inline bool is_float(const DType& t) { return t.kind == 'f'; }

inline int64_t as_int(const uint8_t* p, const DType& t) {
  const uint64_t v = load_bits(p, t.size, t.big_endian);
  if (t.kind == 'b') return v ? 1 : 0;
  if (t.kind == 'u') return v > uint64_t(INT64_MAX) ? INT64_MAX : int64_t(v);
  const int sh = 64 - 8 * t.size;
  return int64_t(v << sh) >> sh;  // sign-extend
}

inline double as_double(const uint8_t* p, const DType& t) {
  const uint64_t v = load_bits(p, t.size, t.big_endian);
  if (t.size == 8) {
    double d;
    std::memcpy(&d, &v, 8);
    return d;
  }
  if (t.size == 4) {
    const uint32_t u = uint32_t(v);
    float f;
    std::memcpy(&f, &u, 4);
    return f;
  }
  return half_to_double(uint16_t(v));
}

// Decodes rows [0, rows) of the four columns (t, x, y, p) into the sink.
void decode_columns(std::array<ColumnSpec, 4>& cols, uint64_t rows, EventSink& sink, const std::string& file) {
  const EventReadOptions& o = sink.options();
  double scale = 1.0;
  if (is_float(cols[0].type)) {
    const std::string unit = o.array_time_unit.empty() ? "us" : o.array_time_unit;
    scale = std::pow(10.0, time_unit_exponent(unit, file));
    sink.report().time_unit = unit;
  }
  // Every column's bytes must exist: a short array is a truncated file.
  for (auto& c : cols) {
    if (rows == 0) break;
    const uint64_t need = c.base + (rows - 1) * c.stride + uint64_t(c.type.size);
    if (c.src->size() < need)
      throw DataError(file + ": " + c.name + " needs " + std::to_string(need) + " bytes for " + std::to_string(rows) +
                  " rows but the data has " + std::to_string(c.src->size()) + " (truncated file)");
  }
  auto value_t = [&](uint64_t r) {
    uint8_t b[8];
    cols[0].src->read_at(cols[0].base + r * cols[0].stride, b, size_t(cols[0].type.size));
    return is_float(cols[0].type) ? (std::isnan(as_double(b, cols[0].type)) ? INFINITY : as_double(b, cols[0].type) * scale)
                                  : double(as_int(b, cols[0].type));
  };
  if (sink.probing()) {
    if (rows) sink.probed(value_t(0), value_t(rows - 1));
    else sink.probed(INFINITY, -INFINITY);
    return;
  }
  uint64_t r0 = 0, r1 = rows;
  bool seekable = true;
  for (auto& c : cols) seekable &= c.src->seekable();
  if ((o.t_begin_us || o.t_end_us) && o.on_bad != BadEventPolicy::sort && seekable && rows > 0) {
    auto lower_bound = [&](uint64_t lo, uint64_t hi, double v) {
      while (lo < hi) {
        const uint64_t mid = lo + (hi - lo) / 2;
        if (value_t(mid) < v) lo = mid + 1;
        else hi = mid;
      }
      return lo;
    };
    if (o.t_begin_us) r0 = lower_bound(0, rows, double(*o.t_begin_us));
    if (o.t_end_us) r1 = lower_bound(r0, rows, double(*o.t_end_us));
    sink.report().stopped_early = r0 > 0 || r1 < rows;
    sink.note("time window: binary search on t read rows " + std::to_string(r0) + ".." + std::to_string(r1) + " of " +
              std::to_string(rows));
  }
  sink.expect_records(r1 - r0);
  const bool tf = is_float(cols[0].type);
  const bool cf = is_float(cols[1].type) || is_float(cols[2].type) || is_float(cols[3].type);
  // Group columns that share a source so each chunk of bytes is read once (front to back).
  std::vector<uint8_t> buf[4];
  uint64_t buf_start[4] = {0, 0, 0, 0};
  int owner[4] = {0, 1, 2, 3};
  for (int c = 0; c < 4; ++c)
    for (int d = 0; d < c; ++d)
      if (cols[size_t(d)].src == cols[size_t(c)].src && cols[size_t(d)].stride == cols[size_t(c)].stride && owner[d] == d) {
        owner[c] = d;
        break;
      }
  for (uint64_t c0 = r0; c0 < r1; c0 += kChunkRows) {
    const uint64_t n = std::min(kChunkRows, r1 - c0);
    for (int c = 0; c < 4; ++c) {
      if (owner[c] != c) continue;
      uint64_t lo = UINT64_MAX, hi = 0;
      for (int d = 0; d < 4; ++d) {
        if (owner[d] != c) continue;
        const auto& s = cols[size_t(d)];
        lo = std::min(lo, s.base + c0 * s.stride);
        hi = std::max(hi, s.base + (c0 + n - 1) * s.stride + uint64_t(s.type.size));
      }
      buf[c].resize(size_t(hi - lo));
      const size_t got = cols[size_t(c)].src->read_at(lo, buf[c].data(), buf[c].size());
      if (got < buf[c].size()) throw DataError(file + ": " + cols[size_t(c)].name + " ends early (truncated file)");
      buf_start[c] = lo;
    }
    auto at = [&](int c, uint64_t r) {
      const auto& s = cols[size_t(c)];
      return buf[owner[c]].data() + (s.base + r * s.stride - buf_start[owner[c]]);
    };
    for (uint64_t r = c0; r < c0 + n; ++r) {
      sink.set_record_index(r);
      bool more;
      if (!tf && !cf) {
        more = sink.add(as_int(at(0, r), cols[0].type), as_int(at(1, r), cols[1].type), as_int(at(2, r), cols[2].type),
                        as_int(at(3, r), cols[3].type));
      } else {
        auto num = [&](int c) { return is_float(cols[size_t(c)].type) ? as_double(at(c, r), cols[size_t(c)].type)
                                                                      : double(as_int(at(c, r), cols[size_t(c)].type)); };
        const double t = tf ? num(0) * scale : double(as_int(at(0, r), cols[0].type));
        if (!cf) more = sink.add_float_time(t, as_int(at(1, r), cols[1].type), as_int(at(2, r), cols[2].type),
                                            as_int(at(3, r), cols[3].type));
        else more = sink.add_float(t, num(1), num(2), num(3));
      }
      if (!more) return;
    }
  }
}

char field_role(std::string n) {
  for (auto& c : n) c = char(std::tolower(static_cast<unsigned char>(c)));
  if (n == "t" || n == "ts" || n == "timestamp" || n == "timestamps" || n == "time") return 't';
  if (n == "x") return 'x';
  if (n == "y") return 'y';
  if (n == "p" || n == "pol" || n == "polarity" || n == "polarities") return 'p';
  return 0;
}

int role_index(char r) { return r == 't' ? 0 : r == 'x' ? 1 : r == 'y' ? 2 : 3; }

// Column specs of one array (N x K plain, or structured with t/x/y/p fields). Returns rows.
uint64_t array_columns(const NpyHeader& h, ByteSource& src, const std::string& what, std::array<ColumnSpec, 4>& cols,
                       std::string& layout) {
  const std::string file = src.name();
  if (h.structured) {
    if (h.shape.size() != 1)
      throw DataError(file + ": " + what + " is a record array of " + std::to_string(h.shape.size()) +
                  " dimensions; expected 1-D with fields x, y, p, t");
    bool have[4] = {false, false, false, false};
    for (const auto& f : h.fields) {
      const char r = field_role(f.name);
      if (!r) continue;
      const int i = role_index(r);
      if (have[i]) throw DataError(file + ": " + what + " has two fields for '" + std::string(1, r) + "'");
      have[i] = true;
      cols[size_t(i)] = {&src, h.data_offset + f.offset, h.itemsize, f.type, what + " field '" + f.name + "'"};
    }
    for (int i = 0; i < 4; ++i)
      if (!have[i])
        throw DataError(file + ": " + what + " is a record array without a '" + std::string(1, "txyp"[i]) +
                    "' field (expected fields x, y, p, t)");
    layout = "record";
    return h.shape[0];
  }
  if (h.shape.size() != 2 || h.shape[1] < 4)
    throw DataError(file + ": " + what + " has shape (" + [&] {
      std::string s;
      for (size_t i = 0; i < h.shape.size(); ++i) s += (i ? ", " : "") + std::to_string(h.shape[i]);
      return s;
    }() + "); expected N x 4 columns t, x, y, p or a record array with fields x, y, p, t");
  const uint64_t n = h.shape[0], k = h.shape[1], sz = h.itemsize;
  if (n > (uint64_t(1) << 40) || k > (uint64_t(1) << 20)) throw DataError(file + ": " + what + " shape is implausible");
  for (int c = 0; c < 4; ++c) {
    if (h.fortran) cols[size_t(c)] = {&src, h.data_offset + uint64_t(c) * n * sz, sz, h.type, what + " column " + std::to_string(c)};
    else cols[size_t(c)] = {&src, h.data_offset + uint64_t(c) * sz, k * sz, h.type, what + " column " + std::to_string(c)};
  }
  layout = h.fortran ? "Nx4-fortran" : "Nx4";
  return n;
}

}  // namespace

void read_npy(ByteSource& src, EventSink& sink) {
  const NpyHeader h = parse_npy_header(src, src.name());
  std::array<ColumnSpec, 4> cols;
  std::string layout;
  const uint64_t rows = array_columns(h, src, "the array", cols, layout);
  sink.report().format = "npy:" + layout;
  decode_columns(cols, rows, sink, src.name());
}

void read_npz(const std::string& path, const uint8_t* data, size_t size, EventSink& sink) {
  NpzArchive archive(path, data, size);
  archive.read(sink);
}

void NpzArchive::read(EventSink& sink) {
  if (members_.empty()) throw DataError(path_ + ": the .npz holds no arrays");
  std::string listing, key;
  for (const auto& [name, idx] : members_) listing += (listing.empty() ? "" : ", ") + name;
  auto has = [&](const std::string& k) {
    return std::any_of(members_.begin(), members_.end(), [&](const auto& m) { return m.first == k; });
  };
  for (const char* k : {"event", "events", "evs"})
    if (has(k)) {
      key = k;
      break;
    }
  // Separate 1-D arrays x, y, p, t (per-frame Fastec files).
  std::string sep[4];
  for (const auto& [name, idx] : members_)
    if (char r = field_role(name)) sep[role_index(r)] = name;
  const bool separate = key.empty() && !sep[0].empty() && !sep[1].empty() && !sep[2].empty() && !sep[3].empty();
  if (key.empty() && !separate) {
    if (members_.size() == 1) key = members_.front().first;
    else
      throw DataError(path_ + ": cannot tell which array holds the events (arrays: " + listing +
                  "); expected 'event'/'events', one array, or separate x, y, p, t");
  }
  std::array<ColumnSpec, 4> cols;
  if (!separate) {
    ZipMemberSource& src = member(key);
    const NpyHeader h = parse_npy_header(src, src.name());
    std::string layout;
    const uint64_t rows = array_columns(h, src, "array '" + key + "'", cols, layout);
    sink.report().format = "npz:" + layout;
    sink.note("events from array '" + key + "'" + (src.stored() ? " (stored)" : " (deflated)"));
    decode_columns(cols, rows, sink, path_);
    return;
  }
  uint64_t rows = 0;
  for (int i = 0; i < 4; ++i) {
    ZipMemberSource& src = member(sep[i]);
    const NpyHeader h = parse_npy_header(src, src.name());
    if (h.structured || h.shape.size() != 1)
      throw DataError(path_ + ": array '" + sep[i] + "' should be 1-D numbers (separate x, y, p, t arrays)");
    if (i == 0) rows = h.shape[0];
    else if (h.shape[0] != rows)
      throw DataError(path_ + ": arrays x, y, p, t have different lengths ('" + sep[0] + "' " + std::to_string(rows) + ", '" +
                  sep[i] + "' " + std::to_string(h.shape[0]) + ")");
    cols[size_t(i)] = {&src, h.data_offset, h.itemsize, h.type, "array '" + sep[i] + "'"};
  }
  sink.report().format = "npz:separate";
  decode_columns(cols, rows, sink, path_);
}

}  // namespace vkunroll::detail
