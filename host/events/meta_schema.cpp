#include "vkunroll/host/events/meta_schema.hpp"

#include <sys/stat.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "vkunroll/host/events/sequence.hpp"

namespace vkunroll {
namespace fs = std::filesystem;

namespace {

constexpr double kTimeLimit = 9007199254740992.0;  // 2^53 us: int64 windows and float64 times stay exact
constexpr double kInf = HUGE_VAL;

// The cross-field rules, by name; the functions below cite them and the doc lists them.
struct MetaRule {
  const char* name;
  const char* doc;
};
const MetaRule kRules[] = {
    {"frames-in-time-order", "every frame's `t0_us` is later than the previous frame's (all layouts)"},
    {"readout-within-frame-period",
     "a frame's first row starts no earlier than the previous frame's last row: `t0_us[k] - t0_us[k-1] >= "
     "(height - 1) x line_delay_us` (a `t0_us` inside the previous readout is refused)"},
    {"distinct-frame-files", "no two frames name the same image file (nor two ground-truth entries); all layouts"},
    {"images-agree",
     "every frame and ground-truth image is `width` x `height` and has the first frame's channel count (a gray "
     "frame among colour frames is refused); all layouts"},
    {"ground-truth-inside-recording",
     "every `ground_truth[].t_us` lies in [first frame's `t0_us`, the last frame's end], where the end is the "
     "later of its last row's exposure end and its `t0_us` plus the last frame period"},
};

std::string rule_text(const char* name) {
  for (const auto& r : kRules)
    if (std::string(r.name) == name) return std::string("rule ") + r.name + ": " + r.doc;
  return std::string("rule ") + name;
}

const std::vector<MetaField> kMetaFields = {
    {"width", MetaType::integer, "px", true, 1, 32767, 8, 8192, "sensor width; every frame and event must fit"},
    {"height", MetaType::integer, "px", true, 1, 32767, 8, 8192, "sensor height (rows read out)"},
    {"line_delay_us", MetaType::time, "us", true, 0, 1e6, 0, 1e4, "start of row y+1 minus start of row y"},
    {"exposure_us", MetaType::time, "us", true, 0, kTimeLimit, 1, 1e6, "exposure of one row (> 0)"},
    {"readout", MetaType::readout, "", false, 0, 0, 0, 0, "`top-down` (default) or `bottom-up`"},
    {"frames", MetaType::list, "items", true, 1, 1e7, 1, 1e6, "the RS frames in time order"},
    {"frames[]", MetaType::object, "", true, 0, 0, 0, 0, "`{\"file\", \"t0_us\"}`"},
    {"frames[].file", MetaType::string, "", true, 0, 0, 0, 0, "image path, relative to the folder"},
    {"frames[].t0_us", MetaType::time, "us", true, -kTimeLimit, kTimeLimit, -kInf, kInf,
     "exposure start of the first row read out"},
    {"frames[].exposure_us", MetaType::time, "us", false, 0, kTimeLimit, 1, 1e6, "this frame's exposure (extension)"},
    {"events", MetaType::string, "", true, 0, 0, 0, 0, "event file, relative to the folder"},
    {"events_topic", MetaType::string, "", false, 0, 0, 0, 0, "a ROS bag's event topic (extension)"},
    {"ground_truth", MetaType::list, "items", false, 0, 1e8, 0, 1e7, "sharp GS images at instants"},
    {"ground_truth[]", MetaType::object, "", true, 0, 0, 0, 0, "`{\"file\", \"t_us\"}`"},
    {"ground_truth[].file", MetaType::string, "", true, 0, 0, 0, 0, "image path, relative to the folder"},
    {"ground_truth[].t_us", MetaType::time, "us", true, -kTimeLimit, kTimeLimit, -kInf, kInf, "the instant it shows"},
    {"ground_truth[].frame", MetaType::integer, "", false, 0, 1e7, 0, 1e6, "the RS frame period it belongs to (simulator)"},
    {"ground_truth[].index", MetaType::integer, "", false, 0, 1e7, 0, 1e4, "its instant's index in that period (simulator)"},
    {"ground_truth[].tau", MetaType::number, "", false, -1e6, 1e6, -1, 10,
     "(t - first row start) / frame span of that frame; > 1: between frames (simulator)"},
    {"source", MetaType::object, "", false, 0, 0, 0, 0, "free-form: simulator settings, camera, notes"},
    {"source.settings", MetaType::object, "", false, 0, 0, 0, 0, "the simulator's settings"},
    {"source.settings.gamma", MetaType::number, "", false, 0.1, 10, 1, 3, "the frames' encoding gamma (simulator)"},
    {"source.gamma", MetaType::number, "", false, 0.1, 10, 1, 3, "the frames' encoding gamma"},
};

// Containers whose keys are all in the table: a key that is not is warned about (a typo such as
// "line_delay" would otherwise be silently ignored, then refused as missing, or worse, defaulted).
const char* const kClosedContainers[] = {"", "frames[]", "ground_truth[]"};

std::string shown(const nlohmann::json& j) {
  std::string s = j.dump();
  return s.size() > 80 ? s.substr(0, 77) + "..." : s;
}

std::string num(double v) {
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  if (v == kTimeLimit) return "2^53";
  if (v == -kTimeLimit) return "-2^53";
  std::ostringstream os;
  os << v;
  return os.str();
}

std::string with_unit(const MetaField& f, double v) { return num(v) + (*f.unit ? std::string(" ") + f.unit : ""); }

const char* type_name(MetaType t) {
  switch (t) {
    case MetaType::integer: return "integer";
    case MetaType::time: return "time (number, or exact string like \"73000/259\")";
    case MetaType::number: return "number";
    case MetaType::string: return "non-empty string";
    case MetaType::readout: return "string, top-down or bottom-up";
    case MetaType::list: return "list";
    case MetaType::object: return "object";
  }
  return "?";
}

bool ranged(MetaType t) { return t == MetaType::integer || t == MetaType::time || t == MetaType::number || t == MetaType::list; }

std::string legal_text(const MetaField& f) {
  if (!ranged(f.type)) return "";
  const bool open_min = f.type == MetaType::time && f.min == 0 && std::string(f.path).find("exposure") != std::string::npos;
  return (open_min ? "(" : "[") + with_unit(f, f.min) + ", " + with_unit(f, f.max) + "]";
}

// The value of a field as a number (throws the field's error when its type is wrong).
double numeric_value(const MetaField& f, const nlohmann::json& v, const std::string& file, const std::string& field) {
  const std::string expected = std::string("expected ") + type_name(f.type) + " in " + legal_text(f);
  switch (f.type) {
    case MetaType::integer:
      if (!v.is_number_integer()) throw MetaSchemaError(file, field, shown(v), expected);
      if (v.is_number_unsigned() && v.get<uint64_t>() > uint64_t(INT64_MAX)) return kInf;
      return double(v.get<int64_t>());
    case MetaType::number:
      if (!v.is_number()) throw MetaSchemaError(file, field, shown(v), expected);
      return v.get<double>();
    case MetaType::list: return double(v.size());
    default: break;
  }
  if (v.is_number()) return v.get<double>();
  if (!v.is_string()) throw MetaSchemaError(file, field, shown(v), expected);
  try {
    return Rational::parse(v.get<std::string>(), field).to_double();
  } catch (const Error&) {
    throw MetaSchemaError(file, field, shown(v), expected);
  }
}

struct Validator {
  const std::string& file;
  std::vector<std::string> warnings;

