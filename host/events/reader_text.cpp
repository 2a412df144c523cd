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

enum class Num { ok, nan, overflow, bad };  // nan: NaN or +-inf (as_double says which)

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
  if (ieq(body, "nan")) {
    as_double = NAN;
    return Num::nan;
  }
  if (ieq(body, "inf") || ieq(body, "infinity")) {
    as_double = s[0] == '-' ? -INFINITY : INFINITY;
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
  auto too_large = [&] { return Num::overflow; };  // beyond int64 microseconds
  if (exp10 >= 0) {
    for (int k = 0; k < exp10 && mant != 0; ++k) {
      mant *= 10;
      if (mant > limit) return too_large();
    }
  } else {
    I128 div = 1;
    int k = 0;
    for (; k < -exp10 && div < limit; ++k) div *= 10;
    if (k < -exp10) mant = 0;  // far below a microsecond
    else mant = (mant + div / 2) / div;
  }
  if (mant > limit) return too_large();
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

// Line iterator over a byte source in 1 MiB blocks, from `offset` (a line start) on.
class LineReader {
 public:
  LineReader(ByteSource& src, uint64_t offset = 0, uint64_t lines_before = 0)
      : src_(src), offset_(offset), base_(offset), line_no_(lines_before) {}
  // False at the end. `line` excludes the newline; lines longer than kMaxLine are an error.
  bool next(std::string_view& line) {
    for (;;) {
      const size_t nl = static_cast<size_t>(std::find(buf_.begin() + long(pos_), buf_.end(), '\n') - buf_.begin());
      if (nl < buf_.size() || (eof_ && pos_ < buf_.size())) {
        const size_t end = nl < buf_.size() ? nl : buf_.size();
        line = std::string_view(buf_.data() + pos_, end - pos_);
        line_offset_ = base_ + pos_;
        pos_ = nl < buf_.size() ? nl + 1 : buf_.size();
        ++line_no_;
        // A UTF-8 byte-order mark (spreadsheet exports) would hide the header line's first name.
        if (line_offset_ == 0 && line.substr(0, 3) == "\xEF\xBB\xBF") line.remove_prefix(3);
        return true;
      }
      if (eof_) return false;
      if (buf_.size() - pos_ > kMaxLine)
        throw DataError(src_.name() + ": line " + std::to_string(line_no_ + 1) + " is longer than " +
                    std::to_string(kMaxLine) + " bytes (not a text event file?)");
      buf_.erase(buf_.begin(), buf_.begin() + long(pos_));
      base_ += pos_;
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
  uint64_t line_offset() const { return line_offset_; }  // byte offset of the line last returned

 private:
  ByteSource& src_;
  std::vector<char> buf_;
  size_t pos_ = 0;
  uint64_t offset_ = 0;  // next byte to read from the source
  uint64_t base_ = 0;    // file offset of buf_[0]
  uint64_t line_no_ = 0;
  uint64_t line_offset_ = 0;
  bool eof_ = false;
};

// A token for a message: at most 40 bytes, bytes outside printable ASCII written as \xNN.
std::string shown(std::string_view t) {
  static const char* hexd = "0123456789abcdef";
  std::string out;
  for (size_t i = 0; i < t.size() && i < 40; ++i) {
    const unsigned char c = static_cast<unsigned char>(t[i]);
    if (c >= 0x20 && c < 0x7f) out += char(c);
    else out += std::string("\\x") + hexd[c >> 4] + hexd[c & 15];
  }
  if (t.size() > 40) out += "...";
  return out;
}

// Text holds no NUL and few control bytes; a binary file read as text gets an error that says
// what it looks like and how to read it.
void refuse_binary(ByteSource& src) {
  const auto head = read_range(src, 0, 1 << 16);
  size_t first_bad = head.size(), control = 0;
  for (size_t i = 0; i < head.size(); ++i) {
    const uint8_t c = head[i];
    if (c < 0x20 && c != '\t' && c != '\n' && c != '\r' && c != '\f' && c != '\v') {
      ++control;
      if (first_bad == head.size() || c == 0) first_bad = std::min(first_bad, i);
      if (c == 0) break;
    }
  }
  // A NUL, or many control bytes (a stray one in a line is a bad record, reported as such).
  const bool has_nul = std::find(head.begin(), head.end(), uint8_t(0)) != head.end();
  if (!has_nul && (control <= 4 || control * 50 <= head.size())) return;
  const BinaryGuess g = guess_binary_format(src);
  std::string msg = src.name() + ": not a text event file: byte " + std::to_string(first_bad) + " is binary (0x" +
                    [&] {
                      static const char* d = "0123456789abcdef";
                      const uint8_t c = first_bad < head.size() ? head[first_bad] : 0;
                      return std::string{d[c >> 4], d[c & 15]};
                    }() + ")";
  if (!g.format.empty())
    msg += "; it looks like " + g.description + ": read it with " + opt("format") + " " + g.format + " (EventReadOptions::format = \"" +
           g.format + "\") or give it the " + g.extension + " extension";
  else
    msg += "; " + g.description + " (pass " + opt("format") + " if it is one of " + event_format_names() + ")";
  throw DataError(msg);
}

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

namespace {

// What the first 1000 data lines say: column order, header or E2VID size line, time unit.
struct TextLayout {
  int width = 0, height = 0;        // from a size comment or E2VID's first line
  std::string size_source, unit;
  std::vector<std::string> notes;
  std::string columns;
  bool skip_first = false;  // the first data line is a header or E2VID's "W H"
  int unit_exp = 0;
  int ct = -1, cx = -1, cy = -1, cp = -1;
  size_t need = 0;  // fields a line must have
};

void check_columns(const std::string& file, const std::string& c, const std::string& from) {
  const std::string problem = text_columns_problem(c);
  if (!problem.empty()) throw DataError(file + ": text column order '" + c + "' from " + from + " " + problem);
}

TextLayout prescan_text(ByteSource& src, const EventReadOptions& o) {
  const std::string& file = src.name();
  // Column layout: user option, possibly replaced by a header line of names when left default.
  TextLayout L;
  L.columns = o.text_columns.empty() ? "txyp" : o.text_columns;
  check_columns(file, L.columns, "the options");
  const bool columns_from_user = o.text_columns != "txyp" && !o.text_columns.empty();
  bool e2vid = false, many_decimals = false;
  int size_w = 0, size_h = 0;
  std::string size_source;
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
        e2vid = L.skip_first = true;
        size_w = int(std::clamp<int64_t>(a, 0, 1 << 20));
        size_h = int(std::clamp<int64_t>(b, 0, 1 << 20));
        size_source = "the E2VID 'W H' first line";
        continue;
      }
      if (!tok.empty() && !is_number(tok[0])) {
        L.skip_first = true;
        if (!columns_from_user) {
          std::string c;
          for (auto t : tok) c += role_of(t);
          bool complete = true;
          for (char r : std::string("txyp")) complete &= std::count(c.begin(), c.end(), r) == 1;
          if (complete) {
            while (!c.empty() && c.back() == '_') c.pop_back();
            L.columns = c;
            L.notes.push_back("column order '" + L.columns + "' from the header line");
          }
        }
        continue;
      }
    }
    ++data_lines;
    const size_t tcol = L.columns.find('t');
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
  if (size_w > 0 && size_h > 0) L.width = size_w, L.height = size_h, L.size_source = size_source;
  std::string unit = o.text_time_unit;
  if (unit.empty()) {
    if (e2vid) unit = "s", L.notes.push_back("time unit: seconds (E2VID 'W H' first line)");
    else if (many_decimals) unit = "s", L.notes.push_back("time unit: seconds (time values with more than 3 decimals)");
    else unit = "us";
  }
  L.unit_exp = time_unit_exponent(unit, file);
  L.unit = unit;
  for (size_t i = 0; i < L.columns.size(); ++i) {
    if (L.columns[i] == 't') L.ct = int(i);
    if (L.columns[i] == 'x') L.cx = int(i);
    if (L.columns[i] == 'y') L.cy = int(i);
    if (L.columns[i] == 'p') L.cp = int(i);
  }
  L.need = size_t(std::max({L.ct, L.cx, L.cy, L.cp})) + 1;
  return L;
}

// One data line into the sink; false when the sink says stop.
bool text_record(const TextLayout& L, std::vector<std::string_view>& tok, EventSink& sink) {
  if (tok.size() < L.need) {
    sink.unknown_record_lazy([&] {
      return "has " + std::to_string(tok.size()) + " fields, expected at least " + std::to_string(L.need) + " (columns '" +
             L.columns + "')";
    });
    return true;
  }
  int64_t t = 0, x = 0, y = 0, p = 0;
  double td = 0;
  const auto tt = tok[size_t(L.ct)], tx = tok[size_t(L.cx)], ty = tok[size_t(L.cy)], tp = tok[size_t(L.cp)];
  const Num tn = parse_time(tt, L.unit_exp, t, td);
  if (tn == Num::bad) {
    sink.unknown_record_lazy([&] { return "time '" + shown(tt) + "' is not a number"; });
    return true;
  }
  if (tn == Num::overflow)
    return sink.bad_time([&] {
      return "time '" + shown(tt) + "' (" + L.unit + ") " + kEventTimeRule;
    });
  if (!parse_int(tx, x) || !parse_int(ty, y)) {
    sink.unknown_record_lazy(
        [&] { return "x '" + shown(tx) + "' / y '" + shown(ty) + "' is not an integer pixel coordinate"; });
    return true;
  }
  if (!parse_polarity(tp, p)) {
    sink.unknown_record_lazy([&] { return "polarity '" + shown(tp) + "' is not 0/1, -1/+1 or true/false"; });
    return true;
  }
  return tn == Num::nan ? sink.add_float_time(td, x, y, p) : sink.add(t, x, y, p);
}

// The layout of the file: parsed from its first lines, or kept from an earlier read of the index.
std::shared_ptr<const TextLayout> text_layout(ByteSource& src, EventSink& sink) {
  StreamIndex* ix = sink.index();
  if (ix && ix->header) return std::static_pointer_cast<const TextLayout>(ix->header);
  refuse_binary(src);
  auto L = std::make_shared<const TextLayout>(prescan_text(src, sink.options()));
  if (ix) ix->header = L;
  return L;
}

}  // namespace

void read_text(ByteSource& src, EventSink& sink) {
  const std::shared_ptr<const TextLayout> layout = text_layout(src, sink);
  const TextLayout& L = *layout;
  if (L.width > 0 && L.height > 0) sink.set_file_geometry(L.width, L.height, L.size_source);
  for (const auto& n : L.notes) sink.note(n);
  sink.report().time_unit = L.unit;
  uint64_t start = 0, lines_before = 0, record = 0;
  bool first = true;  // no data line seen yet (it may be a header to skip)
  if (const Checkpoint* c = sink.resume_point()) {
    start = c->offset, lines_before = c->line, record = c->record, first = c->state[0] != 0;
    sink.resume(*c);
  }
  auto checkpoint = [&](uint64_t offset, uint64_t lines) {
    Checkpoint c;
    c.offset = offset, c.line = lines, c.record = record, c.state[0] = first;
    return c;
  };
  if (!sink.boundary(checkpoint(start, lines_before))) return;
  uint64_t next = sink.next_checkpoint(start, 0);
  LineReader lr(src, start, lines_before);
  std::string_view line;
  std::vector<std::string_view> tok;
  bool stopped = false;
  while (lr.next(line)) {
    if (lr.line_offset() >= next) {
      if (!sink.boundary(checkpoint(lr.line_offset(), lr.line_no() - 1))) {
        stopped = true;
        break;
      }
      next = sink.next_checkpoint(lr.line_offset(), 0);
    }
    if (is_blank(line) || is_comment(line)) continue;
    if (first) {
      first = false;
      if (L.skip_first) continue;
    }
    sink.set_line(lr.line_no());
    sink.set_record_index(record++);
    split(line, tok);
    if (!text_record(L, tok, sink)) {
      stopped = true;
      break;
    }
  }
  if (!stopped) sink.end_of_data(checkpoint(src.size(), lr.line_no()));
  sink.set_line(0);
}

}  // namespace vkunroll::detail

namespace vkunroll {

std::string text_columns_problem(const std::string& c) {
  for (char r : c)
    if (r != 't' && r != 'x' && r != 'y' && r != 'p' && r != '_')
      return "has '" + std::string(1, r) + "' (allowed: t, x, y, p, _)";
  for (char r : std::string("txyp"))
    if (std::count(c.begin(), c.end(), r) != 1) return "must name each of t, x, y, p exactly once ('_' skips a column)";
  if (c.size() > 64) return "has " + std::to_string(c.size()) + " columns (at most 64)";
  return {};
}

}  // namespace vkunroll
