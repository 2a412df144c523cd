#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <map>
#include <stdexcept>
#include <opencv2/core/utility.hpp>

#include "vkunroll/base/error.hpp"
#include "vkunroll/host/cli/cli.hpp"
#include "vkunroll/host/unroll/output_paths.hpp"
#include "vkunroll/host/unroll/unroll_options.hpp"
#include "vkunroll/host/unroll/value_list.hpp"

namespace vkunroll::cli {

namespace {

std::vector<std::string>& argv_store() {
  static std::vector<std::string> v;
  return v;
}

// A deprecated spelling: hidden from the help, warns on stderr, fills the same value.
void add_deprecated_alias(CLI::App* app, const std::string& old_name, const std::string& new_name, std::string& target) {
  CLI::Option* o = app->add_option(old_name, target, "deprecated spelling of " + new_name)->group("");
  o->each([old_name, new_name](const std::string&) {
    std::cerr << "vkunroll " << "warning: " << old_name << " is deprecated; use " << new_name << "\n";
  });
  o->excludes(app->get_option(new_name));
}

Rational rational(const std::string& text, const std::string& what) {
  try {
    return Rational::parse(text, what);
  } catch (const Error& e) {
    throw UsageError(e.text());
  }
}

}  // namespace

std::string flag_for(std::string_view field) {
  // Fields whose flag is not "--" + the field with '-' for '_'.
  // The output table spells its own fields (OUT, VKUNROLL_CACHE_DIR).
  for (const OutputPath& p : output_paths())
    if (std::string_view(p.front_end) != "python" && field == p.field) return p.spelled;
  static const std::map<std::string_view, std::string_view> renamed = {
      {"sequence", "SEQUENCE"}, {"speed_scale", "--speed"}, {"flicker_amplitude", "--flicker-amp"}, {"hot_fraction", "--hot-pixels"}};
  if (auto it = renamed.find(field); it != renamed.end()) return std::string(it->second);
  std::string flag = "--" + std::string(field);
  std::replace(flag.begin(), flag.end(), '_', '-');
  return flag;
}

std::string cli_message(const std::exception& e) {
  if (const auto* err = dynamic_cast<const Error*>(&e)) return err->spelled(flag_for);
  return e.what();
}

Formatter::Formatter() {
  column_width(34);
  label("REQUIRED", "(required)");
}

std::string Formatter::make_usage(const CLI::App* app, std::string name) const {
  // CLI11's help passes "vkunroll unroll" (parents included), usage() passes "unroll": name the parents once.
  std::string parents;
  for (const CLI::App* p = app->get_parent(); p; p = p->get_parent()) parents = p->get_name() + " " + parents;
  std::string out = "usage: " + (name.rfind(parents, 0) == 0 ? name : parents + name);
  if (!app->get_subcommands([](const CLI::App* s) { return !s->get_name().empty(); }).empty()) out += " <command>";
  for (const CLI::Option* o : app->get_options([](const CLI::Option* o) { return o->get_positional(); })) {
    const std::string n = o->get_name();
    out += " " + (o->get_required() ? n : "[" + n + "]");
  }
  for (const CLI::Option* o : app->get_options([](const CLI::Option* o) { return o->nonpositional() && o->get_required(); }))
    out += " " + o->get_name(false, true).substr(0, o->get_name(false, true).find(',')) + " " + o->get_type_name();
  if (!app->get_options([](const CLI::Option* o) { return o->nonpositional() && !o->get_required(); }).empty())
    out += " [options]";
  return out + "\n";
}

void add_sequence_timing(CLI::App* app, SequenceTimingArgs& a) {
  const std::string g = "Sequence timing (the same for unroll and voxelize; values in us are exact: '73000/259')";
  app->add_option("--layout", a.layout, "generic | gev-rs | gev-rs-real | dre | fastec (default: detected)")
      ->check(CLI::IsMember({"auto", "generic", "gev-rs", "gev-rs-real", "dre", "fastec"}))->group(g)->type_name("L");
  app->add_option("--line-delay-us", a.line_delay, "row-to-row start delay, overriding the layout's")->group(g)->type_name("US");
  app->add_option("--exposure-us", a.exposure, "row exposure, overriding the layout's")->group(g)->type_name("US");
  app->add_option("--readout", a.readout, "top-down | bottom-up")
      ->check(CLI::IsMember({"top-down", "bottom-up"}))->group(g)->type_name("DIR");
  app->add_option("--t0s-us", a.t0s, "first-row exposure start of every frame of the sequence (a list, one per frame)")
      ->group(g)->type_name("LIST");
  app->add_option("--frame-period-us", a.frame_period, "Gev-RS-Real: the frame period (default: inferred)")
      ->group(g)->type_name("US");
  app->add_flag("--gev-half-row", a.gev_half_row, "Gev-RS: the half-row variant (row step 100 us, exposure 8 GS frames)")->group(g);
  app->add_option("--on-bad", a.on_bad, "events breaking a rule: error (stop) | drop (count and skip) | sort")
      ->capture_default_str()
      ->check(CLI::IsMember({"error", "drop", "sort"}))->group(g)->type_name("P");
  app->add_option("--events", a.events, "read the events from this file instead of the sequence's")->group(g)->type_name("FILE");
  app->add_option("--events-topic", a.events_topic, "ROS bag events: the topic (default: the bag's only event topic)")
      ->group(g)->type_name("TOPIC");
  add_deprecated_alias(app, "--line-delay", "--line-delay-us", a.line_delay);
  add_deprecated_alias(app, "--exposure", "--exposure-us", a.exposure);
  add_deprecated_alias(app, "--t0s", "--t0s-us", a.t0s);
  add_deprecated_alias(app, "--frame-period", "--frame-period-us", a.frame_period);
}

SequenceOptions sequence_options(const SequenceTimingArgs& a) {
  SequenceOptions so;
  try {
    if (!a.layout.empty()) so.layout = parse_sequence_layout(a.layout);
    if (!a.readout.empty()) so.readout = parse_readout(a.readout);
    if (!a.t0s.empty()) so.t0s_us = parse_value_list(a.t0s, "t0s_us");
  } catch (const Error& e) {
    throw UsageError(e.text());
  }
  if (so.t0s_us) {
    const std::vector<Rational>& t0 = *so.t0s_us;
    for (size_t i = 1; i < t0.size(); ++i)
      if (!(t0[i - 1] < t0[i]))
        throw UsageError("--t0s-us: value " + std::to_string(i + 1) + " (" + t0[i].str() + " us) is not after value " +
                         std::to_string(i) + " (" + t0[i - 1].str() + " us); frames must start in increasing time order");
  }
  if (!a.line_delay.empty()) so.line_delay_us = rational(a.line_delay, "--line-delay-us");
  if (!a.exposure.empty()) so.exposure_us = rational(a.exposure, "--exposure-us");
  if (!a.frame_period.empty()) so.frame_period_us = rational(a.frame_period, "--frame-period-us");
  so.gev_half_row = a.gev_half_row;
  so.events.on_bad = a.on_bad == "drop" ? BadEventPolicy::drop : a.on_bad == "sort" ? BadEventPolicy::sort : BadEventPolicy::error;
  if (!a.events.empty()) so.events_file = a.events;
  so.events.events_topic = a.events_topic;
  validate_sequence_options(so);
  return so;
}

void add_device_options(CLI::App* app, DeviceArgs& a) {
  const std::string g = "Device";
  app->add_option("--device", a.device,
                  "INDEX, uuid:UUID (see vkunroll devices) or a name substring; default: VKUNROLL_DEVICE, else "
                  "discrete > integrated > virtual > cpu")
      ->group(g)->type_name("D");
  app->add_option("--threads", a.threads,
                  "CPU threads: lavapipe's workers (LP_NUM_THREADS) and the CPU backend's pool; 0: the machine's")
      ->check(int_range(0, 1024))->group(g)->type_name("N");
}

void apply_threads(unsigned threads) {
  if (threads == 0) return;
  ::setenv("LP_NUM_THREADS", std::to_string(threads).c_str(), 1);  // read when lavapipe's device is made
  cv::setNumThreads(static_cast<int>(threads));
}

namespace {
// `s` as a finite number into `v`; else what is wrong with it (the validators' shared first step).
std::string parse_finite(const std::string& s, double& v) {
  char* end = nullptr;
  v = std::strtod(s.c_str(), &end);
  if (end == s.c_str() || *end) return "'" + s + "' is not a number";
  if (!std::isfinite(v)) return "'" + s + "' is not a finite number";
  return {};
}
}  // namespace

CLI::Validator finite_at_least(double lo, bool open) {
  return CLI::Validator(
      [lo, open](std::string& s) -> std::string {
        double v = 0;
        if (std::string bad = parse_finite(s, v); !bad.empty()) return bad;
        if (open ? !(v > lo) : !(v >= lo)) return "'" + s + "': expected a value " + (open ? "> " : ">= ") + number_text(lo);
        return {};
      },
      std::string(open ? "> " : ">= ") + number_text(lo));
}

CLI::Validator finite_range(double lo, double hi) {
  return CLI::Validator(
      [lo, hi](std::string& s) -> std::string {
        double v = 0;
        if (std::string bad = parse_finite(s, v); !bad.empty()) return bad;
        if (!(v >= lo && v <= hi)) return "'" + s + "': expected a value in [" + number_text(lo) + ", " + number_text(hi) + "]";
        return {};
      },
      "[" + number_text(lo) + ", " + number_text(hi) + "]");
}

CLI::Validator int_range(long long lo, long long hi) {
  return CLI::Validator(
      [lo, hi](std::string& s) -> std::string {
        char* end = nullptr;
        errno = 0;
        const long long v = std::strtoll(s.c_str(), &end, 10);
        if (end == s.c_str() || *end || errno) return "'" + s + "' is not an integer";
        if (v < lo || v > hi) return "'" + s + "': expected an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
        return {};
      },
      "[" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
}

void parse_size(const std::string& s, const std::string& what, int& w, int& h) {
  int a = 0, b = 0;
  char x = 0, extra = 0;
  if (std::sscanf(s.c_str(), "%d%c%d%c", &a, &x, &b, &extra) != 3 || (x != 'x' && x != 'X') || a < 2 || b < 2 ||
      a > 32767 || b > 32767)
    throw UsageError(what + " '" + s + "': expected WIDTHxHEIGHT, each 2 to 32767, e.g. 346x260");
  w = a;
  h = b;
}

void check_output_file(const std::string& path, const std::string& option) {
  std::error_code ec;
  const auto st = std::filesystem::status(path, ec);
  if (std::filesystem::exists(st) && !std::filesystem::is_regular_file(st))
    throw UsageError(option + " " + path + ": exists and is not a regular file (" +
                     (std::filesystem::is_directory(st) ? "a folder" : "a device, FIFO or socket") +
                     "); the output is written under a temporary name and renamed over it: name a file");
  const std::filesystem::path parent = std::filesystem::absolute(path, ec).parent_path();
  if (!parent.empty()) check_output_folder(parent.string(), option + " " + path + ": its folder");
}

CLI::Option* add_output_option(CLI::App* app, std::string_view id, std::string& value) {
  const OutputPath& p = output_path(id);
  if (std::string_view(p.front_end) != "cli" || app->get_name() != p.command)
    throw std::logic_error("output path '" + std::string(id) + "' is not an option of vkunroll " + app->get_name());
  return app->add_option(p.spelled, value, p.help)
      ->check(non_empty())
      ->type_name(p.shape == OutputShape::folder ? "DIR" : "FILE");
}

CLI::Validator non_empty() {
  return CLI::Validator(
      [](std::string& s) -> std::string { return s.empty() ? "an empty value (give one, or leave the option out)" : ""; },
      "");
}

void check_output_folder(const std::string& path, const std::string& option) {
  namespace fs = std::filesystem;
  std::error_code ec;
  for (fs::path p = fs::absolute(path, ec).lexically_normal(); !p.empty(); p = p.parent_path()) {
    const auto st = fs::status(p, ec);
    if (fs::exists(st)) {
      if (!fs::is_directory(st))
        throw UsageError(option + " " + path + ": " + (p == fs::absolute(path, ec).lexically_normal() ? "exists" : p.string() + " exists") +
                         " and is not a folder");
      return;
    }
    if (p == p.root_path()) return;
  }
}

std::string number_text(double v) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  char buf[64];
  std::snprintf(buf, sizeof buf, std::abs(v) < 1e18 && v == std::floor(v) ? "%.0f" : "%.17g", v);
  return buf;
}

const std::vector<std::string>& command_line() { return argv_store(); }

void set_command_line(int argc, char** argv) { argv_store().assign(argv, argv + argc); }

}  // namespace vkunroll::cli
