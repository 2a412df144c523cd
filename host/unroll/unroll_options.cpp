#include "vkunroll/host/unroll/unroll_options.hpp"

#include <cmath>
#include <filesystem>

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/events/event_reader.hpp"
#include "vkunroll/host/unroll/backend_options.hpp"
#include "vkunroll/host/unroll/value_list.hpp"

namespace vkunroll {

namespace fs = std::filesystem;

namespace {

// "1e+300" is no good in a message about 1e300; inf and nan by name.
std::string number_text(double v) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

// `which`: the value's place in a list (" value 2"), empty for a single value.
void check_time(const Rational& v, const std::string& field, const std::string& which = "") {
  const double d = v.to_double();
  const std::string rule = "times must lie within +-2^53 us (285 years)";
  if (!(std::abs(d) <= kMaxTimeUs))
    throw OptionError(field, v.str(), rule, opt(field) + which + " " + v.str() + " us is out of range: " + rule);
}

// The path `field` names exists and is a folder (or a regular file): an OptionError of kind
// input_missing (exit 66) or data (exit 65) otherwise.
void check_exists(const std::string& path, const std::string& field, bool folder) {
  const std::string what = opt(field) + " " + path;
  auto fail = [&](const std::string& rule, ErrorKind kind) { throw OptionError(field, path, rule, what + ": " + rule, kind); };
  std::error_code ec;
  const auto st = fs::status(path, ec);
  if (!fs::exists(st)) fail(std::string("no such ") + (folder ? "folder" : "file"), ErrorKind::input_missing);
  if (folder && !fs::is_directory(st)) fail("is not a folder", ErrorKind::data);
  if (!folder && fs::is_directory(st)) fail("is a folder, expected a file", ErrorKind::data);
  if (const std::string kind = special_file_kind(path); !folder && !kind.empty())
    fail("is " + kind + ", expected a regular file (reading it could block for ever)", ErrorKind::data);
}

[[noreturn]] void refuse(const std::string& field, const std::string& value, const std::string& rule) {
  throw OptionError(field, value, rule);
}

}  // namespace

UnrollMode parse_unroll_mode(const std::string& s, const std::string& what) {
  if (s == "auto") return UnrollMode::automatic;
  if (s == "s") return UnrollMode::s;
  if (s == "m") return UnrollMode::m;
  if (s == "physics") return UnrollMode::physics;
  if (s == "choose") return UnrollMode::choose;
  throw OptionError(what, "'" + s + "'", "expected s, m, choose, physics or auto",
                    opt(what) + " '" + s + "' (expected s, m, choose, physics or auto)");
}

const char* unroll_mode_name(UnrollMode m) {
  switch (m) {
    case UnrollMode::automatic: return "auto";
    case UnrollMode::s: return "s";
    case UnrollMode::m: return "m";
    case UnrollMode::physics: return "physics";
    case UnrollMode::choose: return "choose";
  }
  return "?";
}

ChannelOrder parse_channel_order(const std::string& s, const std::string& what) {
  if (s == "rgb") return ChannelOrder::rgb;
  if (s == "bgr") return ChannelOrder::bgr;
  if (s == "model") return ChannelOrder::model;
  throw OptionError(what, "'" + s + "'", "expected rgb, bgr or model: the weights' metadata",
                    opt(what) + " '" + s + "' (expected rgb, bgr or model: the weights' metadata)");
}

GateRadiusOption parse_gate_radius(const std::string& s, const std::string& what) {
  if (s == "auto") return {GateRadiusOption::Kind::automatic, 0};
  if (s == "model") return {GateRadiusOption::Kind::model, 0};
  size_t used = 0;
  int r = -1;
  try {
    r = std::stoi(s, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != s.size() || s.empty() || r < 0 || r > kMaxGateRadius)
    throw OptionError(what, "'" + s + "'", "expected auto, model or an integer radius 0.." + std::to_string(kMaxGateRadius));
  return {GateRadiusOption::Kind::fixed, r};
}

std::string gate_radius_text(const GateRadiusOption& g) {
  switch (g.kind) {
    case GateRadiusOption::Kind::automatic: return "auto";
    case GateRadiusOption::Kind::model: return "model";
    case GateRadiusOption::Kind::fixed: return std::to_string(g.radius);
  }
  return "?";
}

TargetTimes parse_target_times(const std::string& times, const std::string& times_us) {
  if (!times_us.empty()) return {TargetTimes::Kind::absolute_us, parse_value_list(times_us, "times_us")};
  if (times == "gt") return {TargetTimes::Kind::ground_truth, {}};
  return {TargetTimes::Kind::normalized, parse_value_list(times, "times")};
}

void validate_sequence_options(const SequenceOptions& o) {
  if (o.line_delay_us) {
    check_time(*o.line_delay_us, "line_delay_us");
    if (*o.line_delay_us < Rational(0) || *o.line_delay_us > Rational(1000000))
      refuse("line_delay_us", o.line_delay_us->str(), "expected 0 to 1e6 us (a row-to-row delay; sensors use 1 to 100 us)");
  }
  if (o.exposure_us) {
    check_time(*o.exposure_us, "exposure_us");
    if (*o.exposure_us <= Rational(0)) refuse("exposure_us", o.exposure_us->str(), "expected > 0 us");
  }
  if (o.frame_period_us) {
    check_time(*o.frame_period_us, "frame_period_us");
    if (*o.frame_period_us <= Rational(0)) refuse("frame_period_us", o.frame_period_us->str(), "expected > 0 us");
  }
  if (o.t0s_us) {
    if (o.t0s_us->empty()) refuse("t0s_us", "", "no value given");
    for (size_t i = 0; i < o.t0s_us->size(); ++i) check_time((*o.t0s_us)[i], "t0s_us", " value " + std::to_string(i + 1));
  }
  if (o.events_file) check_exists(*o.events_file, "events", false);
}

namespace {

// Options of the Vulkan backend only: given (their value shown; "on" for a switch) or not (empty).
struct VulkanOnlyOption {
  const char* field;
  std::string (*given)(const SessionOptions&);
  const char* why;
  bool is_switch = false;
};

const VulkanOnlyOption kVulkanOnlyOptions[] = {
    {"precision", [](const SessionOptions& o) { return o.precision == Precision::fp16 ? std::string("fp16") : std::string(); },
     "the CPU backend computes the fp32 reference"},
    {"device", [](const SessionOptions& o) { return o.device; }, "the CPU backend opens no device"},
    {"conv_choice", [](const SessionOptions& o) { return o.conv_choice == ConvChoice::automatic ? std::string() : std::string(conv_choice_name(o.conv_choice)); },
     "it chooses among the Vulkan conv kernels"},
    {"profile", [](const SessionOptions& o) { return o.profile_ops ? std::string("on") : std::string(); },
     "it reads the device's timestamps", true},
    {"trace", [](const SessionOptions& o) { return o.trace ? std::string("on") : std::string(); },
     "the timeline is the device's dispatches", true},
};

}  // namespace

void check_session_options_apply(const SessionOptions& o) {
  if (o.backend != BackendKind::cpu) return;
  if (o.precision == Precision::fp16) throw fp16_needs_vulkan();  // the library's one text for it
  for (const VulkanOnlyOption& v : kVulkanOnlyOptions)
    if (const std::string value = v.given(o); !value.empty())
      throw OptionError(v.field, value, "the vulkan backend",
                        opt(v.field) + (v.is_switch ? "" : " " + value) + " applies to " + opt("backend") + " vulkan only (" + v.why +
                            "); with " + opt("backend") + " cpu leave it out");
}

void validate_unroll_options(const UnrollOptions& o) {
  if (o.sequence.empty()) throw OptionError("sequence", "", "a folder", "no " + opt("sequence") + " folder given");
  if (o.out_dir.empty()) throw OptionError("out", "", "a folder", opt("out") + " DIR is required");
  const bool needs_model = o.mode == UnrollMode::s || o.mode == UnrollMode::m || o.mode == UnrollMode::choose;
  if (needs_model && o.session.model_path.empty())
    throw OptionError("mode", unroll_mode_name(o.mode), "needs a model",
                      std::string(opt("mode") + " ") + unroll_mode_name(o.mode) + " needs " + opt("model") + " FILE.safetensors");
  SessionOptions session = o.session;
  session.trace = session.trace || !o.trace_path.empty();
  check_session_options_apply(session);
  if (o.tile < 0 || o.tile % kTileAlign)
    refuse("tile", std::to_string(o.tile), "expected 0 (automatic) or a positive multiple of " + std::to_string(kTileAlign));
  if (o.halo < -1 || (o.halo >= 0 && o.halo % kTileAlign))
    refuse("halo", std::to_string(o.halo), "expected -1 (automatic) or a non-negative multiple of " + std::to_string(kTileAlign));
  if (!(o.sparse_threshold >= 0) || std::isinf(o.sparse_threshold))
    refuse("sparse_threshold", number_text(o.sparse_threshold), "expected a finite value >= 0 events per pixel");
  // Ranges a real sensor can have: event thresholds are 0.05 to 1 in log intensity, decode gammas 1 to 2.6.
  if (o.contrast && !(*o.contrast > 0 && *o.contrast <= 5))
    refuse("contrast", number_text(*o.contrast), "expected a log-intensity threshold in (0, 5]");
  if (o.gamma && !(*o.gamma >= 0.1 && *o.gamma <= 10))
    refuse("gamma", number_text(*o.gamma), "expected a decode gamma in [0.1, 10] (2.2 for sRGB-like frames, 1 for linear)");
  if (o.output.video_fps && !(*o.output.video_fps > 0 && *o.output.video_fps <= 1000))
    refuse("fps", number_text(*o.output.video_fps), "expected a frame rate in (0, 1000]");
  const char* times_field = o.times.kind == TargetTimes::Kind::absolute_us ? "times_us" : "times";
  if (o.times.kind != TargetTimes::Kind::ground_truth && o.times.values.empty()) refuse(times_field, "", "no target given");
  for (const Rational& v : o.times.values) {
    if (o.times.kind == TargetTimes::Kind::absolute_us) check_time(v, "times_us");
    else if (!(std::abs(v.to_double()) <= kMaxTau))
      refuse("times", v.str(), "a normalized target must lie within +-1e6 frame spans");
  }
  refuse_repeated(o.times.values, times_field, false);  // the lists' one rule, as the CLI's parser applies it
  std::vector<Rational> frames;
  for (int k : o.frames) {
    if (k < 0) refuse("frames", "", "frame index " + std::to_string(k) + " is negative");
    frames.emplace_back(k);
  }
  refuse_repeated(frames, "frames", true);
  validate_sequence_options(o.sequence_options);
  if (o.follow.enabled) {
    if (o.output.existing == ExistingOutput::resume)
      throw OptionError("follow", "", "a fresh output", opt("follow") + " writes a fresh output; " + opt("resume") + " does not apply to it");
    if (o.sequence_options.events_file)
      throw OptionError("events", "", "not with follow", opt("follow") + " reads its events from " + opt("follow_events") + " (default stdin), not " + opt("events"));
    // Below the reader's 20 ms poll a stream would end between two reads of a healthy pipe.
    if (!(o.follow.idle_s == 0 || (o.follow.idle_s >= 0.1 && o.follow.idle_s <= 1e6)))
      refuse("follow_idle_s", number_text(o.follow.idle_s), "expected 0 (wait for ever) or seconds in [0.1, 1e6]");
    if (o.follow.events.empty()) refuse("follow_events", "", "an empty value (name a pipe, a growing file, or - for stdin)");
    if (o.follow.max_events < 1024 || o.follow.max_events > (size_t(1) << 34))
      refuse("follow_max_events", std::to_string(o.follow.max_events), "expected 1024 to 2^34 events");
  }
}

void check_output_apart(const std::string& out, const std::string& out_field,
                        const std::vector<std::pair<std::string, std::string>>& inputs) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path o = fs::weakly_canonical(fs::absolute(out), ec);
  if (ec) return;  // an unresolvable output path fails later, with its own error
  auto within = [](const fs::path& inner, const fs::path& outer) {  // inner == outer or below it
    auto i = inner.begin();
    for (auto p = outer.begin(); p != outer.end(); ++p, ++i)
      if (i == inner.end() || *i != *p) return false;
    return true;
  };
  for (const auto& [what, path] : inputs) {
    if (path.empty()) continue;
    const fs::path in = fs::weakly_canonical(fs::absolute(path), ec);
    if (ec) continue;
    const std::string option = opt(out_field);
    if (within(in, o))
      throw OptionError(out_field, out, "apart from the inputs",
                        option + " " + out + ": " + (in == o ? "is" : "holds") + " the input " + what + " " + path +
                            "; the output would replace what the run reads: choose another " + option);
    if (within(o, in))
      throw OptionError(out_field, out, "apart from the inputs",
                        option + " " + out + ": lies inside the input " + what + " " + path +
                            "; write the output outside the inputs: choose another " + option);
  }
}

void check_unroll_inputs(const UnrollOptions& o) {
  check_exists(o.sequence, "sequence", true);
  if (!o.session.model_path.empty() && o.mode != UnrollMode::physics) check_exists(o.session.model_path, "model", false);
  check_output_apart(o.out_dir, "out", {{opt("sequence"), o.sequence},
                                        {opt("events") + " file", o.sequence_options.events_file.value_or("")},
                                        {opt("model") + " file", o.mode == UnrollMode::physics ? "" : o.session.model_path}});
}

void spell_options(nlohmann::json& j, const FieldSpelling& spell) {
  if (j.is_string()) {
    const std::string& s = j.get_ref<const std::string&>();
    if (s.find('\x1f') != std::string::npos) j = spell_fields(s, spell ? spell : [](std::string_view f) { return std::string(f); });
  } else if (j.is_structured()) {
    for (auto& item : j) spell_options(item, spell);
  }
}

nlohmann::json unroll_options_json(const UnrollOptions& o) {
  const SequenceOptions& so = o.sequence_options;
  auto opt_rational = [](const std::optional<Rational>& r) { return r ? nlohmann::json(r->str()) : nlohmann::json(); };
  nlohmann::json times = nlohmann::json::array();
  for (const auto& v : o.times.values) times.push_back(v.str());
  nlohmann::json t0s;
  if (so.t0s_us)
    for (const auto& v : *so.t0s_us) t0s.push_back(v.str());
  const char* kinds[] = {"normalized", "absolute_us", "ground_truth"};
  return {
      {"sequence", o.sequence},
      {"out", o.out_dir},
      {"mode", unroll_mode_name(o.mode)},
      {"times", {{"kind", kinds[static_cast<int>(o.times.kind)]}, {"values", times}}},
      {"frames", o.frames},
      {"model", o.session.model_path},
      {"backend", backend_kind_name(o.session.backend)},
      {"device", o.session.device},
      {"precision", precision_name(o.session.precision)},
      {"conv_choice", conv_choice_name(o.session.conv_choice)},
      {"cpu_threads", o.session.cpu_threads},
      {"channel_order", o.channel_order == ChannelOrder::model ? "model" : o.channel_order == ChannelOrder::rgb ? "rgb" : "bgr"},
      {"contrast", o.contrast ? nlohmann::json(*o.contrast) : nlohmann::json()},
      {"gate_radius", gate_radius_text(o.gate_radius)},
      {"gamma", o.gamma ? nlohmann::json(*o.gamma) : nlohmann::json()},
      {"tile", o.tile},
      {"halo", o.halo},
      {"sparse", sparse_policy_name(o.sparse)},
      {"sparse_threshold", o.sparse_threshold},
      {"sparse_split", o.sparse_split},
      {"frame_format", frame_format_name(o.output.frame_format)},
      {"video", o.output.write_video},
      {"fps", o.output.video_fps ? nlohmann::json(*o.output.video_fps) : nlohmann::json()},
      {"existing_output", existing_output_name(o.output.existing)},
      {"follow", o.follow.enabled ? nlohmann::json{{"events", o.follow.events}, {"idle_s", o.follow.idle_s}, {"max_events", o.follow.max_events}} : nlohmann::json()},
      {"sequence_options",
       {{"layout", sequence_layout_name(so.layout)},
        {"line_delay_us", opt_rational(so.line_delay_us)},
        {"exposure_us", opt_rational(so.exposure_us)},
        {"readout", so.readout ? nlohmann::json(readout_name(*so.readout)) : nlohmann::json()},
        {"t0s_us", t0s},
        {"frame_period_us", opt_rational(so.frame_period_us)},
        {"gev_half_row", so.gev_half_row},
        {"on_bad", so.events.on_bad == BadEventPolicy::error ? "error" : so.events.on_bad == BadEventPolicy::drop ? "drop" : "sort"},
        {"events_file", so.events_file ? nlohmann::json(*so.events_file) : nlohmann::json()}}},
  };
}

}  // namespace vkunroll
