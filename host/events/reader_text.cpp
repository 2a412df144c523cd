// Text and CSV events: "t x y p" lines by default (any order through text_columns or a header
// line of names), separators space/tab/comma/semicolon, '#' and '%' comments, E2VID's "W H" first
// line, times in s/ms/us/ns converted exactly (decimal arithmetic, rounded to the nearest us).
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <string_view>

#include "vkunroll/host/events/event_reader_detail.hpp"

namespace vkunroll::detail {

namespace {

constexpr size_t kMaxLine = 1 << 16;

__extension__ typedef __int128 I128;  // exact decimal arithmetic for times

// Splits a line on spaces, tabs, commas and semicolons (empty fields from ",," are kept).
void split(std::string_view line, std::vector<std::string_view>& out) {
  out.clear();
  const bool csv = line.find_first_of(",;") != std::string_view::npos;
  size_t i = 0;
  const size_t n = line.size();
  auto is_ws = [](char c) { return c == ' ' || c == '\t' || c == '\r'; };
  while (i < n) {
    while (i < n && is_ws(line[i])) ++i;
    if (i >= n) break;
    size_t j = i;
    while (j < n && !is_ws(line[j]) && line[j] != ',' && line[j] != ';') ++j;
    out.push_back(line.substr(i, j - i));
    while (j < n && is_ws(line[j])) ++j;
    if (csv && j < n && (line[j] == ',' || line[j] == ';')) {
      ++j;
      // ",," or a trailing ',' is an empty field
      size_t k = j;
      while (k < n && is_ws(line[k])) ++k;
      if (k >= n || line[k] == ',' || line[k] == ';') out.push_back(std::string_view());
    }
    i = j;
  }
}

enum class Num { ok, nan, bad };

// Exact decimal -> integer microseconds: value * 10^unit_exp, rounded half away from zero.
Num parse_time(std::string_view s, int unit_exp, int64_t& out, double& as_double) {
  if (s.empty()) return Num::bad;
  std::string_view low = s;
  auto ieq = [](std::string_view a, const char* b) {
    if (a.size() != std::strlen(b)) return false;
    for (size_t i = 0; i < a.size(); ++i)
      if (std::tolower(static_cast<unsigned char>(a[i])) != b[i]) return false;
    return true;
  };
  std::string_view body = low;
  if (!body.empty() && (body[0] == '+' || body[0] == '-')) body.remove_prefix(1);
  if (ieq(body, "nan") || ieq(body, "inf") || ieq(body, "infinity")) {
    as_double = NAN;
    return Num::nan;
  }
  size_t i = 0;
  bool neg = false;
  if (s[i] == '+' || s[i] == '-') neg = s[i++] == '-';
  I128 mant = 0;
  int exp10 = 0, digits = 0, sig = 0;
  bool any = false, dropped_nonzero = false;
  for (; i < s.size() && s[i] >= '0' && s[i] <= '9'; ++i, any = true) {
    if (sig < 30) { mant = mant * 10 + (s[i] - '0'); if (mant) ++sig; }
    else { ++exp10; dropped_nonzero |= s[i] != '0'; }
    ++digits;
  }
  if (i < s.size() && s[i] == '.') {
    ++i;
    for (; i < s.size() && s[i] >= '0' && s[i] <= '9'; ++i, any = true) {
      if (sig < 30) { mant = mant * 10 + (s[i] - '0'); if (mant) ++sig; --exp10; }
      else dropped_nonzero |= s[i] != '0';
    }
  }
  if (!any) return Num::bad;
  if (i < s.size() && (s[i] == 'e' || s[i] == 'E')) {
    ++i;
    int e = 0;
    bool eneg = false;
    if (i < s.size() && (s[i] == '+' || s[i] == '-')) eneg = s[i++] == '-';
    if (i >= s.size()) return Num::bad;
    for (; i < s.size() && s[i] >= '0' && s[i] <= '9'; ++i) e = std::min(e * 10 + (s[i] - '0'), 100000);
    exp10 += eneg ? -e : e;
  }
  if (i != s.size()) return Num::bad;
  (void)dropped_nonzero;
  exp10 += unit_exp;
  const I128 limit = (I128(1) << 62);
  if (exp10 >= 0) {
    for (int k = 0; k < exp10 && mant != 0; ++k) {
      mant *= 10;
      if (mant > limit) { as_double = neg ? -INFINITY : INFINITY; return Num::nan; }
    }
  } else {
    I128 div = 1;
    int k = 0;
    for (; k < -exp10 && div < limit; ++k) div *= 10;
    if (k < -exp10) mant = 0;  // far below a microsecond
    else mant = (mant + div / 2) / div;
  }
  if (mant > limit) { as_double = neg ? -INFINITY : INFINITY; return Num::nan; }
  out = neg ? -int64_t(mant) : int64_t(mant);
  return Num::ok;
}

// Integer (or integral decimal like "12.0") coordinate/polarity token.
bool parse_int(std::string_view s, int64_t& out) {
  if (s.empty()) return false;
  const char* b = s.data();
  const char* e = b + s.size();
  if (*b == '+') ++b;
  auto r = std::from_chars(b, e, out);
  if (r.ec == std::errc() && r.ptr == e) return true;
  double d = 0;
  auto r2 = std::from_chars(b, e, d);
  if (r2.ec != std::errc() || r2.ptr != e || !std::isfinite(d) || d != std::floor(d) || std::fabs(d) > 1e15) return false;
  out = int64_t(d);
  return true;
}

bool parse_polarity(std::string_view s, int64_t& out) {
  if (s == "True" || s == "true" || s == "TRUE") { out = 1; return true; }
  if (s == "False" || s == "false" || s == "FALSE") { out = 0; return true; }
  return parse_int(s, out);
}

bool is_number(std::string_view s) {
  int64_t i;
  double d;
  if (parse_time(s, 0, i, d) != Num::bad) return true;
  return false;
}

// Column name -> role letter.
char role_of(std::string_view name) {
  std::string n(name);
  for (auto& c : n) c = char(std::tolower(static_cast<unsigned char>(c)));
  while (!n.empty() && (n.front() == '"' || n.front() == '\'' || n.front() == '#')) n.erase(n.begin());
  while (!n.empty() && (n.back() == '"' || n.back() == '\'')) n.pop_back();
  if (n == "t" || n == "ts" || n == "time" || n == "timestamp" || n == "timestamps" || n == "t_us" || n == "time_us") return 't';
  if (n == "x") return 'x';
  if (n == "y") return 'y';
  if (n == "p" || n == "pol" || n == "polarity" || n == "polarities") return 'p';
  return '_';
}

// Line iterator over a byte source in 1 MiB blocks.
class LineReader {
 public:
  explicit LineReader(ByteSource& src) : src_(src) {}
  // False at the end. `line` excludes the newline; lines longer than kMaxLine are an error.
  bool next(std::string_view& line) {
    for (;;) {
      const size_t nl = static_cast<size_t>(std::find(buf_.begin() + long(pos_), buf_.end(), '\n') - buf_.begin());
      if (nl < buf_.size()) {
        line = std::string_view(buf_.data() + pos_, nl - pos_);
        pos_ = nl + 1;
        ++line_no_;
        return true;
      }
      if (eof_) {
        if (pos_ >= buf_.size()) return false;
        line = std::string_view(buf_.data() + pos_, buf_.size() - pos_);
        pos_ = buf_.size();
        ++line_no_;
        return true;
      }
      if (buf_.size() - pos_ > kMaxLine)
        throw Error(src_.name() + ": line " + std::to_string(line_no_ + 1) + " is longer than " +
                    std::to_string(kMaxLine) + " bytes (not a text event file?)");
      buf_.erase(buf_.begin(), buf_.begin() + long(pos_));
      pos_ = 0;
      const size_t old = buf_.size();
      const size_t step = size_t(std::min<uint64_t>(1 << 20, src_.size() > offset_ ? src_.size() - offset_ : 0));
      buf_.resize(old + step);
      const size_t got = step ? src_.read_at(offset_, buf_.data() + old, step) : 0;
      buf_.resize(old + got);
      offset_ += got;
      if (got == 0) eof_ = true;
    }
  }
  uint64_t line_no() const { return line_no_; }