  void check(const MetaField& f, const nlohmann::json& v, const std::string& field) {
    const std::string expected = std::string("expected ") + type_name(f.type);
    if (f.type == MetaType::object && !v.is_object()) throw MetaSchemaError(file, field, shown(v), expected);
    if (f.type == MetaType::list && !v.is_array()) throw MetaSchemaError(file, field, shown(v), expected);
    if ((f.type == MetaType::string || f.type == MetaType::readout) && (!v.is_string() || v.get<std::string>().empty()))
      throw MetaSchemaError(file, field, shown(v), expected);
    if (f.type == MetaType::readout) {
      try {
        parse_readout(v.get<std::string>());
      } catch (const Error&) {
        throw MetaSchemaError(file, field, shown(v), expected);
      }
    }
    if (!ranged(f.type)) return;
    const double x = numeric_value(f, v, file, field);
    const bool open_min = legal_text(f)[0] == '(';
    if (!std::isfinite(x) || x < f.min || x > f.max || (open_min && x <= f.min))
      throw MetaSchemaError(file, field, shown(v), std::string("expected ") + type_name(f.type) + " in " + legal_text(f));
    if (x < f.plausible_min || x > f.plausible_max)
      warnings.push_back(file + ":" + field + " = " + shown(v) + " is legal but implausible (expected " +
                         with_unit(f, f.plausible_min) + " to " + with_unit(f, f.plausible_max) + ")");
  }

