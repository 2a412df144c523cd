// Helpers of the kernel parity tests: seeded random host tensors and the max abs difference.
#pragma once
#include <algorithm>
#include <cmath>
#include <random>
#include <string>

#include "vkunroll/kernels/common.hpp"
#include "vkunroll/base/half.hpp"
#include "vkunroll/runtime/tensor.hpp"

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

// ---- canaries: an op must write nothing outside its output slice ----------------------------
// A value no op of these tests produces by chance, exact in fp32 and fp16.
constexpr float kCanary = 1234.f;

// An output slice inside a larger tensor: `c_before` channels before it and `c_after` after it,
// one batch item before it and one after, every element outside the slice holding kCanary (the
// slice itself random, so an op must overwrite it). Elements between the slice's batch items (n >=
// 2) and the alignment slack before its first element lie inside the slice's binding; on a
// whole_tensor_bindings context (vktest::whole_binding_context) every canary does, so a stray write
// lands on one instead of past the binding, where lavapipe drops it.
struct CanarySlice {
  HostTensor host;  // the tensor's contents before the op
  int64_t c0 = 0, c = 0, n0 = 0, n = 0;
  HostSliceOut of(HostTensor& t) const { return HostSliceOut(t, c0, c, n0, n); }
  Slice of(const Tensor& t) const { return Slice(t, c0, c, n0, n); }
};

inline CanarySlice canary_slice(Shape s, std::mt19937& rng, int64_t c_before = 1, int64_t c_after = 2) {
  CanarySlice cs;
  cs.host = HostTensor({s.n + 2, s.c + c_before + c_after, s.h, s.w}, kCanary);
  cs.c0 = c_before, cs.c = s.c, cs.n0 = 1, cs.n = s.n;
  std::uniform_real_distribution<float> d(-1.f, 1.f);
  for (int64_t n = 0; n < s.n; ++n)
    for (int64_t c = 0; c < s.c; ++c)
      for (int64_t y = 0; y < s.h; ++y)
        for (int64_t x = 0; x < s.w; ++x) cs.host.at(cs.n0 + n, cs.c0 + c, y, x) = d(rng);
  return cs;
}

// "" when every element of `t` outside the slice still holds kCanary; else how many do not and the
// first of them.
inline std::string canary_damage(const HostTensor& t, const CanarySlice& cs) {
  int64_t bad = 0;
  std::string first;
  for (int64_t n = 0; n < t.shape.n; ++n)
    for (int64_t c = 0; c < t.shape.c; ++c) {
      const bool inside = n >= cs.n0 && n < cs.n0 + cs.n && c >= cs.c0 && c < cs.c0 + cs.c;
      if (inside) continue;
      for (int64_t y = 0; y < t.shape.h; ++y)
        for (int64_t x = 0; x < t.shape.w; ++x) {
          const float v = t.at(n, c, y, x);
          if (v == kCanary) continue;
          if (bad++ == 0)
            first = "(n " + std::to_string(n) + ", c " + std::to_string(c) + ", y " + std::to_string(y) + ", x " +
                    std::to_string(x) + ") = " + std::to_string(v);
        }
    }
  return bad == 0 ? std::string() : std::to_string(bad) + " canaries overwritten, first " + first;
}

// Largest |a - b| inside the canary slice over the range of the reference b there, max(1, max |b|),
// counting only where |b| <= `limit` (fp16: its range) — fp16's error scales with the values' range.
inline double max_range_rel_diff(const HostTensor& a, const HostTensor& b, const CanarySlice& cs,
                                 double limit = INFINITY) {
  if (!(a.shape == b.shape)) return INFINITY;
  double m = 0, range = 1;
  for (int pass = 0; pass < 2; ++pass)
    for (int64_t n = cs.n0; n < cs.n0 + cs.n; ++n)
      for (int64_t ch = cs.c0; ch < cs.c0 + cs.c; ++ch)
        for (int64_t y = 0; y < a.shape.h; ++y)
          for (int64_t x = 0; x < a.shape.w; ++x) {
            const double r = b.at(n, ch, y, x);
            if (!(std::fabs(r) <= limit)) continue;
            if (pass == 0) {
              range = std::max(range, std::fabs(r));
              continue;
            }
            const double d = std::fabs(static_cast<double>(a.at(n, ch, y, x)) - r) / range;
            if (!(d <= m)) m = std::isnan(d) ? INFINITY : d;
          }
  return m;
}

// The tensor as fp16 storage keeps it (each value rounded to nearest even half).
inline HostTensor rounded_to_half(HostTensor t) {
  for (auto& v : t.data) v = round_to_half(v);
  return t;
}

// Largest |a - b| inside the canary slice of two tensors of its layout.
inline double max_abs_diff(const HostTensor& a, const HostTensor& b, const CanarySlice& cs) {
  if (!(a.shape == b.shape)) return INFINITY;
  double m = 0;
  for (int64_t n = cs.n0; n < cs.n0 + cs.n; ++n)
    for (int64_t ch = cs.c0; ch < cs.c0 + cs.c; ++ch)
      for (int64_t y = 0; y < a.shape.h; ++y)
        for (int64_t x = 0; x < a.shape.w; ++x) {
          const double d = std::fabs(static_cast<double>(a.at(n, ch, y, x)) - b.at(n, ch, y, x));
          if (!(d <= m)) m = std::isnan(d) ? INFINITY : d;
        }
  return m;
}

}  // namespace vkunroll::ktest
