// The extent of an NCHW tensor, on the host or on the device, and a rectangle of its pixels.
#pragma once
#include <cstdint>
#include <string>

namespace vkunroll {

struct Shape {
  int64_t n = 1, c = 1, h = 1, w = 1;
  int64_t count() const { return n * c * h * w; }
  int64_t plane() const { return h * w; }
  bool operator==(const Shape&) const = default;
  std::string str() const { return std::to_string(n) + "x" + std::to_string(c) + "x" + std::to_string(h) + "x" + std::to_string(w); }
};

// A rectangle of pixels: rows [y, y + h), columns [x, x + w).
struct Rect {
  int64_t y = 0, x = 0, h = 0, w = 0;
  int64_t area() const { return h * w; }
  bool operator==(const Rect&) const = default;
};

}  // namespace vkunroll
