// Events in memory: a struct of arrays, time-sorted, with the sensor size that bounds x and y.
#pragma once
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace vkunroll {

struct EventStream {
  int width = 0;   // sensor width in pixels; every x < width
  int height = 0;  // sensor height in pixels; every y < height
  std::vector<int64_t> t;   // microseconds, non-decreasing
  std::vector<uint16_t> x;
  std::vector<uint16_t> y;
  std::vector<int8_t> p;    // +1 brightness increase, -1 decrease (readers map every encoding)

  size_t size() const { return t.size(); }
  bool empty() const { return t.empty(); }
  void reserve(size_t n) {
    t.reserve(n);
    x.reserve(n);
    y.reserve(n);
    p.reserve(n);
  }
  void push(int64_t ts, uint16_t xs, uint16_t ys, int8_t ps) {
    t.push_back(ts);
    x.push_back(xs);
    y.push_back(ys);
    p.push_back(ps);
  }
};

}  // namespace vkunroll
