// Rolling-shutter row timing, in exact rational microseconds.
//
// Why rationals: event times are integer microseconds, but row times are not (a Gev-RS-Real
// line delay is readout / (H - 1), e.g. 73000/259 us). Every time here is a Rational (128-bit
// numerator and denominator, always reduced), so "is this event before row y's start" and
// "which of N bins" are answered exactly; the event-tensor builder turns them into integer
// thresholds the GPU compares with 32-bit ints. Where float64 is exact (integers, dyadic
// fractions) the answers equal the reference's float64 arithmetic.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "vkunroll/base/int_math.hpp"

namespace vkunroll {

class Rational {
 public:
  Rational() = default;
  Rational(int64_t v) : num_(v), den_(1) {}  // NOLINT: integers convert implicitly
  Rational(int128_t num, int128_t den);       // throws Error on den == 0

  // The simplest fraction (continued fractions, denominator <= 2^32) that rounds to exactly `v`
  // as a float64; else v's exact binary value. 0.1 -> 1/10, 281.8532818532818 -> 73000/259.
  static Rational from_double(double v);
  // "12", "-3.25", "1e3", "2.5e-1", "73000/259", "-1/3": exact. Throws Error naming `what`.
  static Rational parse(const std::string& text, const std::string& what = "value");

  int128_t num() const { return num_; }
  int128_t den() const { return den_; }
  double to_double() const;
  int64_t floor() const;  // throws if out of int64 range
  int64_t ceil() const;
  std::string str() const;  // "73000/259" or "12"

  friend Rational operator+(const Rational& a, const Rational& b);
  friend Rational operator-(const Rational& a, const Rational& b);
  friend Rational operator*(const Rational& a, const Rational& b);
  friend Rational operator/(const Rational& a, const Rational& b);
  Rational operator-() const { return Rational(-num_, den_); }
  Rational& operator+=(const Rational& o) { return *this = *this + o; }
  Rational& operator-=(const Rational& o) { return *this = *this - o; }
  friend int compare(const Rational& a, const Rational& b);  // -1, 0, +1
  friend bool operator==(const Rational& a, const Rational& b) { return compare(a, b) == 0; }
  friend bool operator!=(const Rational& a, const Rational& b) { return compare(a, b) != 0; }
  friend bool operator<(const Rational& a, const Rational& b) { return compare(a, b) < 0; }
  friend bool operator<=(const Rational& a, const Rational& b) { return compare(a, b) <= 0; }
  friend bool operator>(const Rational& a, const Rational& b) { return compare(a, b) > 0; }
  friend bool operator>=(const Rational& a, const Rational& b) { return compare(a, b) >= 0; }

 private:
  int128_t num_ = 0, den_ = 1;  // den_ > 0, gcd(num_, den_) == 1
};

enum class Readout { top_down, bottom_up };
const char* readout_name(Readout r);          // "top-down", "bottom-up"
Readout parse_readout(const std::string& s);  // throws Error on anything else

// How the target instant t* of a (frame, target) pair is given.
struct Target {
  enum class Kind { tau, absolute_us } kind = Kind::tau;
  Rational value;  // tau (normalized), or t* in microseconds
  static Target tau(Rational v) { return {Kind::tau, v}; }
  static Target absolute(Rational us) { return {Kind::absolute_us, us}; }
};

// Timing of one RS frame. Row y is read as the r-th row, r = y (top-down) or H-1-y (bottom-up);
// start(y) = t0 + r * line_delay, end(y) = start(y) + exposure.
struct RowTiming {
  Rational t0;           // exposure start of the first row read out, us
  Rational line_delay;   // start of read-out row r+1 minus start of row r, us (>= 0)
  Rational exposure;     // row exposure, us (> 0)
  int rows = 0;          // sensor height H
  Readout readout = Readout::top_down;

  int read_index(int y) const { return readout == Readout::top_down ? y : rows - 1 - y; }
  Rational start(int y) const;  // throws Error if y is not in [0, rows)
  Rational end(int y) const;
  // start(y) / end(y) of every row as float64 microseconds (what the physics gatherer reads).
  std::vector<double> start_times_us() const;
  std::vector<double> end_times_us() const;
  // First row's start and last read-out row's end: the frame's full span.
  Rational first_start() const { return t0; }
  Rational last_end() const;
  // The reference's normalized target: t* = start[0] + tau * (end[H-1] - start[0]) for
  // top-down. For bottom-up the same formula in read-out order: t* = t0 + tau * (last_end - t0),
  // so tau = 0 is always the exposure start of the first row read and tau = 1 the exposure end
  // of the last row read. tau outside [0, 1] is an inter-frame target.
  Rational target_time(const Rational& tau) const { return t0 + tau * (last_end() - t0); }
  Rational resolve(const Target& t) const { return t.kind == Target::Kind::tau ? target_time(t.value) : t.value; }
  // Inverse of target_time.
  Rational tau_of(const Rational& t_us) const { return (t_us - t0) / (last_end() - t0); }
  void validate(const std::string& what) const;  // rows > 0, delay >= 0, exposure > 0
};

}  // namespace vkunroll
