// An NCHW float32 array in host memory: the CPU references' data, model inputs and outputs, and
// weights (a weight's PyTorch shape padded to four dimensions: bias [C] is {C, 1, 1, 1}).
#pragma once
#include <cstddef>
#include <cstdint>
#include <vector>

#include "vkunroll/base/shape.hpp"

namespace vkunroll {

struct HostTensor {
  Shape shape;
  std::vector<float> data;

  HostTensor() = default;
  explicit HostTensor(Shape s, float fill = 0.f);
  HostTensor(Shape s, std::vector<float> values);  // values.size() must equal s.count()

  size_t index(int64_t n, int64_t c, int64_t y, int64_t x) const {
    return static_cast<size_t>(((n * shape.c + c) * shape.h + y) * shape.w + x);
  }
  float& at(int64_t n, int64_t c, int64_t y, int64_t x) { return data[index(n, c, y, x)]; }
  float at(int64_t n, int64_t c, int64_t y, int64_t x) const { return data[index(n, c, y, x)]; }
};

}  // namespace vkunroll
