#include "vkunroll/base/error.hpp"

namespace vkunroll {

namespace {

std::string as_named(std::string_view field) { return std::string(field); }

std::string option_text(const std::string& field, const std::string& value, const std::string& rule) {
  return opt(field) + (value.empty() ? "" : " " + value) + ": " + rule;
}

}  // namespace

std::string spell_fields(std::string_view text, const FieldSpelling& spell) {
  std::string out;
  out.reserve(text.size());
  for (size_t i = 0; i < text.size();) {
    const size_t open = text.find('\x1f', i), close = open == std::string_view::npos ? open : text.find('\x1f', open + 1);
    if (close == std::string_view::npos) {
      out.append(text.substr(i));
      break;
    }
    out.append(text.substr(i, open - i));
    out += spell(text.substr(open + 1, close - open - 1));
    i = close + 1;
  }
  return out;
}

const char* kind_name(ErrorKind kind) {
  switch (kind) {
    case ErrorKind::unspecified: return "unspecified";
    case ErrorKind::usage: return "usage";
    case ErrorKind::data: return "data";
    case ErrorKind::input_missing: return "input_missing";
    case ErrorKind::device_unavailable: return "device_unavailable";
    case ErrorKind::internal: return "internal";
    case ErrorKind::io: return "io";
    case ErrorKind::temporary: return "temporary";
  }
  return "unspecified";
}

Error::Error(const std::string& text, ErrorKind kind)
    : std::runtime_error(text.find('\x1f') == std::string::npos ? text : spell_fields(text, as_named)), kind_(kind), text_(text) {}

OptionError::OptionError(std::string field, std::string value, std::string rule, std::string text, ErrorKind kind)
    : Error(text.empty() ? option_text(field, value, rule) : text, kind),
      field_(std::move(field)),
      value_(std::move(value)),
      rule_(std::move(rule)) {}

}  // namespace vkunroll
