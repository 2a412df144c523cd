#include "vkunroll/host/unroll/value_list.hpp"

#include <algorithm>

#include "vkunroll/base/error.hpp"

namespace vkunroll {
namespace {

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  size_t pos = 0;
  while (true) {
    const size_t n = s.find(sep, pos);
    out.push_back(s.substr(pos, n == std::string::npos ? std::string::npos : n - pos));
    if (n == std::string::npos) break;
    pos = n + 1;
  }
  return out;
}

// `field`'s number: Rational::parse's rule, as the field's OptionError.
Rational parse_number(const std::string& item, const std::string& field) {
  try {
    return Rational::parse(item, opt(field));
  } catch (const OptionError&) {
    throw;
  } catch (const Error& e) {
    throw OptionError(field, "'" + item + "'", "a number", e.text());
  }
}

std::vector<Rational> parse_items(const std::string& text, const std::string& what, bool frames) {
  const std::string option = opt(what);
  auto fail = [&](const std::string& value, const std::string& text_after) {
    throw OptionError(what, value, text_after, option + ": " + text_after);
  };
  if (text.empty()) fail("", "empty list");
  std::vector<Rational> out;
  for (const auto& item : split(text, ',')) {
    if (item.empty()) fail(text, "empty item in '" + text + "'");
    const auto parts = split(item, ':');
    if (parts.size() == 1) {
      out.push_back(parse_number(item, what));
    } else if (parts.size() == 2 && frames) {
      const Rational a = parse_number(parts[0], what), b = parse_number(parts[1], what);
      if (a.den() != 1 || b.den() != 1 || b < a) fail(item, "'" + item + "' must be a:b with integers a <= b");
      if (b - a > Rational(1000000)) fail(item, "'" + item + "' spans more than 1000000 frames");
      for (int64_t v = a.floor(); v <= b.floor(); ++v) out.push_back(Rational(v));
    } else if (parts.size() == 3) {
      const Rational a = parse_number(parts[0], what), b = parse_number(parts[1], what);
      const Rational n = parse_number(parts[2], what);
      if (n.den() != 1 || n < Rational(1) || n > Rational(1000000))
        fail(item, "'" + item + "': the count (third number) must be an integer in [1, 1000000]");
      const int64_t count = n.floor();
      for (int64_t i = 0; i < count; ++i)
        out.push_back(count == 1 ? a : a + (b - a) * Rational(i) / Rational(count - 1));
    } else {
      fail(item, "'" + item + "' is not a value or start:stop:count" + (frames ? " or a:b" : ""));
    }
  }
  refuse_repeated(out, what, frames, text);
  return out;
}

}  // namespace

void refuse_repeated(const std::vector<Rational>& values, const std::string& what, bool frames, const std::string& listed) {
  std::vector<Rational> sorted = values;
  std::sort(sorted.begin(), sorted.end(), [](const Rational& x, const Rational& y) { return x < y; });
  for (size_t i = 1; i < sorted.size(); ++i)
    if (!(sorted[i - 1] < sorted[i])) {
      const std::string where = listed.empty() ? std::string(" in the list")
                                               : " in '" + listed.substr(0, 64) + (listed.size() > 64 ? "...'" : "'");
      const std::string text = std::string(frames ? "frame " : "value ") + sorted[i].str() + " is listed twice" + where + " (each once)";
      throw OptionError(what, sorted[i].str(), text, opt(what) + ": " + text);
    }
}

std::vector<Rational> parse_value_list(const std::string& text, const std::string& what) {
  return parse_items(text, what, false);
}

std::vector<int> parse_frame_list(const std::string& text, const std::string& what) {
  std::vector<int> out;
  for (const auto& v : parse_items(text, what, true)) {
    if (v.den() != 1 || v < Rational(0) || v > Rational(1 << 30))
      throw OptionError(what, v.str(), "a non-negative integer", opt(what) + ": frame " + v.str() + " is not a non-negative integer");
    out.push_back(static_cast<int>(v.floor()));
  }
  return out;
}

SensorCrop user_crop(const std::vector<long long>& v, const std::string& field) {
  std::string shown;
  for (long long x : v) shown += (shown.empty() ? "" : ",") + std::to_string(x);
  auto refuse = [&](const std::string& rule) { throw OptionError(field, shown, rule, opt(field) + " " + shown + ": " + rule); };
  if (v.size() != 4) refuse("expected x0,y0,width,height (four integers)");
  if (v[0] < 0 || v[1] < 0) refuse("x0 and y0 must be >= 0");
  if (v[2] <= 0 || v[3] <= 0) refuse("the width and height must be positive (leave the crop out for the whole sensor)");
  for (long long x : v)
    if (x > 32767) refuse("each value at most 32767 (the largest sensor)");
  return {static_cast<int>(v[0]), static_cast<int>(v[1]), static_cast<int>(v[2]), static_cast<int>(v[3])};
}

}  // namespace vkunroll