  // Visits every value of `path` below `node` (segments "a", "b[]"); missing required ones fail.
  void visit(const MetaField& f, const nlohmann::json& node, const std::vector<std::string>& segs, size_t i,
             const std::string& field) {
    const std::string& seg = segs[i];
    const bool each = seg.size() > 2 && seg.compare(seg.size() - 2, 2, "[]") == 0;
    const std::string key = each ? seg.substr(0, seg.size() - 2) : seg;
    const std::string name = field.empty() ? key : field + "." + key;
    if (!node.is_object()) return;  // the parent's own entry reported its type
    if (!node.contains(key)) {
      // "frames[]" entries are required within their list; the list's own entry says whether it is.
      if (i + 1 == segs.size() && f.required && !each) throw MetaSchemaError(file, name, "(missing)", "a required field");
      return;
    }
    const nlohmann::json& v = node[key];
    if (each) {
      if (!v.is_array()) return;
      for (size_t k = 0; k < v.size(); ++k) {
        const std::string at = name + "[" + std::to_string(k) + "]";
        if (i + 1 == segs.size()) check(f, v[k], at);
        else visit(f, v[k], segs, i + 1, at);
      }
      return;
    }
    if (i + 1 == segs.size()) check(f, v, name);
    else visit(f, v, segs, i + 1, name);
  }
};

std::vector<std::string> split_path(const std::string& path) {
  std::vector<std::string> out;
  std::stringstream ss(path);
  for (std::string s; std::getline(ss, s, '.');) out.push_back(s);
  return out;
}

// Keys of `container` ("", "frames[]") that the table names.
std::set<std::string> known_keys(const std::string& container) {
  std::set<std::string> keys;
  const std::string prefix = container.empty() ? "" : container + ".";
  for (const auto& f : kMetaFields) {
    const std::string p = f.path;
    if (p.compare(0, prefix.size(), prefix) != 0) continue;
    std::string rest = p.substr(prefix.size());
    rest = rest.substr(0, rest.find('.'));
    if (rest.size() > 2 && rest.compare(rest.size() - 2, 2, "[]") == 0) rest.resize(rest.size() - 2);
    keys.insert(rest);
  }
  return keys;
}

std::vector<std::string> unknown_keys(const nlohmann::json& obj, const std::set<std::string>& keys) {
  std::vector<std::string> out;
  if (!obj.is_object()) return out;
  for (const auto& item : obj.items())
    if (!keys.count(item.key())) out.push_back(item.key());
  return out;
}

std::string unknown_warning(const std::string& file, const std::string& field, const std::string& key) {
  return file + ":" + (field.empty() ? "" : field + ".") + key + " is not a meta.json field (ignored; see " +
         "docs/reliability.md, \"meta.json schema\")";
}

std::string seq_file(const Sequence& s) {
  return s.layout == SequenceLayout::generic ? (fs::path(s.root) / "meta.json").string() : s.root;
}

std::string channels_text(int c) {
  return std::to_string(c) + (c == 1 ? " channel (gray)" : c == 3 ? " channels (colour)" : " channels");
}

}  // namespace

const std::vector<MetaField>& meta_fields() { return kMetaFields; }

std::vector<std::string> validate_meta(const nlohmann::json& meta, const std::string& meta_path) {
  if (!meta.is_object()) throw MetaSchemaError(meta_path, "(top level)", shown(meta), "expected a JSON object");
  Validator v{meta_path, {}};
  for (const auto& f : kMetaFields) v.visit(f, meta, split_path(f.path), 0, "");
  for (const char* c : kClosedContainers) {
    const std::string container = c;
    if (container.empty()) {
      for (const auto& key : unknown_keys(meta, known_keys(""))) v.warnings.push_back(unknown_warning(meta_path, "", key));
      continue;
    }
    const std::string list = container.substr(0, container.size() - 2);
    if (!meta.contains(list) || !meta[list].is_array()) continue;
    // One warning per unknown key of a list's items, at its first item, with the count.
    std::map<std::string, std::pair<size_t, std::string>> unknown;  // key -> (items, first item's field)
    const std::set<std::string> keys = known_keys(container);
    for (size_t k = 0; k < meta[list].size(); ++k)
      for (const auto& key : unknown_keys(meta[list][k], keys)) {
        auto& u = unknown[key];
        if (u.first++ == 0) u.second = list + "[" + std::to_string(k) + "]";
      }
    for (const auto& [key, u] : unknown)
      v.warnings.push_back(unknown_warning(meta_path, u.second, key) +
                           (u.first > 1 ? " (in " + std::to_string(u.first) + " " + list + " items)" : ""));
  }
  return v.warnings;
}

void rule_readout_within_frame_period(const Sequence& s, const FieldName& t0_field) {
  for (size_t k = 1; k < s.frames.size(); ++k) {
    const RowTiming& prev = s.frames[k - 1].timing;
    const Rational readout = prev.line_delay * Rational(prev.rows - 1);
    const Rational t0 = s.frames[k].timing.t0;
    if (t0 >= prev.t0 + readout) continue;
    const std::string field = t0_field(k);
    const auto colon = field.rfind(':');
    throw MetaSchemaError(field.substr(0, colon), field.substr(colon + 1), t0.str(),
                          "frame " + std::to_string(k) + " starts inside frame " + std::to_string(k - 1) +
                              "'s readout [" + prev.t0.str() + ", " + (prev.t0 + readout).str() + "] us: the frame period " +
                              (t0 - prev.t0).str() + " us is shorter than the readout (" + std::to_string(prev.rows - 1) +
                              " x " + prev.line_delay.str() + " = " + readout.str() + " us) (" +
                              rule_text("readout-within-frame-period") + ")");
  }
}

void rule_distinct_frame_files(const Sequence& s, const std::string& meta_path) {
  auto check = [&](const std::vector<std::string>& images, const char* list) {
    std::map<std::string, size_t> first;
    for (size_t k = 0; k < images.size(); ++k) {
      const auto [it, fresh] = first.emplace(image_identity(images[k]), k);
      if (!fresh)
        throw MetaSchemaError(meta_path, std::string(list) + "[" + std::to_string(k) + "].file", "\"" + images[k] + "\"",
                              std::string("the same image as ") + list + "[" + std::to_string(it->second) + "] (" +
                                  rule_text("distinct-frame-files") + ")");
    }
  };
  std::vector<std::string> frames, truth;
  for (const auto& f : s.frames) frames.push_back(f.image);
  for (const auto& g : s.ground_truth) truth.push_back(g.image);
  check(frames, "frames");
  check(truth, "ground_truth");
}

void rule_ground_truth_inside_recording(const Sequence& s, const std::string& meta_path) {
  if (s.frames.empty()) return;
  const RowTiming& last = s.frames.back().timing;
  Rational end = last.last_end();
  if (s.frames.size() > 1) end = std::max(end, last.t0 + (last.t0 - s.frames[s.frames.size() - 2].timing.t0));
  const Rational begin = s.frames.front().timing.t0;
  for (size_t i = 0; i < s.ground_truth.size(); ++i) {
    const Rational t = s.ground_truth[i].t_us;
    if (t >= begin && t <= end) continue;
    throw MetaSchemaError(meta_path, "ground_truth[" + std::to_string(i) + "].t_us", t.str(),
                          "outside the recording [" + begin.str() + ", " + end.str() + "] us (" +
                              rule_text("ground-truth-inside-recording") + ")");
  }
}

std::string image_identity(const std::string& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) == 0) return "inode " + std::to_string(st.st_dev) + ":" + std::to_string(st.st_ino);
  std::error_code ec;
  fs::path p = fs::weakly_canonical(path, ec);
  if (ec) p = fs::path(path).lexically_normal();
  return p.string();
}

