// Helpers of the kernel parity tests: seeded random host tensors and the max abs difference.
#pragma once
#include <cmath>
#include <random>
#include <string>

#include "vkunroll/kernels/common.hpp"

namespace vkunroll::ktest {

inline HostTensor random_tensor(Shape s, std::mt19937& rng, float lo = -1.f, float hi = 1.f) {
  std::uniform_real_distribution<float> d(lo, hi);
  HostTensor t(s);
  for (auto& v : t.data) v = d(rng);
  return t;
}

// Largest |a - b| over two equally shaped tensors; NaN anywhere counts as infinite.
inline double max_abs_diff(const HostTensor& a, const HostTensor& b) {
  if (!(a.shape == b.shape)) return INFINITY;
  double m = 0;
  for (size_t i = 0; i < a.data.size(); ++i) {
    const double d = std::fabs(static_cast<double>(a.data[i]) - b.data[i]);
    if (!(d <= m)) m = std::isnan(d) ? INFINITY : d;
  }
  return m;
}

// Same, limited to a slice of both (channels [c0, c0+c), all batch items).
inline double max_abs_diff(const HostTensor& a, const HostTensor& b, int64_t c0, int64_t c) {
  if (!(a.shape == b.shape)) return INFINITY;
  double m = 0;
  for (int64_t n = 0; n < a.shape.n; ++n)
    for (int64_t ch = c0; ch < c0 + c; ++ch)
      for (int64_t y = 0; y < a.shape.h; ++y)
        for (int64_t x = 0; x < a.shape.w; ++x) {
          const double d = std::fabs(static_cast<double>(a.at(n, ch, y, x)) - b.at(n, ch, y, x));
          if (!(d <= m)) m = std::isnan(d) ? INFINITY : d;
        }
  return m;
}

}  // namespace vkunroll::ktest