 private:
  ByteSource& src_;
  std::vector<char> buf_;
  size_t pos_ = 0;
  uint64_t offset_ = 0;
  uint64_t line_no_ = 0;
  bool eof_ = false;
};

bool is_comment(std::string_view l) {
  size_t i = 0;
  while (i < l.size() && (l[i] == ' ' || l[i] == '\t')) ++i;
  return i < l.size() && (l[i] == '#' || l[i] == '%' || (l[i] == '/' && i + 1 < l.size() && l[i + 1] == '/'));
}

bool is_blank(std::string_view l) {
  for (char c : l)
    if (c != ' ' && c != '\t' && c != '\r') return false;
  return true;
}

// "# width 346 height 260" (the project's writer) -> geometry.
bool parse_size_comment(std::string_view l, int& w, int& h) {
  std::vector<std::string_view> tok;
  split(l, tok);
  for (size_t i = 0; i + 3 < tok.size(); ++i) {
    if (tok[i] == "width" && tok[i + 2] == "height") {
      int64_t a, b;
      if (parse_int(tok[i + 1], a) && parse_int(tok[i + 3], b) && a > 0 && b > 0 && a <= 65536 && b <= 65536) {
        w = int(a);
        h = int(b);
        return true;
      }
    }
  }
  return false;
}

}  // namespace

void read_text(ByteSource& src, EventSink& sink) {
  const EventReadOptions& o = sink.options();
  const std::string& file = src.name();
  // Column layout: user option, possibly replaced by a header line of names when left default.
  std::string columns = o.text_columns.empty() ? "txyp" : o.text_columns;
  auto check_columns = [&](const std::string& c, const std::string& from) {
    for (char r : std::string("txyp"))
      if (std::count(c.begin(), c.end(), r) != 1)
        throw Error(file + ": text column order '" + c + "' from " + from +
                    " must name each of t, x, y, p exactly once ('_' skips a column)");
    for (char r : c)
      if (r != 't' && r != 'x' && r != 'y' && r != 'p' && r != '_')
        throw Error(file + ": text column order '" + c + "' from " + from + " has '" + std::string(1, r) +
                    "' (allowed: t, x, y, p, _)");
  };
  check_columns(columns, "the options");
  const bool columns_from_user = o.text_columns != "txyp" && !o.text_columns.empty();

  // Pre-scan up to 1000 data lines: header, E2VID size line, time unit.
  bool e2vid = false, header_line = false;
  int size_w = 0, size_h = 0;
  std::string size_source;
  bool many_decimals = false;
  {
    LineReader lr(src);
    std::string_view line;
    std::vector<std::string_view> tok;
    int data_lines = 0;
    bool first = true;
    while (data_lines < 1000 && lr.next(line)) {
      if (is_blank(line)) continue;
      if (is_comment(line)) {
        if (first && size_w == 0 && parse_size_comment(line, size_w, size_h)) size_source = "the '# width W height H' comment";
        continue;
      }
      split(line, tok);
      if (first) {
        first = false;
        int64_t a, b;
        if (tok.size() == 2 && parse_int(tok[0], a) && parse_int(tok[1], b)) {
          e2vid = true;
          size_w = int(std::clamp<int64_t>(a, 0, 1 << 20));
          size_h = int(std::clamp<int64_t>(b, 0, 1 << 20));
          size_source = "the E2VID 'W H' first line";
          continue;
        }
        if (!tok.empty() && !is_number(tok[0])) {
          header_line = true;
          if (!columns_from_user) {
            std::string c;
            for (auto t : tok) c += role_of(t);
            bool complete = true;
            for (char r : std::string("txyp")) complete &= std::count(c.begin(), c.end(), r) == 1;
            if (complete) {
              while (!c.empty() && c.back() == '_') c.pop_back();
              columns = c;
              sink.note("column order '" + columns + "' from the header line");
            }
          }
          continue;
        }
      }
      ++data_lines;
      const size_t tcol = columns.find('t');
      if (tcol < tok.size()) {
        const auto ts = tok[tcol];
        const size_t dot = ts.find('.');
        if (dot != std::string_view::npos) {
          size_t k = dot + 1, nd = 0;
          while (k < ts.size() && ts[k] >= '0' && ts[k] <= '9') ++k, ++nd;
          if (nd > 3) many_decimals = true;
        }
      }
    }
  }
  if (size_w > 0 && size_h > 0) sink.set_file_geometry(size_w, size_h, size_source);
  std::string unit = o.text_time_unit;
  if (unit.empty()) {
    if (e2vid) unit = "s", sink.note("time unit: seconds (E2VID 'W H' first line)");
    else if (many_decimals) unit = "s", sink.note("time unit: seconds (time values with more than 3 decimals)");
    else unit = "us";
  }
  const int unit_exp = time_unit_exponent(unit, file);
  sink.report().time_unit = unit;

  size_t need = 0;
  int ct = -1, cx = -1, cy = -1, cp = -1;
  for (size_t i = 0; i < columns.size(); ++i) {
    if (columns[i] == 't') ct = int(i);
    if (columns[i] == 'x') cx = int(i);
    if (columns[i] == 'y') cy = int(i);
    if (columns[i] == 'p') cp = int(i);
  }
  need = size_t(std::max({ct, cx, cy, cp})) + 1;

  LineReader lr(src);
  std::string_view line;
  std::vector<std::string_view> tok;
  bool first = true;
  uint64_t record = 0;
  while (lr.next(line)) {
    if (is_blank(line) || is_comment(line)) continue;
    if (first) {
      first = false;
      if (e2vid || header_line) continue;
    }
    sink.set_line(lr.line_no());
    sink.set_record_index(record++);
    split(line, tok);
    if (tok.size() < need) {
      sink.unknown_record_lazy([&] {
        return "has " + std::to_string(tok.size()) + " fields, expected at least " + std::to_string(need) + " (columns '" +
               columns + "')";
      });
      continue;
    }
    int64_t t = 0, x = 0, y = 0, p = 0;
    double td = 0;
    const Num tn = parse_time(tok[size_t(ct)], unit_exp, t, td);
    if (tn == Num::bad) {
      sink.unknown_record_lazy([&] { return "time '" + std::string(tok[size_t(ct)].substr(0, 40)) + "' is not a number"; });
      continue;
    }
    if (!parse_int(tok[size_t(cx)], x) || !parse_int(tok[size_t(cy)], y)) {
      sink.unknown_record_lazy([&] {
        return "x '" + std::string(tok[size_t(cx)].substr(0, 40)) + "' / y '" + std::string(tok[size_t(cy)].substr(0, 40)) +
               "' is not an integer pixel coordinate";
      });
      continue;
    }
    if (!parse_polarity(tok[size_t(cp)], p)) {
      sink.unknown_record_lazy(
          [&] { return "polarity '" + std::string(tok[size_t(cp)].substr(0, 40)) + "' is not 0/1, -1/+1 or true/false"; });
      continue;
    }
    const bool more = tn == Num::nan ? sink.add_float_time(td, x, y, p) : sink.add(t, x, y, p);
    if (!more) break;
  }
  sink.set_line(0);
}

}  // namespace vkunroll::detail
