// Integer and size flags of the benches: the whole value must be a number in [lo, hi] (a size WxH,
// each side in [lo, hi]), else the bench stops with exit status 2 naming the flag (std::atoi read
// "abc" as 0 and "5x" as 5, and sscanf("%dx%d") took "346x260abc", silently).
#pragma once
#include <charconv>
#include <cstdio>
#include <cstdlib>
#include <string>

inline long long bench_int_arg(const char* bench, const std::string& flag, const std::string& value, long long lo,
                               long long hi) {
  long long v = 0;
  const char* end = value.data() + value.size();
  const auto [stop, ec] = std::from_chars(value.data(), end, v);
  if (value.empty() || ec != std::errc() || stop != end || v < lo || v > hi) {
    std::fprintf(stderr, "%s: %s '%s': expected a whole number from %lld to %lld\n", bench, flag.c_str(), value.c_str(), lo, hi);
    std::exit(2);
  }
  return v;
}

struct BenchSize {
  long long w = 0, h = 0;
};
inline BenchSize bench_size_arg(const char* bench, const std::string& flag, const std::string& value, long long lo,
                                long long hi) {
  const size_t x = value.find('x');
  if (x == std::string::npos) {
    std::fprintf(stderr, "%s: %s '%s': expected WxH, e.g. 346x260\n", bench, flag.c_str(), value.c_str());
    std::exit(2);
  }
  return {bench_int_arg(bench, flag + " (width)", value.substr(0, x), lo, hi),
          bench_int_arg(bench, flag + " (height)", value.substr(x + 1), lo, hi)};
}