void rule_image_agrees(const Sequence& s, const std::string& field, const std::string& image, const ImageHeader& h,
                       const ImageHeader& reference, const std::string& reference_field) {
  const std::string file = seq_file(s);
  const std::string value = "\"" + image + "\" (" + std::to_string(h.width) + "x" + std::to_string(h.height) + ", " +
                            channels_text(h.channels) + ")";
  if (h.width != s.width || h.height != s.height)
    throw MetaSchemaError(file, field, value,
                          "the image is " + std::to_string(h.width) + "x" + std::to_string(h.height) + ", the sensor is " +
                              std::to_string(s.width) + "x" + std::to_string(s.height) + " (" + rule_text("images-agree") + ")");
  if (h.channels != reference.channels)
    throw MetaSchemaError(file, field, value,
                          "the image has " + channels_text(h.channels) + ", " + reference_field + " has " +
                              channels_text(reference.channels) + " (" + rule_text("images-agree") + ")");
}

void rule_images_agree(const Sequence& s, const std::vector<ImageHeader>& frames, const std::vector<ImageHeader>& truth) {
  const ImageHeader reference = frames.empty() ? ImageHeader{} : frames[0];
  for (size_t k = 0; k < frames.size(); ++k)
    rule_image_agrees(s, "frames[" + std::to_string(k) + "].file", s.frames[k].image, frames[k], reference, "frames[0]");
  for (size_t k = 0; k < truth.size(); ++k)
    rule_image_agrees(s, "ground_truth[" + std::to_string(k) + "].file", s.ground_truth[k].image, truth[k], reference, "frames[0]");
}

