// Helpers shared by the model tests: fixtures, host arrays, comparisons.
#pragma once
#include <algorithm>
#include <cmath>
#include <random>
#include <string>

#include "vkunroll/host/model/model.hpp"
#include "vkunroll/host/model/safetensors.hpp"

namespace vkunroll::modeltest {

inline std::string fixture(const std::string& name) {
  return std::string(VKUNROLL_SOURCE_DIR) + "/tests/data/" + name;
}

inline HostTensor array_from(const SafetensorsTensor& t) {
  HostTensor a;
  a.shape = Shape{t.shape.at(0), t.shape.at(1), t.shape.at(2), t.shape.at(3)};
  a.data = t.to_f32();
  return a;
}

inline ModelInputs inputs_from(const SafetensorsFile& f) {
  ModelInputs in{array_from(f.get("rs")), array_from(f.get("ev1")), array_from(f.get("ev2")), array_from(f.get("ev3"))};
  if (f.has("phys")) in.phys = array_from(f.get("phys"));  // the physics-informed variant's fixtures
  return in;
}

inline HostTensor take(const HostTensor& a, int64_t i0, int64_t n) {
  HostTensor r;
  r.shape = a.shape;
  r.shape.n = n;
  const int64_t per = a.shape.c * a.shape.h * a.shape.w;
  r.data.assign(a.data.begin() + i0 * per, a.data.begin() + (i0 + n) * per);
  return r;
}

inline ModelInputs take_items(const ModelInputs& in, int64_t i0, int64_t n) {
  return {take(in.rs, i0, n), take(in.ev1, i0, n), take(in.ev2, i0, n), take(in.ev3, i0, n)};
}

inline double max_abs_diff(const HostTensor& a, const HostTensor& b) {
  if (!(a.shape == b.shape)) return INFINITY;
  double m = 0;
  for (size_t i = 0; i < a.data.size(); ++i) {
    const double d = std::fabs(double(a.data[i]) - double(b.data[i]));
    if (!(d <= m)) m = std::isnan(d) ? INFINITY : d;
  }
  return m;
}

// Images uniform in [0,1]; event counts 0..3 at a quarter of the pixels.
inline ModelInputs random_inputs(int64_t b, int64_t h, int64_t w, int n_bins, uint32_t seed, bool values = true) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  auto make = [&](int64_t c, bool events) {
    HostTensor a{{b, c, h, w}, std::vector<float>(size_t(b * c * h * w))};
    if (values)
      for (auto& v : a.data) v = events ? (u(rng) < 0.25f ? float(int(u(rng) * 4)) : 0.f) : u(rng);
    return a;
  };
  ModelInputs in;
  in.rs = make(3, false);
  in.ev1 = make(2 * n_bins, true);
  in.ev2 = make(2 * n_bins, true);
  in.ev3 = make(2 * n_bins, true);
  return in;
}

}  // namespace vkunroll::modeltest
