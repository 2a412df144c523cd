#include "vkunroll/base/row_timing.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>

#include "vkunroll/base/error.hpp"

namespace vkunroll {
namespace {

// Values beyond this are rejected so products of two values cannot overflow 128 bits silently.
const int128_t kLimit = static_cast<int128_t>(1) << 120;

int bits(int128_t v) {
  v = abs128(v);
  int n = 0;
  while (v) {
    ++n;
    v >>= 1;
  }
  return n;
}

int128_t mul_checked(int128_t a, int128_t b) {
  if (bits(a) + bits(b) > 125) throw TimeRangeError("Rational: time arithmetic overflows 128 bits (denominators too large)");
  return a * b;
}

std::string to_string128(int128_t v) {
  if (v == 0) return "0";
  const bool neg = v < 0;
  std::string s;
  while (v) {
    int d = static_cast<int>(v % 10);
    s.insert(s.begin(), static_cast<char>('0' + (d < 0 ? -d : d)));
    v /= 10;
  }
  return neg ? "-" + s : s;
}

}  // namespace

Rational::Rational(int128_t num, int128_t den) {
  if (den == 0) throw TimeRangeError("Rational: zero denominator");
  if (den < 0) {
    num = -num;
    den = -den;
  }
  const int128_t g = gcd128(num, den);
  num_ = g ? num / g : 0;
  den_ = g ? den / g : 1;
  if (abs128(num_) > kLimit || den_ > kLimit) throw TimeRangeError("Rational: value out of the 120-bit range");
}

Rational Rational::from_double(double v) {
  if (!std::isfinite(v)) throw TimeRangeError("Rational: non-finite time value " + std::to_string(v));
  if (v == std::floor(v) && std::fabs(v) < 9e18) return Rational(static_cast<int64_t>(v));
  // Continued-fraction convergents: the first p/q that rounds back to v is the number meant.
  const double sign = v < 0 ? -1.0 : 1.0;
  double x = std::fabs(v);
  int128_t p0 = 0, q0 = 1, p1 = 1, q1 = 0;
  double r = x;
  for (int i = 0; i < 64; ++i) {
    const double a = std::floor(r);
    if (a > 1e18) break;
    const auto ai = static_cast<int128_t>(a);
    const int128_t p2 = ai * p1 + p0, q2 = ai * q1 + q0;
    if (q2 > (static_cast<int128_t>(1) << 32)) break;
    if (static_cast<double>(p2) / static_cast<double>(q2) == x) return Rational(sign < 0 ? -p2 : p2, q2);
    p0 = p1;
    q0 = q1;
    p1 = p2;
    q1 = q2;
    const double frac = r - a;
    if (frac <= 0) break;
    r = 1.0 / frac;
  }
  // The exact binary value of the double.
  int e = 0;
  const double m = std::frexp(x, &e);  // x = m * 2^e, m in [0.5, 1)
  const auto mant = static_cast<int128_t>(std::ldexp(m, 53));
  int shift = e - 53;
  if (shift < -110 || shift > 60) throw TimeRangeError("Rational: time value " + std::to_string(v) + " is out of range");
  Rational out = shift >= 0 ? Rational(mant << shift, 1) : Rational(mant, static_cast<int128_t>(1) << (-shift));
  return sign < 0 ? -out : out;
}

Rational Rational::parse(const std::string& text, const std::string& what) {
  auto fail = [&](const std::string& why) -> Rational {
    throw DataError(what + ": '" + text + "' is not a number (" + why + "); expected e.g. 12, -3.25, 1e3 or 73000/259");
  };
  // One grammar for exact times: [sign] digits [. digits] [e [sign] digits] [/ the same], spaces
  // only around the whole ("60 000" is not 60000).
  size_t b = 0, e = text.size();
  while (b < e && std::isspace(static_cast<unsigned char>(text[b]))) ++b;
  while (e > b && std::isspace(static_cast<unsigned char>(text[e - 1]))) --e;
  const std::string s = text.substr(b, e - b);
  if (s.empty()) return fail("empty");
  for (char c : s)
    if (std::isspace(static_cast<unsigned char>(c))) return fail("a space inside it");
  const auto slash = s.find('/');
  if (slash != std::string::npos) {
    if (s.find('/', slash + 1) != std::string::npos) return fail("more than one '/': a fraction is a single a/b");
    Rational n = parse(s.substr(0, slash), what), d = parse(s.substr(slash + 1), what);
    if (d.num() == 0) return fail("zero denominator");
    return n / d;
  }
  size_t i = 0;
  bool neg = false;
  if (s[i] == '+' || s[i] == '-') neg = s[i++] == '-';
  int128_t num = 0, den = 1;
  int digits = 0;
  bool dot = false;
  for (; i < s.size(); ++i) {
    const char c = s[i];
    if (std::isdigit(static_cast<unsigned char>(c))) {
      if (digits > 30) return fail("too many digits");
      num = num * 10 + (c - '0');
      if (dot) den *= 10;
      if (num || dot) ++digits;
    } else if (c == '.' && !dot) {
      dot = true;
    } else {
      break;
    }
  }
  if (i == 0 || (i == 1 && (s[0] == '+' || s[0] == '-'))) return fail("no digits");
  int exp10 = 0;
  if (i < s.size() && (s[i] == 'e' || s[i] == 'E')) {
    ++i;
    bool eneg = false;
    if (i < s.size() && (s[i] == '+' || s[i] == '-')) eneg = s[i++] == '-';
    if (i >= s.size()) return fail("empty exponent");
    for (; i < s.size() && std::isdigit(static_cast<unsigned char>(s[i])); ++i) {
      exp10 = exp10 * 10 + (s[i] - '0');
      if (exp10 > 30) return fail("exponent too large");
    }
    if (eneg) exp10 = -exp10;
  }
  if (i != s.size()) return fail("unexpected '" + s.substr(i) + "'");
  for (; exp10 > 0; --exp10) num *= 10;
  for (; exp10 < 0; ++exp10) den *= 10;
  return Rational(neg ? -num : num, den);
}

double Rational::to_double() const { return static_cast<double>(num_) / static_cast<double>(den_); }
int64_t Rational::floor() const {
  const int128_t f = floor_div(num_, den_);
  if (f > std::numeric_limits<int64_t>::max() || f < std::numeric_limits<int64_t>::min())
    throw TimeRangeError("Rational: " + str() + " out of int64 range");
  return static_cast<int64_t>(f);
}
int64_t Rational::ceil() const { return -(-*this).floor(); }
std::string Rational::str() const { return den_ == 1 ? to_string128(num_) : to_string128(num_) + "/" + to_string128(den_); }

Rational operator+(const Rational& a, const Rational& b) {
  if (a.den_ == b.den_) return Rational(a.num_ + b.num_, a.den_);
  const int128_t g = gcd128(a.den_, b.den_);
  const int128_t bd = b.den_ / g;
  return Rational(mul_checked(a.num_, bd) + mul_checked(b.num_, a.den_ / g), mul_checked(a.den_, bd));
}
Rational operator-(const Rational& a, const Rational& b) { return a + (-b); }
Rational operator*(const Rational& a, const Rational& b) {
  const int128_t g1 = gcd128(a.num_, b.den_) ? gcd128(a.num_, b.den_) : 1;
  const int128_t g2 = gcd128(b.num_, a.den_) ? gcd128(b.num_, a.den_) : 1;
  return Rational(mul_checked(a.num_ / g1, b.num_ / g2), mul_checked(a.den_ / g2, b.den_ / g1));
}
Rational operator/(const Rational& a, const Rational& b) {
  if (b.num_ == 0) throw TimeRangeError("Rational: division by zero");
  return a * Rational(b.den_, b.num_);
}
int compare(const Rational& a, const Rational& b) {
  const int128_t l = mul_checked(a.num_, b.den_), r = mul_checked(b.num_, a.den_);
  return l < r ? -1 : (l > r ? 1 : 0);
}

const char* readout_name(Readout r) { return r == Readout::top_down ? "top-down" : "bottom-up"; }
Readout parse_readout(const std::string& s) {
  if (s == "top-down" || s == "top_down") return Readout::top_down;
  if (s == "bottom-up" || s == "bottom_up") return Readout::bottom_up;
  throw UsageError("readout: '" + s + "' is not a readout direction (expected \"top-down\" or \"bottom-up\")");
}

Rational RowTiming::start(int y) const {
  if (y < 0 || y >= rows)
    throw UsageError("RowTiming: row " + std::to_string(y) + " outside [0, " + std::to_string(rows) + ")");
  return t0 + line_delay * Rational(read_index(y));
}
Rational RowTiming::end(int y) const { return start(y) + exposure; }
std::vector<double> RowTiming::start_times_us() const {
  std::vector<double> v(static_cast<size_t>(std::max(rows, 0)));
  for (int y = 0; y < rows; ++y) v[y] = start(y).to_double();
  return v;
}

std::vector<double> RowTiming::end_times_us() const {
  std::vector<double> v(static_cast<size_t>(std::max(rows, 0)));
  for (int y = 0; y < rows; ++y) v[y] = end(y).to_double();
  return v;
}

Rational RowTiming::last_end() const { return t0 + line_delay * Rational(rows - 1) + exposure; }

void RowTiming::validate(const std::string& what) const {
  if (rows <= 0) throw DataError(what + ": row count must be positive, got " + std::to_string(rows));
  if (line_delay < Rational(0)) throw DataError(what + ": line delay must be >= 0 us, got " + line_delay.str());
  if (exposure <= Rational(0)) throw DataError(what + ": exposure must be > 0 us, got " + exposure.str());
}

}  // namespace vkunroll