std::string meta_schema_markdown() {
  std::ostringstream md;
  md << "Generated from `kMetaFields` and `kRules` (host/events/meta_schema.cpp) by `meta_schema_markdown()`;\n"
        "`MetaSchema.DocIsInSyncWithTheTable` fails when this section differs. A value outside its legal\n"
        "range is an error `<meta.json>:<field> = <value>: <rule>` (exit 65); outside the plausible range, a\n"
        "warning naming the field (stderr and `summary.json` `warnings`). Fields the schema does not name\n"
        "(at the top level and in `frames[]`, `ground_truth[]`) are warned about and ignored.\n\n"
        "| field | type | unit | required | legal | plausible | meaning |\n"
        "| --- | --- | --- | --- | --- | --- | --- |\n";
  for (const auto& f : kMetaFields) {
    const bool r = ranged(f.type);
    std::string type = type_name(f.type);
    if (f.type == MetaType::time) type = "time";
    md << "| `" << f.path << "` | " << type << " | " << (*f.unit ? f.unit : "") << " | " << (f.required ? "yes" : "no")
       << " | " << (r ? legal_text(f) : "") << " | "
       << (r && !(std::isinf(f.plausible_min) && std::isinf(f.plausible_max))
               ? with_unit(f, f.plausible_min) + " to " + with_unit(f, f.plausible_max)
               : "")
       << " | " << f.doc << " |\n";
  }
  md << "\nTimes are numbers or exact strings (`\"73000/259\"`). `required` holds within the parent (an entry of\n"
        "`frames[]` needs `t0_us`). Cross-field rules, each named in its error:\n\n";
  for (const auto& r : kRules) md << "- `" << r.name << "`: " << r.doc << ".\n";
  return md.str();
}

}  // namespace vkunroll
