// Integer helpers shared by the exact row timing (base/row_timing.cpp), the event-tensor
// thresholds (kernels/event_tensor.cpp) and the tile and buffer sizes.
#pragma once
#include <cstdint>

namespace vkunroll {

__extension__ typedef __int128 int128_t;

// v rounded up to a multiple of m (m > 0, v >= 0).
constexpr int64_t round_up(int64_t v, int64_t m) { return (v + m - 1) / m * m; }

constexpr int128_t abs128(int128_t a) { return a < 0 ? -a : a; }
constexpr int128_t gcd128(int128_t a, int128_t b) {
  a = abs128(a);
  b = abs128(b);
  while (b != 0) {
    const int128_t r = a % b;
    a = b;
    b = r;
  }
  return a;
}
// Floor and ceiling of a / b for b > 0 (C++ division truncates toward zero).
// 64-bit division when both fit: several times cheaper than the 128-bit library call (the
// event-tensor planner does N divisions per (job, row)).
constexpr int128_t floor_div(int128_t a, int128_t b) {
  if (a >= INT64_MIN && a <= INT64_MAX && b <= INT64_MAX) {
    const int64_t a64 = static_cast<int64_t>(a), b64 = static_cast<int64_t>(b);
    const int64_t q = a64 / b64;
    return (a64 % b64 != 0 && a64 < 0) ? q - 1 : q;
  }
  const int128_t q = a / b;
  return (a % b != 0 && a < 0) ? q - 1 : q;
}
constexpr int128_t ceil_div(int128_t a, int128_t b) { return -floor_div(-a, b); }

}  // namespace vkunroll
